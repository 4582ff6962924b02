"""Tile intersection: which Gaussians each 16x16 pixel tile must blend, front to back.

Same result as gsplat's ``isect_tiles`` + ``isect_offset_encode`` (vectorised torch instead
of CUDA): a Gaussian is listed in every tile that its 3-sigma square (``means2d ± radius``,
in tile units, floor/ceil) touches, and each tile's list is sorted by depth (stable, so
equal depths keep Gaussian-index order, as gsplat's radix sort does).

With a :class:`Footprint` (Speedy-Splat's SnugBox and AccuTile, CVPR 2025, with the compiled
rasterizer's own footprint) the square is narrowed, tile row by tile row, to the tiles whose pixels
the Gaussian can reach with alpha >= 1/255: the ellipse ``sigma <= log(255 opacity)``, enlarged to
absorb float rounding and visited row by row as ``csrc/rasterize_cpu.cpp`` does (``make_prep``,
``prep_spans``; the hull of the tile columns of a tile row's spans), inside gsplat's 3-sigma square.
A pair left out would visit no pixel, so every image and gradient stays the same, bit for bit, and a
Gaussian of opacity < 1/255 is in no list. A Gaussian of fewer than :data:`FOOTPRINT_MIN_TILES` tiles
keeps them (its footprint is not worth computing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from stealth_ns.raster.torch_backend import ALPHA_MIN

SPAN_PAD = 0.05  # pixels added to each side of a row's span (csrc: kSpanPad)
FOOTPRINT_MIN_TILES = 9
"""A Gaussian whose 3-sigma square covers fewer tiles keeps them all: computing its footprint costs about
what the pair visits it would save (measured with ``stealth-ns bench train``,
docs/design/training_step.md)."""


@dataclass(frozen=True)
class Footprint:
    """What narrows the tile lists: the projected Gaussians' conics ``[C, N, 3]`` (a, b, c of the inverse
    2D covariance), their opacities ``[C, N]`` as the rasterizer blends them, and the image size."""

    conics: Tensor
    opacities: Tensor
    width: int
    height: int


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
    means2d: Tensor,
    radii: Tensor,
    depths: Tensor,
    tile_size: int,
    tile_width: int,
    tile_height: int,
    footprint: Footprint | None = None,
) -> tuple[Tensor, Tensor]:
    """Sorted (camera, tile, depth) intersection lists.

    Args:
        means2d: [C, N, 2], radii: [C, N], depths: [C, N].
        footprint: narrows each Gaussian's tiles to those its alpha >= 1/255 footprint reaches.

    Returns:
        isect_offsets: [C, tile_height, tile_width] int32, start of each tile's list in
            ``flatten_ids`` (the list ends where the next tile's starts, or at the end).
        flatten_ids: [M] int32, indices into the flattened ``C * N`` Gaussians.
    """
    C, N = radii.shape
    device = means2d.device
    tile_min, tile_max = tile_ranges(means2d, radii, tile_size, tile_width, tile_height)
    # One row per (Gaussian, tile row of its rectangle), with the tile columns [x0, x1) it lists there.
    rows = (tile_max[..., 1] - tile_min[..., 1]).reshape(-1)  # [C*N]
    band_gauss = torch.repeat_interleave(torch.arange(C * N, device=device), rows)
    band_y = tile_min.reshape(-1, 2)[band_gauss, 1] + (
        torch.arange(len(band_gauss), device=device) - (torch.cumsum(rows, 0) - rows)[band_gauss]
    )
    x0 = tile_min.reshape(-1, 2)[band_gauss, 0]
    x1 = tile_max.reshape(-1, 2)[band_gauss, 0]
    if footprint is not None and len(band_gauss):
        area = rows * (tile_max[..., 0] - tile_min[..., 0]).reshape(-1)
        single = area[band_gauss] < FOOTPRINT_MIN_TILES
        x0, x1 = _footprint_columns(footprint, means2d, tile_size, band_gauss, band_y, x0, x1, single)
    counts = x1 - x0
    n_tiles = tile_width * tile_height
    total = int(counts.sum())
    if total == 0:
        offsets = torch.zeros((C, tile_height, tile_width), dtype=torch.int32, device=device)
        return offsets, torch.zeros(0, dtype=torch.int32, device=device)

    # One row per (Gaussian, tile) pair: enumerate the columns of each band.
    band = torch.repeat_interleave(torch.arange(len(counts), device=device), counts)
    local = torch.arange(total, device=device) - (torch.cumsum(counts, 0) - counts)[band]
    gauss = band_gauss[band]
    tile_x = x0[band] + local
    tile_y = band_y[band]
    cam = gauss // N
    key = cam * n_tiles + tile_y * tile_width + tile_x

    # Depth order inside a tile, then tile order; both sorts stable.
    order = torch.argsort(depths.reshape(-1)[gauss], stable=True)
    order = order[torch.argsort(key[order], stable=True)]
    flatten_ids = gauss[order].to(torch.int32)

    per_tile = torch.bincount(key, minlength=C * n_tiles)
    offsets = (torch.cumsum(per_tile, 0) - per_tile).to(torch.int32)
    return offsets.reshape(C, tile_height, tile_width), flatten_ids


def _footprint_columns(
    fp: Footprint,
    means2d: Tensor,
    tile_size: int,
    gauss: Tensor,
    ty: Tensor,
    x0: Tensor,
    x1: Tensor,
    single: Tensor,
) -> tuple[Tensor, Tensor]:
    """Each band's tile columns ``[x0, x1)`` (band ``k``: Gaussian ``gauss[k]`` (flat), tile row ``ty[k]``)
    narrowed to the hull of the columns its footprint's row spans reach (see the module docstring); a
    small Gaussian (``single[k]``: fewer tiles than FOOTPRINT_MIN_TILES) keeps them unless its opacity
    is below 1/255."""
    prep = _footprint_prep(fp, means2d.reshape(-1, 2))
    kind, mx, my, two_a_teff, det, inv_a, b_over_a, ext_y = (v[gauss] for v in prep)
    ts, f32 = tile_size, torch.float32
    half, pad = torch.tensor(0.5, dtype=f32), torch.tensor(SPAN_PAD, dtype=f32)  # float32, as in csrc
    # pixel rows of the band inside the image, then those prep_rows keeps ([C*N bands, ts])
    y_base = ty * ts
    y_end = torch.clamp(y_base + ts, max=fp.height)
    lo_row = torch.ceil(my - ext_y - half - pad)
    hi_row = torch.floor(my + ext_y - half + pad) + 1
    i = y_base[:, None] + torch.arange(ts, device=ty.device)[None, :]  # [B, ts] global pixel rows
    live = (i < y_end[:, None]) & (i.to(f32) >= lo_row[:, None]) & (i.to(f32) < hi_row[:, None])
    dy = my[:, None] - (i.to(f32) + half)
    disc = two_a_teff[:, None] - det[:, None] * dy * dy
    inside = disc >= 0
    span = torch.sqrt(torch.where(inside, disc, torch.zeros_like(disc))) * inv_a[:, None]
    centre = mx[:, None] + b_over_a[:, None] * dy
    flo = torch.clamp(torch.ceil(centre - span - half - pad), 0, fp.width).long()
    fhi = torch.clamp(torch.floor(centre + span - half + pad) + 1, 0, fp.width).long()
    hit = live & inside & (fhi > flo)
    big = torch.iinfo(torch.long).max
    hx0 = torch.where(hit, flo // ts, big).amin(dim=1)
    hx1 = torch.where(hit, (fhi - 1) // ts + 1, -1).amax(dim=1)
    ellipse, skip = (kind == 2) & ~single, kind == 0
    nx0 = torch.where(ellipse, torch.maximum(hx0, x0), x0)
    nx1 = torch.where(ellipse, torch.minimum(hx1, x1), x1)
    nx1 = torch.where(skip, nx0, torch.maximum(nx1, nx0))
    return nx0, nx1


def _footprint_prep(fp: Footprint, means2d: Tensor) -> tuple[Tensor, ...]:
    """Per Gaussian (flat ``[C*N]``): csrc's ``make_prep`` -- kind (0 skip: opacity < 1/255, 1 full tile,
    2 ellipse), centre, and the ellipse's row-span terms, computed in float64, kept in float32."""
    con = fp.conics.reshape(-1, 3).to(torch.float64)
    o32 = fp.opacities.reshape(-1).to(torch.float32)
    a, b, c, o = con[:, 0], con[:, 1], con[:, 2], o32.to(torch.float64)
    mx, my = means2d[:, 0].to(torch.float32), means2d[:, 1].to(torch.float32)
    det = a * c - b * b
    t = torch.log(255.0 * o)
    lmax = 0.5 * (a + c) + torch.sqrt(0.25 * (a - c) * (a - c) + b * b)
    lmin = det / lmax
    kappa = (torch.maximum(a, c) + b.abs()) / lmin
    grad = lmax * torch.sqrt(2.0 * (t.abs() + 1.0) / lmin)
    coord = float(torch.tensor(float(fp.width + fp.height), dtype=torch.float32))
    dpad = 4.0 * grad * 1.2e-7 * (coord + mx.double().abs() + my.double().abs())
    teff = t + 1e-6 * kappa * (t.abs() + 1.0) + 1e-4 * (1.0 + t.abs()) + dpad
    ext = torch.sqrt(2.0 * a * teff / det)
    ok = (a > 0) & (c > 0) & (det > 0) & torch.isfinite(det) & torch.isfinite(o)
    ok &= torch.isfinite(mx) & torch.isfinite(my) & torch.isfinite(teff) & torch.isfinite(ext) & (ext <= 1e7)
    kind = torch.where(ok, 2, 1)
    kind = torch.where(o32 < torch.tensor(ALPHA_MIN, dtype=torch.float32), 0, kind)  # make_prep's kSkip
    terms = (2.0 * a * teff, det, 1.0 / a, b / a, ext)
    two_a_teff, det32, inv_a, b_over_a, ext_y = (torch.nan_to_num(v).to(torch.float32) for v in terms)
    return kind, mx, my, two_a_teff, det32, inv_a, b_over_a, ext_y
