"""The compiled CPU rasterizer (stealth_ns/raster/csrc/rasterize_cpu.cpp) against references.

* a brute-force per-tile reference written here (sequential front-to-back compositing with
  gsplat's skip / early-stop rules, gradients by autograd, no division trick);
* gsplat's pure-torch tile intersection (``_isect_tiles`` + ``_isect_offset_encode``);
* the lead's vectorised pure-PyTorch backend (``torch_backend.rasterize_to_pixels_torch``).

If the extension does not compile these tests FAIL (they do not skip): the machine is
expected to have g++ and ninja.
"""

from __future__ import annotations

import math
import os
import shutil
import sys

import pytest
import torch

from stealth_ns.raster import cpp_backend

ALPHA_MAX = 0.999
ALPHA_MIN = 1.0 / 255.0
T_EPS = 1e-4


@pytest.fixture(scope="module")
def ext():
    mod = cpp_backend.load_extension()
    assert mod is not None, f"C++ rasterizer failed to compile: {cpp_backend.compile_error()}"
    return mod


# ----------------------------------------------------------------------------------------------
# Synthetic inputs
# ----------------------------------------------------------------------------------------------
def make_gaussians(
    C: int,
    N: int,
    W: int,
    H: int,
    D: int = 3,
    seed: int = 0,
    scale_range: tuple[float, float] = (0.8, 6.0),
    anisotropic: bool = False,
    margin: float = 0.15,
    discrete_depths: bool = False,
):
    """Projected Gaussians as the projection stage would produce them (radius = 3 sigma, gsplat)."""
    g = torch.Generator().manual_seed(seed)
    means2d = torch.empty(C, N, 2)
    means2d[..., 0] = (torch.rand(C, N, generator=g) * (1 + 2 * margin) - margin) * W
    means2d[..., 1] = (torch.rand(C, N, generator=g) * (1 + 2 * margin) - margin) * H
    lo, hi = scale_range
    s = lo + (hi - lo) * torch.rand(C, N, 2, generator=g)
    if anisotropic:
        s[..., 0] *= 8.0
        s[..., 1] = s[..., 1].clamp(max=1.2) * 0.4
    theta = torch.rand(C, N, generator=g) * math.pi
    ct, st = torch.cos(theta), torch.sin(theta)
    R = torch.stack([torch.stack([ct, -st], -1), torch.stack([st, ct], -1)], -2)  # [C, N, 2, 2]
    cov = R @ torch.diag_embed(s**2) @ R.transpose(-1, -2) + 0.3 * torch.eye(2)
    det = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] ** 2
    conics = torch.stack([cov[..., 1, 1] / det, -cov[..., 0, 1] / det, cov[..., 0, 0] / det], -1)
    b = 0.5 * (cov[..., 0, 0] + cov[..., 1, 1])
    lam = b + torch.sqrt(torch.clamp(b * b - det, min=0.01))
    radii = torch.ceil(3.0 * torch.sqrt(lam))
    inside = (
        (means2d[..., 0] + radii > 0)
        & (means2d[..., 0] - radii < W)
        & (means2d[..., 1] + radii > 0)
        & (means2d[..., 1] - radii < H)
    )
    radii = torch.where(inside, radii, torch.zeros_like(radii)).int()
    if discrete_depths:
        depths = torch.randint(1, 4, (C, N), generator=g).float()
    else:
        depths = 1.0 + 9.0 * torch.rand(C, N, generator=g)
    opacities = 0.05 + 0.94 * torch.rand(C, N, generator=g)
    colors = torch.rand(C, N, D, generator=g)
    return means2d, conics.contiguous(), colors, opacities, radii, depths


def gsplat_isect(means2d, radii, depths, tile_size, W, H):
    from gsplat.cuda._torch_impl import _isect_offset_encode, _isect_tiles

    C = means2d.shape[0]
    tw, th = math.ceil(W / tile_size), math.ceil(H / tile_size)
    _, isect_ids, flatten_ids = _isect_tiles(means2d, radii, depths, tile_size, tw, th)
    offsets = _isect_offset_encode(isect_ids, C, tw, th)
    return offsets.int().contiguous(), flatten_ids.int().contiguous()


def isect(means2d, radii, depths, tile_size, W, H):
    tw, th = math.ceil(W / tile_size), math.ceil(H / tile_size)
    return cpp_backend.isect_tiles_cpp(means2d, radii, depths, tile_size, tw, th)


