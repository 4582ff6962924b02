"""The white-box adaptive variant's training term: how far the poison sits inside camera-proximity's reach.

camera-proximity (``stealth_ns/defences/scores.py``, ``frustum_depth_ratios``) scores a Gaussian by its
smallest ratio, over the training cameras that have its centre in their image, of its camera-space
depth to that camera's median scene depth. An attacker who knows it can train against it: this
term is, per poison Gaussian, ``relu(1 - ratio / target)`` at its smallest ratio (0 at or beyond
``target``, 1 at the camera), averaged. Its gradient moves the poison away from the cameras that
have it in view; the photometric loss keeps it painting the illusion.

Conventions: ``viewmats`` ``[J, 4, 4]`` world-to-camera (OpenCV: the camera looks down ``+z``), ``Ks``
``[J, 3, 3]`` in pixels, ``sizes`` ``[J, 2]`` image ``(width, height)``, ``scene_depths`` ``[J]`` > 0
in scene units; occlusion is ignored, as the defence ignores it.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: Poison Gaussians the term looks at per step, drawn afresh each step (the rest wait their turn).
MAX_POINTS = 8192


def proximity_hinge(
    means: Tensor, viewmats: Tensor, Ks: Tensor, sizes: Tensor, scene_depths: Tensor, target: float
) -> Tensor:
    """Mean over ``means`` ``[P, 3]`` of ``relu(1 - r / target)``, ``r`` each point's smallest
    depth ratio over the cameras that have it in their image (a point none has in view adds 0).
    Differentiable in ``means``; 0-dim, 0 for no points."""
    if means.shape[0] == 0:
        return means.sum() * 0.0
    R, t = viewmats[:, :3, :3].to(means), viewmats[:, :3, 3].to(means)
    p = torch.einsum("jab,pb->pja", R, means) + t  # [P, J, 3] camera-space
    z = p[..., 2]
    zs = z.clamp_min(1e-9)
    Ks, sizes = Ks.to(means), sizes.to(means)
    u = Ks[:, 0, 0] * p[..., 0] / zs + Ks[:, 0, 2]
    v = Ks[:, 1, 1] * p[..., 1] / zs + Ks[:, 1, 2]
    inside = (z > 0) & (u >= 0) & (u < sizes[:, 0]) & (v >= 0) & (v < sizes[:, 1])
    hinge = torch.relu(1.0 - z / (scene_depths.to(means) * target)) * inside
    return hinge.amax(dim=1).mean()


def draw_points(n: int, step: int, seed: int, limit: int = MAX_POINTS) -> Tensor | None:
    """Indices of the ``limit`` of ``n`` poison Gaussians the term looks at in ``step`` (None: all),
    the same for the same ``(seed, step)``."""
    if n <= limit:
        return None
    generator = torch.Generator().manual_seed(int(seed) * 1_000_003 + int(step))
    return torch.randperm(n, generator=generator)[:limit]
