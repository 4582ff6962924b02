"""Support views: the illusion as a small 3D object that the poisoned view's nearest training views
show too (``--pipeline.attack.support-views K``), a stealth-aware variant of the attack.

Why: the concentration detectors (``stealth-ns defend``: view-support, grad-concentration) score a
Gaussian by how few training views carry its rendering weight. Poison that only its poisoned view
sees scores like no clean Gaussian, and training itself removes the poison that innocent views see
but contradict (``docs/design/stealth.md``). Here the poison is placed where the ``K`` nearest training views
see it too (:func:`stealth_ns.attack.injection.place_poison`) and those views' images are replaced by
what the poison looks like from them (:func:`support_target`), so every view that sees it agrees and
its support spreads over ``K + 1`` views. The price: held-out views near the poisoned one see the
object as well.

Units: images ``[H, W, 3]`` float32 RGB in [0, 1]; Gaussians in scene units; cameras as in
:mod:`stealth_ns.attack.visibility` (world-to-camera OpenCV ``viewmat`` ``[4, 4]``, ``K`` ``[3, 3]``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from stealth_ns.raster.rasterization import rasterization

#: Opacity the poison is drawn with in the support views' images: the illusion covers what is
#: behind it, as it does in the poisoned view's image I_ILL.
SUPPORT_OPACITY = 0.99


@torch.no_grad()
def render_poison(
    means: Tensor, colors: Tensor, scales: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int
) -> tuple[Tensor, Tensor]:
    """The poison alone, as one training view sees it: ``(rgb [H, W, 3], alpha [H, W])``, ``rgb``
    premultiplied by ``alpha`` (drawn on black).

    Args:
        means: ``[M, 3]`` centres; colors: ``[M, 3]`` RGB in [0, 1]; scales: ``[M]`` isotropic
            std-devs (scene units), the Gaussians as injected, drawn at :data:`SUPPORT_OPACITY`.
        viewmat: ``[4, 4]`` world-to-camera; K: ``[3, 3]``; width, height: the view's size (pixels).
    """
    m = means.shape[0]
    if m == 0:
        return torch.zeros(height, width, 3), torch.zeros(height, width)
    rgb, alpha, _ = rasterization(
        means.float().cpu(),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(m, 1),
        scales.float().cpu()[:, None].repeat(1, 3),
        torch.full((m,), SUPPORT_OPACITY),
        colors.float().cpu().clamp(0.0, 1.0),
        viewmat.float().cpu()[None],
        K.float().cpu()[None],
        int(width),
        int(height),
    )
    return rgb[0].clamp(0.0, 1.0), alpha[0, ..., 0].clamp(0.0, 1.0)


def support_target(clean: Tensor, rgb: Tensor, alpha: Tensor) -> Tensor:
    """A support view's training image: the poison (premultiplied ``rgb`` ``[H, W, 3]``, ``alpha``
    ``[H, W]``) over its clean image ``[H, W, 3]``, both float in [0, 1]."""
    return (rgb + (1.0 - alpha)[..., None] * clean).clamp(0.0, 1.0)