# ----------------------------------------------------------------------------------------------
# Brute-force reference
# ----------------------------------------------------------------------------------------------
def reference_rasterize(means2d, conics, colors, opacities, W, H, tile_size, offsets, flatten_ids, bgs=None):
    """Per tile: sequential gsplat compositing decisions, differentiable weights via autograd."""
    C, N, D = colors.shape
    th, tw = offsets.shape[1:]
    n_isects = flatten_ids.numel()
    flat_off = offsets.reshape(-1).tolist() + [n_isects]
    out_c = [[None] * th for _ in range(C)]
    out_a = [[None] * th for _ in range(C)]
    m2 = means2d.reshape(C * N, 2)
    cn = conics.reshape(C * N, 3)
    co = colors.reshape(C * N, D)
    op = opacities.reshape(C * N)
    rows_c, rows_a = [], []
    for c in range(C):
        img_rows_c, img_rows_a = [], []
        for ty in range(th):
            tiles_c, tiles_a = [], []
            for tx in range(tw):
                t = (c * th + ty) * tw + tx
                ids = flatten_ids[flat_off[t] : flat_off[t + 1]].long()
                x0, y0 = tx * tile_size, ty * tile_size
                xs = torch.arange(x0, min(x0 + tile_size, W), dtype=torch.float32) + 0.5
                ys = torch.arange(y0, min(y0 + tile_size, H), dtype=torch.float32) + 0.5
                hh, ww = len(ys), len(xs)
                py, px = torch.meshgrid(ys, xs, indexing="ij")
                px, py = px.reshape(-1), py.reshape(-1)
                K = len(ids)
                if K == 0:
                    col = torch.zeros(hh * ww, D)
                    T = torch.ones(hh * ww)
                else:
                    dx = m2[ids, 0:1] - px[None]
                    dy = m2[ids, 1:2] - py[None]
                    a, b, cc = cn[ids, 0:1], cn[ids, 1:2], cn[ids, 2:3]
                    sigma = 0.5 * (a * dx * dx + cc * dy * dy) + b * dx * dy
                    alpha = torch.clamp(op[ids][:, None] * torch.exp(-sigma), max=ALPHA_MAX)  # [K, P]
                    with torch.no_grad():
                        valid = (sigma >= 0) & (alpha >= ALPHA_MIN)
                        contrib = torch.zeros_like(valid)
                        Tr = torch.ones(hh * ww)
                        done = torch.zeros(hh * ww, dtype=torch.bool)
                        for k in range(K):
                            v = valid[k] & ~done
                            nt = Tr * (1.0 - alpha[k])
                            term = v & (nt <= T_EPS)
                            done |= term
                            ok = v & ~term
                            Tr = torch.where(ok, nt, Tr)
                            contrib[k] = ok
                    a_c = alpha * contrib
                    one_m = 1.0 - a_c
                    Tb = torch.cumprod(torch.cat([torch.ones(1, hh * ww), one_m[:-1]], 0), 0)
                    w = a_c * Tb
                    col = (w[..., None] * co[ids][:, None, :]).sum(0)
                    T = torch.prod(one_m, 0)
                if bgs is not None:
                    col = col + T[:, None] * bgs[c][None]
                tiles_c.append(col.reshape(hh, ww, D))
                tiles_a.append((1.0 - T).reshape(hh, ww, 1))
            img_rows_c.append(torch.cat(tiles_c, 1))
            img_rows_a.append(torch.cat(tiles_a, 1))
        rows_c.append(torch.cat(img_rows_c, 0))
        rows_a.append(torch.cat(img_rows_a, 0))
    del out_c, out_a
    return torch.stack(rows_c), torch.stack(rows_a)


# ----------------------------------------------------------------------------------------------
# Comparison helpers
# ----------------------------------------------------------------------------------------------
def run_both(fn_a, fn_b, inputs, W, H, tile_size, offsets, flatten_ids, bgs=None, seed=1):
    """Forward + backward of two implementations with the same random upstream gradients."""
    results = []
    for fn in (fn_a, fn_b):
        leaves = [t.detach().clone().requires_grad_(True) for t in inputs]
        bg = bgs.detach().clone().requires_grad_(True) if bgs is not None else None
        rc, ra = fn(*leaves, W, H, tile_size, offsets, flatten_ids, bg)
        g = torch.Generator().manual_seed(seed)
        wc = torch.randn(rc.shape, generator=g)
        wa = torch.randn(ra.shape, generator=g)
        loss = (rc * wc).sum() + (ra * wa).sum()
        loss.backward()
        grads = [t.grad if t.grad is not None else torch.zeros_like(t) for t in leaves]
        if bg is not None:
            grads.append(bg.grad)
        results.append((rc.detach(), ra.detach(), grads))
    return results


