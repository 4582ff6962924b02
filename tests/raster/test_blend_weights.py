"""Every Gaussian's blending weight: the compiled forward that sums it as it blends (rasterize_weights)
against the backward's colour gradient, and ``raster.blend_weights`` on the cpp backend against the
gradient reading on the torch reference."""

from __future__ import annotations

import pytest
import torch
from raster_cases import intrinsics, look_at_viewmat, random_gaussians
from test_raster_cpp import isect, make_gaussians

from stealth_ns.raster import blend_weights, cpp_backend, rasterization


@pytest.fixture(scope="module")
def ext():
    mod = cpp_backend.load_extension()
    assert mod is not None, f"C++ rasterizer failed to compile: {cpp_backend.compile_error()}"
    return mod


def _case(C, N, W, H, seed, **kw):
    means2d, conics, colors, opacities, radii, depths = make_gaussians(C, N, W, H, 1, seed=seed, **kw)
    offsets, fids = isect(means2d, radii, depths, 16, W, H)
    return means2d, conics, colors, opacities, offsets, fids


def _gradient_weights(ext, means2d, conics, colors, opacities, W, H, offsets, fids):
    """The backward's colour gradient for an upstream gradient of ones (deterministic mode 0)."""
    rc, ra, last, T = ext.rasterize_fwd(means2d, conics, colors, opacities, None, W, H, 16, offsets, fids)
    grads = ext.rasterize_bwd(
        means2d,
        conics,
        colors,
        opacities,
        None,
        W,
        H,
        16,
        offsets,
        fids,
        T,
        last,
        torch.ones_like(rc),
        torch.zeros_like(ra),
    )
    return (rc, ra), grads[2][..., 0]


@pytest.mark.parametrize(
    "C,N,W,H,seed,kw",
    [
        (1, 300, 64, 48, 0, {}),
        (2, 400, 77, 61, 3, {"anisotropic": True}),
        (1, 150, 32, 32, 12, {"scale_range": (4.0, 10.0), "margin": 0.0}),  # most pixels stop early
    ],
)
def test_weights_are_the_backward_colour_gradient(ext, C, N, W, H, seed, kw):
    means2d, conics, colors, opacities, offsets, fids = _case(C, N, W, H, seed, **kw)
    rc, ra, weights = ext.rasterize_weights(means2d, conics, colors, opacities, None, W, H, 16, offsets, fids)
    (rc_ref, ra_ref), grad = _gradient_weights(ext, means2d, conics, colors, opacities, W, H, offsets, fids)
    assert torch.equal(rc, rc_ref) and torch.equal(ra, ra_ref)  # the forward is unchanged
    assert weights.shape == (C, N) and bool((weights >= 0).all())
    torch.testing.assert_close(weights, grad, rtol=1e-5, atol=1e-6)
    # the weights of a camera add up to its accumulated opacity
    torch.testing.assert_close(weights.sum(1), ra.sum((1, 2, 3)), rtol=1e-4, atol=1e-4)


def test_weights_do_not_depend_on_threads_or_culling(ext):
    means2d, conics, colors, opacities, offsets, fids = _case(2, 500, 96, 64, 8)
    args = (means2d, conics, colors, opacities, None, 96, 64, 16, offsets, fids)
    one = ext.rasterize_weights(*args, True, 1)
    for cull, threads in ((True, 2), (False, 2)):
        other = ext.rasterize_weights(*args, cull, threads)
        assert all(torch.equal(a, b) for a, b in zip(one, other, strict=True))


def _scene(n=120, cameras=2, W=48, H=36):
    means, quats, scales, opacities, _ = random_gaussians(n, seed=5, spread=0.8)
    eyes = [(0.0, 0.3, -3.0), (1.5, 0.5, -2.5), (-1.0, -0.2, -3.2)][:cameras]
    viewmats = torch.stack([look_at_viewmat(e) for e in eyes])
    Ks = intrinsics(W, H)[None].expand(cameras, -1, -1).contiguous()
    return dict(means=means, quats=quats, scales=scales, opacities=opacities, viewmats=viewmats, Ks=Ks), W, H


def test_blend_weights_compiled_matches_the_gradient_reading():
    g, W, H = _scene()
    w_cpp, d_cpp, a_cpp = blend_weights(**g, width=W, height=H, with_depth=True, backend="cpp")
    w_ref, d_ref, a_ref = blend_weights(**g, width=W, height=H, with_depth=True, backend="torch")
    assert w_cpp.shape == w_ref.shape == (2, 120)
    torch.testing.assert_close(w_cpp, w_ref, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(a_cpp, a_ref, rtol=0, atol=1e-5)
    torch.testing.assert_close(d_cpp, d_ref, rtol=1e-4, atol=1e-5)
    # the depth and opacity are those of the renderer's own "RGB+ED" render, exactly
    render, alpha, _ = rasterization(
        **g, colors=torch.rand(120, 3), width=W, height=H, render_mode="RGB+ED", backend="cpp"
    )
    assert torch.equal(d_cpp, render[..., 3]) and torch.equal(a_cpp, alpha[..., 0])
    w_only, no_depth, _ = blend_weights(**g, width=W, height=H, backend="cpp")
    assert no_depth is None and torch.equal(w_only, w_cpp)


def test_blend_weights_leave_out_hidden_and_culled_gaussians():
    g, W, H = _scene(cameras=1)
    g["means"][0] = torch.tensor([0.0, 0.3, -5.0])  # behind the camera
    g["means"][1] = torch.tensor([0.0, 0.3, -2.0])  # in front of it, made opaque and wide: hides ...
    g["scales"][1] = torch.tensor([2.0, 2.0, 2.0])
    g["opacities"][1] = 1.0
    weights, _, _ = blend_weights(**g, width=W, height=H, backend="cpp")
    assert float(weights[0, 0]) == 0.0
    assert float(weights[0, 1]) > 0.9 * W * H  # ... nearly every pixel
    assert float(weights[0, 2:].sum()) < 0.01 * W * H
