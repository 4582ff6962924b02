"""Initial Gaussian rows as splatfacto makes them, as pure functions: colours from the seed points, and
the box a random initialisation is drawn in for an object capture (``random_init_in_object_box``)."""

from __future__ import annotations

import torch
from nerfstudio.models.splatfacto import RGB2SH, num_sh_bases
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor


def initial_colours(seed_rgb: Tensor | None, n: int, sh_degree: int) -> tuple[Tensor, Tensor]:
    """``(features_dc [n, 3], features_rest [n, bases - 1, 3])`` of ``n`` new Gaussians: the seed
    points' colours (``seed_rgb`` [n, 3], 0-255) as the degree-0 SH coefficient (as a logit without
    SH, ``sh_degree`` 0), or random colours when ``seed_rgb`` is None (splatfacto's rule)."""
    dim_sh = num_sh_bases(sh_degree)
    if seed_rgb is None:
        return torch.rand(n, 3), torch.zeros((n, dim_sh - 1, 3))
    rgb = seed_rgb.float() / 255.0
    shs = torch.zeros((n, dim_sh, 3))
    if sh_degree > 0:
        shs[:, 0, :3] = RGB2SH(rgb)
    else:
        CONSOLE.log("use color only optimization with sigmoid activation")
        shs[:, 0, :3] = torch.logit(rgb, eps=1e-10)
    return shs[:, 0, :], shs[:, 1:, :]


def object_box(aabb: Tensor, camera_centres: Tensor, random_scale: float) -> tuple[Tensor, Tensor] | None:
    """``(lo [3], hi [3])``: the scene box ``aabb`` [2, 3] clamped to splatfacto's random cube of side
    ``random_scale`` (scene units), when every camera centre ([C, 3]) is outside the box (an object
    capture); None when some camera is inside it, there is no camera, or the clamped box is empty."""
    aabb, centres = aabb.float().cpu(), camera_centres.float().cpu()
    if centres.shape[0] == 0 or ((centres >= aabb[0]) & (centres <= aabb[1])).all(-1).any():
        return None
    half = random_scale / 2
    lo, hi = aabb[0].clamp(min=-half), aabb[1].clamp(max=half)
    return None if (hi <= lo).any() else (lo, hi)