def assert_close_grads(got, ref, names, rel=1e-3, elementwise=True):
    for name, g, r in zip(names, got, ref, strict=True):
        assert g.shape == r.shape, (name, g.shape, r.shape)
        assert torch.isfinite(g).all(), name
        err = (g - r).norm().item()
        scale = r.norm().item()
        assert err <= rel * scale + 1e-6, f"{name}: |diff| {err:.3e} vs rel*|ref| {rel * scale:.3e}"
        if elementwise:
            atol = 1e-5 + 1e-4 * r.abs().max().item()
            torch.testing.assert_close(g, r, rtol=rel, atol=atol, msg=lambda m, n=name: f"{n}: {m}")


GRAD_NAMES = ["means2d", "conics", "colors", "opacities"]


def check_against_reference(
    C, N, W, H, D=3, tile_size=16, seed=0, with_bg=True, isect_fn=isect, elementwise=True, **kw
):
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, D, seed=seed, **kw)
    offsets, flatten_ids = isect_fn(means2d, radii, depths, tile_size, W, H)
    bgs = torch.rand(C, D, generator=torch.Generator().manual_seed(seed + 7)) if with_bg else None
    (rc, ra, g), (rc_ref, ra_ref, g_ref) = run_both(
        cpp_backend.rasterize_to_pixels_cpp,
        reference_rasterize,
        (means2d, conics, colors, opacities),
        W,
        H,
        tile_size,
        offsets,
        flatten_ids,
        bgs,
        seed=seed,
    )
    assert rc.shape == (C, H, W, D) and ra.shape == (C, H, W, 1)
    torch.testing.assert_close(rc, rc_ref, rtol=0, atol=1e-4)
    torch.testing.assert_close(ra, ra_ref, rtol=0, atol=1e-4)
    names = GRAD_NAMES + (["backgrounds"] if with_bg else [])
    assert_close_grads(g, g_ref, names, elementwise=elementwise)
    return flatten_ids.numel()


# ----------------------------------------------------------------------------------------------
# Tests
# ----------------------------------------------------------------------------------------------
def test_extension_compiles(ext):
    assert hasattr(ext, "rasterize_fwd") and hasattr(ext, "rasterize_bwd") and hasattr(ext, "isect_tiles")
    assert cpp_backend.compile_error() is None


@pytest.mark.parametrize(
    "C,N,W,H,tile_size,discrete",
    [
        (1, 60, 37, 29, 16, False),
        (2, 80, 50, 33, 16, True),
        (1, 40, 20, 20, 8, True),
        (2, 0, 16, 16, 16, False),
    ],
)
def test_isect_tiles_matches_gsplat(ext, C, N, W, H, tile_size, discrete):
    means2d, conics, colors, opacities, radii, depths = make_gaussians(
        C, N, W, H, seed=3, discrete_depths=discrete
    )
    off_ref, fid_ref = gsplat_isect(means2d, radii, depths, tile_size, W, H)
    off, fid = isect(means2d, radii, depths, tile_size, W, H)
    assert off.dtype == torch.int32 and fid.dtype == torch.int32
    assert torch.equal(off, off_ref)
    if not discrete:
        assert torch.equal(fid, fid_ref)
    else:
        # gsplat's python reference uses an unstable torch.sort: equal depths may come in any
        # order there (its CUDA radix sort is stable: Gaussian-index order, as ours).
        assert torch.equal(depths.reshape(-1)[fid.long()], depths.reshape(-1)[fid_ref.long()])
        bounds = off.reshape(-1).tolist() + [fid.numel()]
        for s, e in zip(bounds[:-1], bounds[1:], strict=True):
            assert sorted(fid[s:e].tolist()) == sorted(fid_ref[s:e].tolist())
            key = [(depths.reshape(-1)[i].item(), i) for i in fid[s:e].tolist()]
            assert key == sorted(key)  # stable: ties by Gaussian index


def test_isect_tiles_matches_lead_torch(ext):
    from stealth_ns.raster.tiles import isect_tiles as torch_isect

    C, N, W, H = 2, 3000, 200, 130
    means2d, conics, colors, opacities, radii, depths = make_gaussians(
        C, N, W, H, seed=5, discrete_depths=True
    )
    tw, th = math.ceil(W / 16), math.ceil(H / 16)
    off_ref, fid_ref = torch_isect(means2d, radii, depths, 16, tw, th)
    off, fid = cpp_backend.isect_tiles_cpp(means2d, radii, depths, 16, tw, th)
    assert torch.equal(off, off_ref.int())
    assert torch.equal(fid, fid_ref.int())


