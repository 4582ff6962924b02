"""The training render composited onto its background and clamped to [0, 1], with a compiled CPU path.

:func:`composite_on_background` is splatfacto's last step of ``get_outputs``,
``torch.clamp(render + (1 - alpha) * background, 0, 1)``. On CPU float32 contiguous tensors with a
background that needs no gradient (every training step of the CPU backends) it runs the compiled kernel
(``raster/csrc/composite_cpu.cpp``): one pass forward and one backward instead of torch's chain of
full-image operations, with the same values and gradients bit for bit (``tests/raster/test_composite.py``).
Anywhere else it is the torch expression itself, which is also the reference.
"""

from __future__ import annotations

import torch
from torch import Tensor


class _CompositeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, render: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
        from stealth_ns.raster.cpp_backend import load_extension

        ctx.save_for_backward(render, alpha, background)
        return load_extension().composite_fwd(render, alpha, background)

    @staticmethod
    def backward(ctx, v_rgb: Tensor):
        from stealth_ns.raster.cpp_backend import load_extension

        render, alpha, background = ctx.saved_tensors
        v_render, v_alpha = load_extension().composite_bwd(render, alpha, background, v_rgb.contiguous())
        return v_render, v_alpha, None


def composite_on_background(render: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
    """``clamp(render + (1 - alpha) * background, 0, 1)``.

    Args:
        render: ``[..., D]`` colours composited over a black background.
        alpha: ``[..., 1]`` their opacity.
        background: ``[D]``.

    Returns:
        ``[..., D]``, differentiable with respect to ``render`` and ``alpha`` (and ``background``, which
        then takes the torch path).
    """
    if _compiled_path(render, alpha, background):
        return _CompositeCPU.apply(render, alpha, background)
    return torch.clamp(render + (1 - alpha) * background, 0.0, 1.0)


def _compiled_path(render: Tensor, alpha: Tensor, background: Tensor) -> bool:
    from stealth_ns.raster.cpp_backend import load_extension

    tensors = (render, alpha, background)
    return (
        all(t.device.type == "cpu" and t.dtype == torch.float32 and t.is_contiguous() for t in tensors)
        and background.dim() == 1
        and render.dim() >= 1
        and background.shape[0] == render.shape[-1]
        and alpha.shape == (*render.shape[:-1], 1)
        and not background.requires_grad
        and load_extension() is not None
    )
