"""The training loss's SSIM: pytorch_msssim's (what splatfacto uses), compiled on the CPU.

:class:`SSIM` has the call contract of ``pytorch_msssim.SSIM`` (Gaussian window of 11 px, sigma 1.5,
valid convolution, mean over planes). On CPU float32 images whose first argument needs no gradient
(the ground truth) it runs the fused C++ kernel (``raster/csrc/ssim_cpu.cpp``: five filtered maps and
the SSIM map in one pass, the gradient with respect to the prediction through the transposed window);
anywhere else, and when the compiled module is unavailable, pytorch_msssim itself, which is also the
reference the tests compare with.
"""

from __future__ import annotations

import torch
from pytorch_msssim import SSIM as ReferenceSSIM
from torch import Tensor


class _SSIMPlanesCPU(torch.autograd.Function):
    """Per-plane SSIM ``[B, C]`` of ``X`` (no gradient) and ``Y`` (gradient)."""

    @staticmethod
    def forward(ctx, X: Tensor, Y: Tensor, win: Tensor, C1: float, C2: float) -> Tensor:
        from stealth_ns.raster.cpp_backend import load_extension

        # The training loss passes [H, W, C] images permuted to [1, C, H, W]: channels-last memory.
        # The gradient is given back in that layout, so that the backward's next ops (its sum with the
        # L1 gradient, the composite's backward) get a contiguous [H, W, C] tensor: strided by planes,
        # the clamp's backward `where` is slow (timings: docs/design/training_step.md, "The background
        # composite in one pass, and the SSIM gradient in the image's layout").
        ctx.channels_last = (
            Y.dim() == 4 and not Y.is_contiguous() and Y.is_contiguous(memory_format=torch.channels_last)
        )
        X, Y = X.contiguous(), Y.contiguous()
        planes, dmaps = load_extension().ssim_fwd(X, Y, win, C1, C2, ctx.needs_input_grad[1])
        ctx.save_for_backward(X, Y, win, dmaps)
        return planes

    @staticmethod
    def backward(ctx, v_planes: Tensor):
        from stealth_ns.raster.cpp_backend import load_extension

        X, Y, win, dmaps = ctx.saved_tensors
        v_Y = load_extension().ssim_bwd(X, Y, win, dmaps, v_planes.contiguous(), 0.0, ctx.channels_last)
        return None, v_Y.permute(0, 3, 1, 2) if ctx.channels_last else v_Y, None, None, None


class _L1SSIMLossCPU(torch.autograd.Function):
    """splatfacto's main loss ``(1 - lam) |gt - pred|.mean() + lam (1 - SSIM(gt, pred))`` of ``[H, W, C]``
    images, its gradient written by the SSIM backward kernel in one pass."""

    @staticmethod
    def forward(ctx, pred: Tensor, gt: Tensor, win: Tensor, C1: float, C2: float, lam: float) -> Tensor:
        from stealth_ns.raster.cpp_backend import load_extension

        X, Y = gt.permute(2, 0, 1)[None].contiguous(), pred.permute(2, 0, 1)[None].contiguous()
        planes, dmaps = load_extension().ssim_fwd(X, Y, win, C1, C2, True)
        ctx.save_for_backward(X, Y, win, dmaps)
        ctx.lam, ctx.n, ctx.n_planes = lam, pred.numel(), planes.numel()
        return (1 - lam) * torch.abs(gt - pred).mean() + lam * (1 - planes.mean())

    @staticmethod
    def backward(ctx, v_loss: Tensor):
        from stealth_ns.raster.cpp_backend import load_extension

        X, Y, win, dmaps = ctx.saved_tensors
        # Each term's upstream gradient rounded as autograd rounds it through the expression above: the
        # product with the weight, then the mean's division (SSIM's after the negation of 1 - S).
        v_l1 = (v_loss * (1 - ctx.lam)) / ctx.n
        v_planes = (-(v_loss * ctx.lam)).expand(1, ctx.n_planes) / ctx.n_planes
        v_pred = load_extension().ssim_bwd(X, Y, win, dmaps, v_planes.contiguous(), float(v_l1), True)
        return v_pred[0], None, None, None, None, None


def l1_ssim_loss(pred: Tensor, gt: Tensor, ssim: SSIM, lam: float) -> Tensor | None:
    """splatfacto's main loss of ``[H, W, C]`` images in one compiled pass each way: the value and the
    gradient with respect to ``pred`` are bitwise autograd's of
    ``(1 - lam) * torch.abs(gt - pred).mean() + lam * (1 - ssim(gt_planes, pred_planes))``, which at 1 MP
    chains ~8 full-image passes after the SSIM backward (``sgn``, products, the mean's division, a
    negation, a layout copy, the sum of the two gradients). None where the compiled SSIM does not apply."""
    if gt.dim() != 3 or pred.dim() != 3 or not ssim.size_average:
        return None
    if not ssim._compiled_path(gt.permute(2, 0, 1)[None], pred.permute(2, 0, 1)[None]):
        return None
    return _L1SSIMLossCPU.apply(pred, gt, ssim.window(), *ssim.constants(), lam)


class SSIM(ReferenceSSIM):
    """``pytorch_msssim.SSIM`` with a compiled CPU path (same arguments, same result to float rounding)."""

    def forward(self, X: Tensor, Y: Tensor) -> Tensor:
        if not self._compiled_path(X, Y):
            return super().forward(X, Y)
        planes = _SSIMPlanesCPU.apply(X, Y, self.window(), *self.constants())
        return planes.mean() if self.size_average else planes.mean(1)

    def constants(self) -> tuple[float, float]:
        """SSIM's stabilising constants ``C1 = (K1 L)^2`` and ``C2 = (K2 L)^2``, ``L`` the data range."""
        return (self.K[0] * self.data_range) ** 2, (self.K[1] * self.data_range) ** 2

    def window(self) -> Tensor:
        """The 1-D Gaussian window ``[K]`` (float32) the compiled kernels take."""
        return self.win[0].reshape(-1).to(torch.float32).contiguous()

    def _compiled_path(self, X: Tensor, Y: Tensor) -> bool:
        """Whether the compiled kernel computes exactly what pytorch_msssim would here."""
        from stealth_ns.raster.cpp_backend import load_extension

        size = self.win.shape[-1]
        return (
            X.device.type == "cpu"
            and X.dtype == Y.dtype == torch.float32
            and X.dim() == 4
            and X.shape == Y.shape
            and X.shape[1] == self.win.shape[0]
            and min(X.shape[-2:]) >= size
            and not X.requires_grad
            and not self.nonnegative_ssim
            and load_extension() is not None
        )