def test_forward_backward_small(ext):
    n = check_against_reference(1, 50, 40, 30, D=3, seed=0)
    assert n > 0


def test_gsplat_isect_input(ext):
    check_against_reference(1, 40, 35, 21, D=3, seed=11, isect_fn=gsplat_isect)


def test_one_gaussian(ext):
    for seed in range(3):
        check_against_reference(1, 1, 24, 18, D=3, seed=seed, margin=0.0, scale_range=(2.0, 5.0))


def test_no_gaussians(ext):
    W, H, C, D = 23, 17, 2, 3
    means2d = torch.zeros(C, 0, 2)
    conics = torch.zeros(C, 0, 3)
    colors = torch.zeros(C, 0, D)
    opac = torch.zeros(C, 0)
    offsets = torch.zeros(C, 2, 2, dtype=torch.int32)
    fids = torch.zeros(0, dtype=torch.int32)
    bgs = torch.tensor([[0.1, 0.2, 0.3], [0.5, 0.6, 0.7]], requires_grad=True)
    rc, ra = cpp_backend.rasterize_to_pixels_cpp(means2d, conics, colors, opac, W, H, 16, offsets, fids, bgs)
    assert torch.equal(ra, torch.zeros(C, H, W, 1))
    assert torch.allclose(rc, bgs.detach()[:, None, None, :].expand(C, H, W, D))
    rc.sum().backward()
    assert torch.allclose(bgs.grad, torch.full((C, D), float(H * W)))
    # radii all zero: Gaussians exist but hit no tile
    m, cn, col, op, radii, depths = make_gaussians(C, 10, W, H, seed=2)
    off, fid = isect(m, torch.zeros_like(radii), depths, 16, W, H)
    assert fid.numel() == 0
    rc, ra = cpp_backend.rasterize_to_pixels_cpp(m, cn, col, op, W, H, 16, off, fid)
    assert torch.equal(rc, torch.zeros(C, H, W, D)) and torch.equal(ra, torch.zeros(C, H, W, 1))


def test_partly_offscreen_nonsquare(ext):
    # big margin -> many Gaussians centred off screen; W, H not multiples of 16
    check_against_reference(1, 120, 53, 37, D=3, seed=4, margin=0.5, scale_range=(2.0, 9.0))


def test_anisotropic(ext):
    check_against_reference(1, 80, 64, 48, D=3, seed=6, anisotropic=True)


@pytest.mark.parametrize("D", [1, 2, 4, 7])
def test_channels_two_cameras(ext, D):
    check_against_reference(2, 70, 41, 26, D=D, seed=20 + D)


@pytest.mark.parametrize("tile_size", [12, 20])
def test_tile_sizes_not_a_multiple_of_the_vector_width(ext, tile_size):
    # 12: two 8-pixel blocks per tile row, the second partly outside the tile; 20: three blocks per row
    check_against_reference(1, 90, 45, 31, D=3, seed=30 + tile_size, tile_size=tile_size)


def test_isect_tiles_same_lists_for_any_thread_count(ext):
    # the lists are binned by a parallel counting sort: each thread's chunk of the depth order
    # must land after the chunks of the threads before it
    C, N, W, H = 2, 400, 70, 45
    means2d, _, _, _, radii, depths = make_gaussians(C, N, W, H, seed=5, discrete_depths=True)
    tw, th = math.ceil(W / 8), math.ceil(H / 8)
    lists = [ext.isect_tiles(means2d, radii, depths, 8, tw, th, n) for n in (1, 2, 3, 5)]
    assert lists[0][1].numel() > 2 * N
    for other in lists[1:]:
        assert all(torch.equal(a, b) for a, b in zip(lists[0], other, strict=True))


def test_no_background(ext):
    check_against_reference(2, 70, 33, 40, D=4, seed=9, with_bg=False)


def test_dense_saturation(ext):
    # many opaque Gaussians per pixel: exercises early termination (T <= 1e-4) and the 0.999 clamp
    C, N, W, H, D = 1, 150, 32, 32, 3
    means2d, conics, colors, opacities, radii, depths = make_gaussians(
        C, N, W, H, D, seed=12, scale_range=(4.0, 10.0), margin=0.0
    )
    opacities = torch.where(
        torch.rand(C, N, generator=torch.Generator().manual_seed(0)) < 0.3, 1.0, opacities
    )
    offsets, fids = isect(means2d, radii, depths, 16, W, H)
    (rc, ra, g), (rc_ref, ra_ref, g_ref) = run_both(
        cpp_backend.rasterize_to_pixels_cpp,
        reference_rasterize,
        (means2d, conics, colors, opacities),
        W,
        H,
        16,
        offsets,
        fids,
        torch.rand(C, D),
    )
    assert (ra > 1 - 2e-4).float().mean() > 0.3  # the early stop is actually hit
    torch.testing.assert_close(rc, rc_ref, rtol=0, atol=1e-4)
    torch.testing.assert_close(ra, ra_ref, rtol=0, atol=1e-4)
    assert_close_grads(g, g_ref, GRAD_NAMES + ["backgrounds"], elementwise=False)


