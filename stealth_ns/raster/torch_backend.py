"""Pure-PyTorch tile rasterizer: the readable reference for the compiled CPU backend.

Same contract and results as gsplat 1.4.0's CUDA ``rasterize_to_pixels`` (non-packed):
for every pixel (centre at integer + 0.5) the Gaussians of its tile are blended front to
back with

    sigma = 0.5 * (a dx² + c dy²) + b dx dy,   alpha = min(0.999, opacity * exp(-sigma)),

skipping ``sigma < 0`` or ``alpha < 1/255``, and stopping (exclusively) at the first
Gaussian after which the transmittance would drop to ``1e-4`` or below. The result is
``sum_i c_i alpha_i T_i + T_final * background`` and the alpha ``1 - T_final``.

gsplat clamps alpha at 0.999 (the original 3DGS used 0.99); we follow gsplat so that the
CPU and CUDA backends agree.

Vectorisation: all (tile, Gaussian) pairs of a chunk of tiles are evaluated against the
tile's pixels at once, ``[pairs, tile_size²]``; the transmittance is an exclusive
cumulative product inside each tile's list, computed as a float64 cumulative sum of
``log(1 - alpha)``. Chunks are checkpointed when gradients are needed, so memory stays
bounded by one chunk, not by (pairs x pixels) of the whole image. Gradients come from
autograd.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

ALPHA_MAX = 0.999
ALPHA_MIN = 1.0 / 255.0
T_EPS = 1e-4

# Upper bound on (pairs x pixels) evaluated at once; ~8 float tensors of this size live
# during a chunk, so 2M elements is roughly 100 MB.
CHUNK_ELEMENTS = 2_000_000


def rasterize_to_pixels_torch(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    image_width: int,
    image_height: int,
    tile_size: int,
    isect_offsets: Tensor,
    flatten_ids: Tensor,
    backgrounds: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Alpha-composite projected Gaussians into images.

    Args:
        means2d: [C, N, 2] centres in pixels.
        conics: [C, N, 3] inverse 2D covariance (a, b, c), px⁻².
        colors: [C, N, D] per-Gaussian features to blend.
        opacities: [C, N] in [0, 1].
        image_width, image_height: pixels.
        tile_size: tile edge in pixels (16 in gsplat).
        isect_offsets: [C, tile_height, tile_width] int32 start of each tile's list.
        flatten_ids: [M] int32 indices into the flattened C*N Gaussians, sorted by
            (camera, tile, depth).
        backgrounds: optional [C, D] colour behind everything.

    Returns:
        render_colors: [C, H, W, D]; render_alphas: [C, H, W, 1].
    """
    C, N, D = colors.shape
    tile_height, tile_width = isect_offsets.shape[1:]
    n_tiles = C * tile_height * tile_width
    device, dtype = colors.device, colors.dtype

    starts = isect_offsets.reshape(-1).long()
    ends = torch.cat([starts[1:], torch.tensor([flatten_ids.numel()], device=device)])
    counts = (ends - starts).tolist()
    starts_list = starts.tolist()

    flat = (means2d.reshape(C * N, 2), conics.reshape(C * N, 3), colors.reshape(C * N, D))
    flat_opac = opacities.reshape(C * N)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in (*flat, flat_opac))

    pix = tile_size * tile_size
    out_colors, out_logt = [], []
    tile = 0
    while tile < n_tiles:
        # Grow the chunk of tiles until it holds CHUNK_ELEMENTS (pairs x pixels); at least one tile.
        last, pairs = tile, counts[tile]
        while last + 1 < n_tiles and (pairs + counts[last + 1]) * pix <= CHUNK_ELEMENTS:
            last += 1
            pairs += counts[last]
        t0, t1 = tile, last + 1
        p0, p1 = starts_list[t0], starts_list[t0] + pairs
        args = (t0, t1, counts[t0:t1], flatten_ids[p0:p1].long(), tile_size, tile_width, tile_height)
        if pairs == 0:
            out_colors.append(torch.zeros((t1 - t0, pix, D), device=device, dtype=dtype))
            out_logt.append(torch.zeros((t1 - t0, pix), device=device, dtype=torch.float64))
        elif needs_grad:
            col, logt = checkpoint(_blend_chunk, *flat, flat_opac, *args, use_reentrant=False)
            out_colors.append(col)
            out_logt.append(logt)
        else:
            col, logt = _blend_chunk(*flat, flat_opac, *args)
            out_colors.append(col)
            out_logt.append(logt)
        tile = t1

    colors_t = torch.cat(out_colors, 0)  # [n_tiles, pix, D]
    trans = torch.exp(torch.cat(out_logt, 0)).to(dtype)  # [n_tiles, pix]
    if backgrounds is not None:
        cam_of_tile = torch.arange(n_tiles, device=device) // (tile_height * tile_width)
        colors_t = colors_t + trans[..., None] * backgrounds[cam_of_tile][:, None, :]
    alphas_t = 1.0 - trans
    return (
        _tiles_to_image(colors_t, C, tile_height, tile_width, tile_size, image_height, image_width),
        _tiles_to_image(
            alphas_t[..., None], C, tile_height, tile_width, tile_size, image_height, image_width
        ),
    )


