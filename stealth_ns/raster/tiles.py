"""Tile intersection: which Gaussians each 16x16 pixel tile must blend, front to back.

Same result as gsplat's ``isect_tiles`` + ``isect_offset_encode`` (vectorised torch instead
of CUDA): a Gaussian is listed in every tile that its 3-sigma square (``means2d ± radius``,
in tile units, floor/ceil) touches, and each tile's list is sorted by depth (stable, so
equal depths keep Gaussian-index order, as gsplat's radix sort does).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def tile_grid(width: int, height: int, tile_size: int) -> tuple[int, int]:
    """(tile_width, tile_height): number of tiles covering the image."""
    return math.ceil(width / tile_size), math.ceil(height / tile_size)


@torch.no_grad()
def tile_ranges(
    means2d: Tensor, radii: Tensor, tile_size: int, tile_width: int, tile_height: int
) -> tuple[Tensor, Tensor]:
    """Tile rectangle of every Gaussian.

    Args:
        means2d: [C, N, 2] pixel centres.
        radii: [C, N] radii in pixels (0 = not rendered).

    Returns:
        tile_min, tile_max: [C, N, 2] int64 (x, y); min inclusive, max exclusive, clamped
        to the tile grid. Empty (min == max) for Gaussians with radius 0.
    """
    t_means = means2d.detach() / tile_size
    t_radii = (radii.to(means2d.dtype) / tile_size)[..., None]
    upper = torch.tensor([tile_width, tile_height], device=means2d.device)
    tile_min = torch.minimum(torch.floor(t_means - t_radii).long().clamp(min=0), upper)
    tile_max = torch.minimum(torch.ceil(t_means + t_radii).long().clamp(min=0), upper)
    hidden = (radii <= 0)[..., None]
    tile_max = torch.where(hidden, tile_min, tile_max)
    return tile_min, tile_max


@torch.no_grad()
def isect_tiles(
    means2d: Tensor, radii: Tensor, depths: Tensor, tile_size: int, tile_width: int, tile_height: int
) -> tuple[Tensor, Tensor]:
    """Sorted (camera, tile, depth) intersection lists.

    Args:
        means2d: [C, N, 2], radii: [C, N], depths: [C, N].

    Returns:
        isect_offsets: [C, tile_height, tile_width] int32, start of each tile's list in
            ``flatten_ids`` (the list ends where the next tile's starts, or at the end).
        flatten_ids: [M] int32, indices into the flattened ``C * N`` Gaussians.
    """
    C, N = radii.shape
    device = means2d.device
    tile_min, tile_max = tile_ranges(means2d, radii, tile_size, tile_width, tile_height)
    extent = tile_max - tile_min  # [C, N, 2]
    counts = (extent[..., 0] * extent[..., 1]).reshape(-1)  # [C*N]
    n_tiles = tile_width * tile_height
    total = int(counts.sum())
    if total == 0:
        offsets = torch.zeros((C, tile_height, tile_width), dtype=torch.int32, device=device)
        return offsets, torch.zeros(0, dtype=torch.int32, device=device)

    # One row per (Gaussian, tile) pair: enumerate the tiles of each Gaussian's rectangle.
    gauss = torch.repeat_interleave(torch.arange(C * N, device=device), counts)
    start = torch.cumsum(counts, 0) - counts
    local = torch.arange(total, device=device) - start[gauss]
    ext_x = extent.reshape(-1, 2)[gauss, 0]
    tmin = tile_min.reshape(-1, 2)[gauss]
    tile_x = tmin[:, 0] + local % ext_x
    tile_y = tmin[:, 1] + local // ext_x
    cam = gauss // N
    key = cam * n_tiles + tile_y * tile_width + tile_x

    # Depth order inside a tile, then tile order; both sorts stable.
    order = torch.argsort(depths.reshape(-1)[gauss], stable=True)
    order = order[torch.argsort(key[order], stable=True)]
    flatten_ids = gauss[order].to(torch.int32)

    per_tile = torch.bincount(key, minlength=C * n_tiles)
    offsets = (torch.cumsum(per_tile, 0) - per_tile).to(torch.int32)
    return offsets.reshape(C, tile_height, tile_width), flatten_ids