def test_odd_tile_size_and_degenerate_conics(ext):
    # tile size 8, plus non-positive-definite / NaN-free degenerate conics (full-tile scan path)
    C, N, W, H, D = 1, 40, 30, 22, 3
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, D, seed=13)
    conics[0, :5, 1] = 2.0 * torch.sqrt(conics[0, :5, 0] * conics[0, :5, 2])  # indefinite
    conics[0, 5:8, 0] = -0.1  # negative
    offsets, fids = isect(means2d, radii, depths, 8, W, H)
    (rc, ra, g), (rc_ref, ra_ref, g_ref) = run_both(
        cpp_backend.rasterize_to_pixels_cpp,
        reference_rasterize,
        (means2d, conics, colors, opacities),
        W,
        H,
        8,
        offsets,
        fids,
        None,
    )
    torch.testing.assert_close(rc, rc_ref, rtol=0, atol=1e-4)
    torch.testing.assert_close(ra, ra_ref, rtol=0, atol=1e-4)
    assert_close_grads(g, g_ref, GRAD_NAMES, elementwise=False)


def _raw_fwd_bwd(ext, C, N, W, H, D, seed, cull, mode, n_threads=0, **kw):
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, D, seed=seed, **kw)
    offsets, fids = isect(means2d, radii, depths, 16, W, H)
    bgs = torch.rand(C, D, generator=torch.Generator().manual_seed(seed))
    rc, ra, last, T = ext.rasterize_fwd(
        means2d, conics, colors, opacities, bgs, W, H, 16, offsets, fids, cull, n_threads
    )
    g = torch.Generator().manual_seed(seed)
    vc, va = torch.randn(rc.shape, generator=g), torch.randn(ra.shape, generator=g)
    grads = ext.rasterize_bwd(
        means2d,
        conics,
        colors,
        opacities,
        bgs,
        W,
        H,
        16,
        offsets,
        fids,
        T,
        last,
        vc,
        va,
        cull,
        mode,
        n_threads,
    )
    return (rc, ra, last, T), grads


def test_culling_is_exact(ext):
    """The per-Gaussian footprint culling changes the work, never the result (bitwise)."""
    for kw in ({}, {"anisotropic": True}):
        (f1, g1) = _raw_fwd_bwd(ext, 2, 400, 77, 61, 3, 31, cull=True, mode=0, **kw)
        (f0, g0) = _raw_fwd_bwd(ext, 2, 400, 77, 61, 3, 31, cull=False, mode=0, **kw)
        for a, b in zip(f1 + tuple(g1), f0 + tuple(g0), strict=True):
            assert torch.equal(a, b)


def test_accumulation_modes_and_threads(ext):
    """Deterministic mode 0 vs atomics (1) vs per-thread buffers (2), 1 vs 2 threads."""
    (f0, g0) = _raw_fwd_bwd(ext, 1, 500, 96, 64, 5, 8, cull=True, mode=0, n_threads=1)
    (f0b, g0b) = _raw_fwd_bwd(ext, 1, 500, 96, 64, 5, 8, cull=True, mode=0, n_threads=2)
    for a, b in zip(f0 + tuple(g0), f0b + tuple(g0b), strict=True):
        assert torch.equal(a, b)  # mode 0 is independent of the thread count / schedule
    for mode in (1, 2):
        (_, g) = _raw_fwd_bwd(ext, 1, 500, 96, 64, 5, 8, cull=True, mode=mode, n_threads=2)
        for a, b in zip(g, g0, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_last_ids_and_transmittance(ext):
    (rc, ra, last, T), _ = _raw_fwd_bwd(ext, 1, 100, 40, 40, 3, 2, cull=True, mode=0)
    torch.testing.assert_close(ra[..., 0], 1.0 - T, rtol=0, atol=0)
    assert (last >= -1).all()
    assert torch.equal(last < 0, T == 1.0)


def test_non_contiguous_and_dtype_inputs(ext):
    C, N, W, H, D = 1, 50, 40, 30, 3
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, D, seed=17)
    offsets, fids = isect(means2d, radii, depths, 16, W, H)
    rc_ref, ra_ref = cpp_backend.rasterize_to_pixels_cpp(
        means2d, conics, colors, opacities, W, H, 16, offsets, fids
    )
    colors_nc = torch.stack([colors, colors], -1)[..., 0]
    assert not colors_nc.is_contiguous()
    rc, ra = cpp_backend.rasterize_to_pixels_cpp(
        means2d.double(), conics, colors_nc, opacities, W, H, 16, offsets.long(), fids.long()
    )
    assert torch.equal(rc, rc_ref) and torch.equal(ra, ra_ref)