def _blend_chunk(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    t0: int,
    t1: int,
    counts: list[int],
    ids: Tensor,
    tile_size: int,
    tile_width: int,
    tile_height: int,
) -> tuple[Tensor, Tensor]:
    """Blend tiles ``t0..t1-1``; returns their colours [T, pix, D] and log-transmittance [T, pix]."""
    device = means2d.device
    n = t1 - t0
    pair_tile = torch.repeat_interleave(
        torch.arange(n, device=device), torch.tensor(counts, device=device)
    )  # [P] local tile of each pair
    tile_global = pair_tile + t0
    in_cam = tile_global % (tile_height * tile_width)
    ty, tx = in_cam // tile_width, in_cam % tile_width

    offs = torch.arange(tile_size, device=device, dtype=means2d.dtype)
    oy, ox = torch.meshgrid(offs, offs, indexing="ij")
    px = (tx * tile_size).to(means2d.dtype)[:, None] + ox.reshape(1, -1) + 0.5  # [P, pix]
    py = (ty * tile_size).to(means2d.dtype)[:, None] + oy.reshape(1, -1) + 0.5

    mean = means2d[ids]
    conic = conics[ids]
    dx = mean[:, 0:1] - px
    dy = mean[:, 1:2] - py
    sigma = 0.5 * (conic[:, 0:1] * dx * dx + conic[:, 2:3] * dy * dy) + conic[:, 1:2] * dx * dy
    alpha = torch.clamp(opacities[ids][:, None] * torch.exp(-sigma), max=ALPHA_MAX)
    valid = (sigma >= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(valid, alpha, torch.zeros_like(alpha))

    # Exclusive cumulative log-transmittance inside each tile's list (float64 for accuracy).
    log1m = torch.log1p(-alpha.double())
    csum = torch.cumsum(log1m, 0)
    first = torch.cumsum(torch.tensor(counts, device=device), 0) - torch.tensor(counts, device=device)
    base = (csum - log1m)[first.clamp(max=max(len(ids) - 1, 0))]  # [T, pix] cumsum before each list
    excl = csum - log1m - base[pair_tile]
    next_t = torch.exp(excl + log1m)
    contrib = valid & (next_t > T_EPS)

    weight = alpha * torch.exp(excl).to(alpha.dtype) * contrib
    out_col = torch.zeros((n, weight.shape[1], colors.shape[1]), device=device, dtype=colors.dtype)
    out_col = out_col.index_add(0, pair_tile, weight[..., None] * colors[ids][:, None, :])
    out_logt = torch.zeros((n, weight.shape[1]), device=device, dtype=torch.float64)
    out_logt = out_logt.index_add(0, pair_tile, torch.where(contrib, log1m, torch.zeros_like(log1m)))
    return out_col, out_logt


def _tiles_to_image(
    x: Tensor, C: int, tile_height: int, tile_width: int, tile_size: int, height: int, width: int
) -> Tensor:
    """[C*th*tw, ts*ts, D] tile-major values -> [C, H, W, D] image (cropped)."""
    D = x.shape[-1]
    img = x.reshape(C, tile_height, tile_width, tile_size, tile_size, D).permute(0, 1, 3, 2, 4, 5)
    img = img.reshape(C, tile_height * tile_size, tile_width * tile_size, D)
    return img[:, :height, :width]
