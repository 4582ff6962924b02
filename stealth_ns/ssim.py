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
        # L1 gradient, the composite's backward) get a contiguous [H, W, C] tensor. Strided by planes,
        # the clamp's backward `where` took 2.6 ms per step in a 1-MP training profile.
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
        v_Y = load_extension().ssim_bwd(X, Y, win, dmaps, v_planes.contiguous())
        if ctx.channels_last:
            v_Y = v_Y.contiguous(memory_format=torch.channels_last)
        return None, v_Y, None, None, None


class SSIM(ReferenceSSIM):
    """``pytorch_msssim.SSIM`` with a compiled CPU path (same arguments, same result to float rounding)."""

    def forward(self, X: Tensor, Y: Tensor) -> Tensor:
        if not self._compiled_path(X, Y):
            return super().forward(X, Y)
        C1 = (self.K[0] * self.data_range) ** 2
        C2 = (self.K[1] * self.data_range) ** 2
        win = self.win[0].reshape(-1).to(torch.float32).contiguous()
        planes = _SSIMPlanesCPU.apply(X, Y, win, C1, C2)
        return planes.mean() if self.size_average else planes.mean(1)

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