@pytest.mark.parametrize("D,C", [(3, 2), (4, 1)])
def test_against_lead_torch_backend(ext, D, C):
    from stealth_ns.raster.torch_backend import rasterize_to_pixels_torch

    N, W, H = 2000, 100, 70
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, D, seed=40 + D)
    offsets, fids = isect(means2d, radii, depths, 16, W, H)
    bgs = torch.rand(C, D, generator=torch.Generator().manual_seed(3))
    (rc, ra, g), (rc_ref, ra_ref, g_ref) = run_both(
        cpp_backend.rasterize_to_pixels_cpp,
        rasterize_to_pixels_torch,
        (means2d, conics, colors, opacities),
        W,
        H,
        16,
        offsets,
        fids,
        bgs,
    )
    torch.testing.assert_close(rc, rc_ref, rtol=0, atol=1e-4)
    torch.testing.assert_close(ra, ra_ref, rtol=0, atol=1e-4)
    assert_close_grads(g, g_ref, GRAD_NAMES + ["backgrounds"], elementwise=False)


def test_bigger_random_against_reference(ext):
    # 600 Gaussians, 2 cameras, D=4: many tiles with long lists
    check_against_reference(2, 600, 70, 52, D=4, seed=77, elementwise=False)


def test_rasterization_pipeline_cpp_vs_torch(ext):
    """Full pipeline through the lead's ``rasterization`` (projection + tiles + kernel)."""
    from stealth_ns.raster import rasterization

    g = torch.Generator().manual_seed(0)
    N, W, H = 300, 48, 40
    means = torch.randn(N, 3, generator=g) * 0.8 + torch.tensor([0.0, 0.0, 4.0])
    quats = torch.nn.functional.normalize(torch.randn(N, 4, generator=g), dim=-1)
    scales = torch.rand(N, 3, generator=g) * 0.1 + 0.02
    opac = torch.rand(N, generator=g) * 0.9 + 0.05
    colors = torch.rand(N, 3, generator=g)
    viewmats = torch.eye(4)[None]
    Ks = torch.tensor([[[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]]])
    outs = []
    for backend in ("cpp", "torch"):
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]
        rc, ra, info = rasterization(*leaves, viewmats, Ks, W, H, backend=backend, render_mode="RGB+D")
        (rc.square().sum() + ra.sum()).backward()
        outs.append((rc.detach(), ra.detach(), [t.grad for t in leaves]))
    (rc, ra, g1), (rc_ref, ra_ref, g_ref) = outs
    torch.testing.assert_close(rc, rc_ref, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(ra, ra_ref, rtol=0, atol=1e-4)
    assert_close_grads(g1, g_ref, ["means", "quats", "scales", "opacities", "colors"], elementwise=False)


def test_culling_is_exact_stress(ext):
    """Footprint culling vs full-tile scan, bitwise, on awkward shapes and large coordinates."""
    g = torch.Generator().manual_seed(123)
    C, N, W, H, D = 1, 3000, 1500, 90, 2
    means2d = torch.stack([torch.rand(C, N, generator=g) * W, torch.rand(C, N, generator=g) * H], -1)
    # log-uniform scales over 3 decades, random rotation: from needles to blobs
    s = torch.exp(torch.empty(C, N, 2).uniform_(math.log(0.3), math.log(60.0), generator=g))
    th = torch.rand(C, N, generator=g) * math.pi
    ct, st = torch.cos(th), torch.sin(th)
    R = torch.stack([torch.stack([ct, -st], -1), torch.stack([st, ct], -1)], -2)
    cov = R @ torch.diag_embed(s**2) @ R.transpose(-1, -2) + 0.3 * torch.eye(2)
    det = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] ** 2
    conics = torch.stack([cov[..., 1, 1] / det, -cov[..., 0, 1] / det, cov[..., 0, 0] / det], -1).contiguous()
    opac = torch.where(
        torch.rand(C, N, generator=g) < 0.1, torch.full((C, N), 1.0 / 255.0), torch.rand(C, N, generator=g)
    )
    radii = torch.full((C, N), 40, dtype=torch.int32)  # generous lists: many far, near-threshold pixels
    depths = torch.rand(C, N, generator=g)
    off, fid = isect(means2d, radii, depths, 16, W, H)
    colors = torch.rand(C, N, D, generator=g)
    outs = []
    for cull in (True, False):
        rc, ra, last, T = ext.rasterize_fwd(means2d, conics, colors, opac, None, W, H, 16, off, fid, cull, 0)
        gen = torch.Generator().manual_seed(1)
        vc, va = torch.randn(rc.shape, generator=gen), torch.randn(ra.shape, generator=gen)
        grads = ext.rasterize_bwd(
            means2d, conics, colors, opac, None, W, H, 16, off, fid, T, last, vc, va, cull, 0, 0
        )
        outs.append((rc, ra, last, T, *grads))
    for a, b in zip(*outs, strict=True):
        assert torch.equal(a, b)


