"""Brute-force rasterizer for tests: every Gaussian against every pixel, written for clarity.

Pixels are vectorised; Gaussians are walked one at a time in depth order (stable), with the
same rules as gsplat: a Gaussian reaches a pixel only when the pixel's tile lies in the
Gaussian's tile rectangle (its 3-sigma square), alpha = min(0.999, o * exp(-sigma)),
skipped when sigma < 0 or alpha < 1/255, and a pixel is done (exclusively) at the first
Gaussian that would bring its transmittance to <= 1e-4.
"""

from __future__ import annotations

import torch
from torch import Tensor

from stealth_ns.raster.projection import project_gaussians, quat_scale_to_covar, spherical_harmonics
from stealth_ns.raster.tiles import tile_grid, tile_ranges


def brute_force_pixels(
    means2d, conics, colors, opacities, radii, depths, width, height, tile_size=16, backgrounds=None
) -> tuple[Tensor, Tensor]:
    """[C,N,*] projected Gaussians -> colours [C,H,W,D], alphas [C,H,W,1]."""
    C, N, D = colors.shape
    tw, th = tile_grid(width, height, tile_size)
    tmin, tmax = tile_ranges(means2d, radii, tile_size, tw, th)
    ys, xs = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    px, py = xs.to(means2d.dtype) + 0.5, ys.to(means2d.dtype) + 0.5
    tx, ty = xs // tile_size, ys // tile_size
    out_c, out_a = [], []
    for c in range(C):
        T = torch.ones(height, width, dtype=means2d.dtype)
        done = torch.zeros(height, width, dtype=torch.bool)
        acc = torch.zeros(height, width, D, dtype=colors.dtype)
        for g in torch.argsort(depths[c], stable=True).tolist():
            if radii[c, g] <= 0:
                continue
            in_rect = (
                (tx >= tmin[c, g, 0]) & (tx < tmax[c, g, 0]) & (ty >= tmin[c, g, 1]) & (ty < tmax[c, g, 1])
            )
            dx = means2d[c, g, 0] - px
            dy = means2d[c, g, 1] - py
            a, b, cc = conics[c, g]
            sigma = 0.5 * (a * dx * dx + cc * dy * dy) + b * dx * dy
            alpha = torch.clamp(opacities[c, g] * torch.exp(-sigma), max=0.999)
            live = in_rect & ~done & (sigma >= 0) & (alpha >= 1 / 255)
            next_T = T * (1 - alpha)
            stop = live & (next_T <= 1e-4)
            use = live & ~stop
            done = done | stop
            w = torch.where(use, alpha * T, torch.zeros_like(T))
            acc = acc + w[..., None] * colors[c, g]
            T = torch.where(use, next_T, T)
        if backgrounds is not None:
            acc = acc + T[..., None] * backgrounds[c]
        out_c.append(acc)
        out_a.append((1 - T)[..., None])
    return torch.stack(out_c), torch.stack(out_a)


def brute_force_render(
    means,
    quats,
    scales,
    opacities,
    colors,
    viewmats,
    Ks,
    width,
    height,
    sh_degree=None,
    backgrounds=None,
    render_mode="RGB",
):
    """Full reference: projection + SH + brute-force blending, same contract as rasterization()."""
    C = viewmats.shape[0]
    radii, means2d, depths, conics = project_gaussians(
        means, quat_scale_to_covar(quats, scales), viewmats, Ks, width, height
    )
    if sh_degree is not None:
        campos = torch.linalg.inv(viewmats)[:, :3, 3]
        feats = torch.clamp_min(
            spherical_harmonics(sh_degree, means[None] - campos[:, None], colors[None].expand(C, -1, -1, -1))
            + 0.5,
            0.0,
        )
    else:
        feats = colors[None].expand(C, -1, -1)
    if render_mode in ("RGB+D", "RGB+ED"):
        feats = torch.cat([feats, depths[..., None]], -1)
        if backgrounds is not None:
            backgrounds = torch.cat([backgrounds, backgrounds.new_zeros(C, 1)], -1)
    elif render_mode in ("D", "ED"):
        feats = depths[..., None]
        backgrounds = None if backgrounds is None else backgrounds.new_zeros(C, 1)
    img, alpha = brute_force_pixels(
        means2d,
        conics,
        feats,
        opacities[None].expand(C, -1),
        radii,
        depths,
        width,
        height,
        backgrounds=backgrounds,
    )
    if render_mode in ("ED", "RGB+ED"):
        img = torch.cat([img[..., :-1], img[..., -1:] / alpha.clamp(min=1e-10)], -1)
    return img, alpha