def test_isect_tiles_depth_order_edge_cases(ext):
    """Negative / zero / equal depths sort like the stable float sort of the torch backend."""
    from stealth_ns.raster.tiles import isect_tiles as torch_isect

    g = torch.Generator().manual_seed(8)
    C, N, W, H = 2, 400, 64, 48
    means2d = torch.rand(C, N, 2, generator=g) * torch.tensor([W, H])
    radii = torch.randint(1, 20, (C, N), generator=g, dtype=torch.int32)
    radii[:, ::7] = 0  # some not rendered
    depths = torch.randint(-3, 4, (C, N), generator=g).float() * 0.5
    depths[0, :5] = -0.0
    depths[1, :5] = torch.tensor([1e-30, -1e-30, 3e38, -3e38, 0.0])
    off_ref, fid_ref = torch_isect(means2d, radii, depths, 16, 4, 3)
    off, fid = cpp_backend.isect_tiles_cpp(means2d, radii, depths, 16, 4, 3)
    assert torch.equal(off, off_ref.int())
    assert torch.equal(fid, fid_ref.int())


def test_compile_failure_is_reported(tmp_path):
    """A broken compiler gives load_extension() -> None with the reason, not an exception."""
    import subprocess

    code = (
        "from stealth_ns.raster import cpp_backend as cb\n"
        "assert cb.load_extension() is None\n"
        "err = cb.compile_error()\n"
        "assert err and '/bin/false' in err, err\n"
        "print('ok')\n"
    )
    env = dict(os.environ, STEALTH_NS_CACHE=str(tmp_path), CXX="/bin/false")
    env.pop("STEALTH_NS_DISABLE_CPP", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-2000:]
    env = dict(os.environ, STEALTH_NS_DISABLE_CPP="1")
    code = (
        "from stealth_ns.raster import cpp_backend as cb\n"
        "assert cb.load_extension() is None\n"
        "print(cb.compile_error())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "STEALTH_NS_DISABLE_CPP" in out.stdout, out.stderr[-2000:]


def test_bad_lists_raise(ext):
    C, N, W, H = 1, 5, 20, 20
    m, cn, col, op, radii, depths = make_gaussians(C, N, W, H, seed=1)
    off, fid = isect(m, radii, depths, 16, W, H)
    bad = fid.clone()
    bad[0] = N  # out of range
    with pytest.raises(RuntimeError, match="flatten_ids"):
        cpp_backend.rasterize_to_pixels_cpp(m, cn, col, op, W, H, 16, off, bad)
    bad_off = off.clone()
    bad_off.view(-1)[-1] = fid.numel() + 5
    with pytest.raises(RuntimeError, match="isect_offsets"):
        cpp_backend.rasterize_to_pixels_cpp(m, cn, col, op, W, H, 16, bad_off, fid)


# ----------------------------------------------------------------------------------------------
# Footprint-narrowed tile lists (issue 33: SnugBox + AccuTile with the rasterizer's own footprint)
# ----------------------------------------------------------------------------------------------
def _lists(fn, means2d, radii, depths, W, H, conics=None, opacities=None, tile_size=16):
    from stealth_ns.raster.tiles import Footprint

    tw, th = math.ceil(W / tile_size), math.ceil(H / tile_size)
    fp = None if conics is None else Footprint(conics, opacities, W, H)
    return fn(means2d, radii, depths, tile_size, tw, th, fp)


@pytest.mark.parametrize("seed", [0, 3])
def test_footprint_lists_are_a_subset_the_torch_reference_agrees_on(ext, seed):
    from stealth_ns.raster.tiles import isect_tiles as torch_isect

    C, N, W, H = 2, 3000, 203, 131
    means2d, conics, _, opacities, radii, depths = make_gaussians(C, N, W, H, seed=seed)
    opacities[0, :40] = 0.002  # below 1/255: in no list
    full = _lists(cpp_backend.isect_tiles_cpp, means2d, radii, depths, W, H)
    narrow = _lists(cpp_backend.isect_tiles_cpp, means2d, radii, depths, W, H, conics, opacities)
    ref = _lists(torch_isect, means2d, radii, depths, W, H, conics, opacities)
    assert torch.equal(narrow[0], ref[0].int()) and torch.equal(narrow[1], ref[1].int())
    assert 0 < narrow[1].numel() < 0.8 * full[1].numel()
    assert not set(range(40)) & set(narrow[1].tolist())
    # every tile's narrowed list is its full list with entries left out, in the same order
    n_bins = full[0].numel()
    for off_n, fid_n, off_f, fid_f in ((*narrow, *full),):
        ends_n = off_n.reshape(-1).tolist()[1:] + [fid_n.numel()]
        ends_f = off_f.reshape(-1).tolist()[1:] + [fid_f.numel()]
        for b in range(n_bins):
            sub = fid_n[off_n.reshape(-1)[b] : ends_n[b]].tolist()
            sup = iter(fid_f[off_f.reshape(-1)[b] : ends_f[b]].tolist())
            assert all(any(x == y for y in sup) for x in sub)  # an ordered subsequence


@pytest.mark.parametrize(
    ("C", "N", "W", "H", "tile_size"), [(1, 400, 97, 61, 16), (2, 1500, 160, 120, 16), (1, 300, 70, 45, 8)]
)
def test_footprint_lists_change_no_pixel_and_no_gradient(ext, C, N, W, H, tile_size):
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, seed=N)
    bgs = torch.rand(C, 3, generator=torch.Generator().manual_seed(1))
    results = []
    for fp in (None, (conics, opacities)):
        lists = _lists(
            cpp_backend.isect_tiles_cpp, means2d, radii, depths, W, H, *(fp or ()), tile_size=tile_size
        )
        results.append(
            run_both(
                cpp_backend.rasterize_to_pixels_cpp, cpp_backend.rasterize_to_pixels_cpp,
                (means2d, conics, colors, opacities), W, H, tile_size, *lists, bgs,
            )[0]
        )  # fmt: skip
    (rc, ra, g), (rc_n, ra_n, g_n) = results
    assert torch.equal(rc, rc_n) and torch.equal(ra, ra_n)
    for name, a, b in zip(GRAD_NAMES + ["backgrounds"], g, g_n, strict=True):
        assert torch.equal(a, b), name


def _fake_ninjas(root, *dirs):
    for name in dirs:
        (root / name).mkdir()
        (root / name / "ninja").write_text("#!/bin/sh\n")
        (root / name / "ninja").chmod(0o755)


def test_the_ninja_beside_python_builds_whatever_path_holds(tmp_path, monkeypatch):
    """torch runs ``ninja`` by name: the build must not switch ninjas (1.11 and 1.13 rebuild everything
    after each other) when the venv is activated or not, nor find none without a system ninja."""
    _fake_ninjas(tmp_path, "venv", "a", "b")
    monkeypatch.setattr(sys, "executable", str(tmp_path / "venv" / "python"))
    monkeypatch.setenv("PATH", str(tmp_path / "a"))
    first = cpp_backend.build_directory()
    monkeypatch.setenv("PATH", str(tmp_path / "b"))
    assert cpp_backend.build_directory() == first
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    assert cpp_backend.build_directory() == first
    with cpp_backend._first_on_path(cpp_backend._ninja_program()):
        assert shutil.which("ninja") == str(tmp_path / "venv" / "ninja")  # what torch will run
    assert os.environ["PATH"] == str(tmp_path / "empty")


def test_without_one_beside_python_each_ninja_on_path_builds_apart(tmp_path, monkeypatch):
    _fake_ninjas(tmp_path, "a", "b")
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    monkeypatch.setenv("PATH", str(tmp_path / "a"))
    first = cpp_backend.build_directory()
    assert cpp_backend.build_directory() == first
    monkeypatch.setenv("PATH", str(tmp_path / "b"))
    assert cpp_backend.build_directory() != first
    monkeypatch.setattr(sys, "executable", "")  # embedded Python: not a ./ninja of the working directory
    monkeypatch.chdir(tmp_path / "a")
    assert cpp_backend._ninja_program() == str(tmp_path / "b" / "ninja")
