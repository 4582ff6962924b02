"""Unit tests of the attack's pure functions (stealth_ns.attack): density/KDE, ray search, noise,
illusions and view selection. Fast (a few seconds), CPU only, no network."""

from __future__ import annotations

import math
import socket
import sys

import numpy as np
import pytest
import torch
from scipy import ndimage

from stealth_ns.attack.density import (
    DensityGrid,
    gaussian_kde_grid,
    load_density_npz,
    sample_grid,
    voxel_density,
)
from stealth_ns.attack.illusion import (
    BUILTIN_ILLUSIONS,
    Illusion,
    builtin_illusion,
    composite,
    load_illusion,
    place_illusion,
)
from stealth_ns.attack.noise_schedule import noise_sigma, noisy_image
from stealth_ns.attack.ray_search import min_density_points, pixel_rays, zdepth_to_ray_t
from stealth_ns.attack.views import (
    median_view,
    multi_view_indices,
    resolve_views,
    scene_center,
    scene_up,
)
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import save_png

# ------------------------------------------------------------------------------------------ density / KDE


def test_voxel_density_sums_weights_per_voxel():
    pts = np.array(
        [
            [0.0, 0.0, 0.0],  # voxel (0,0,0)
            [0.1, 0.2, 0.05],  # voxel (0,0,0)
            [0.6, 0.1, 0.1],  # voxel (1,0,0)
            [1.0, 1.0, 1.0],  # AABB max -> last voxel (1,1,1)
            [0.99, 0.51, 0.0],  # voxel (1,1,0)
        ]
    )
    w = np.array([0.5, 0.25, 1.0, 0.75, 0.125])
    g = voxel_density(pts, w, voxel_size=0.5)
    assert g.shape == (2, 2, 2)
    assert g.values.dtype == np.float32
    np.testing.assert_allclose(g.origin, [0, 0, 0])
    expected = np.zeros((2, 2, 2))
    expected[0, 0, 0] = 0.75
    expected[1, 0, 0] = 1.0
    expected[1, 1, 1] = 0.75
    expected[1, 1, 0] = 0.125
    np.testing.assert_allclose(g.values, expected)
    assert math.isclose(float(g.values.sum()), w.sum(), rel_tol=1e-6)


def test_voxel_density_geometry_semantics():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1, 0, 2], [1, 1, 2.5], size=(500, 3))
    pts[0] = [-1, 0, 2]
    pts[1] = [1, 1, 2.5]  # exact AABB corners
    w = rng.uniform(size=500)
    g = voxel_density(pts, w, voxel_size=0.25)
    assert g.shape == (8, 4, 2)
    np.testing.assert_allclose(g.origin, [-1, 0, 2])
    np.testing.assert_allclose(g.upper, [1, 1, 2.5])
    # padding grows the box by whole empty voxels
    gp = voxel_density(pts, w, voxel_size=0.25, padding_voxels=2)
    assert gp.shape == (12, 8, 6)
    np.testing.assert_allclose(gp.origin, [-1.5, -0.5, 1.5])
    np.testing.assert_allclose(gp.values[2:-2, 2:-2, 2:-2], g.values)
    assert gp.values.sum() == pytest.approx(g.values.sum(), rel=1e-6)
    # resolution = voxels along the longest side
    gr = voxel_density(pts, w, resolution=16)
    assert gr.voxel_size == pytest.approx(2.0 / 16)
    assert gr.shape == (16, 8, 4)
    # every point lies in the voxel world_to_index says, and centres are mid-voxel
    idx = np.clip(g.world_to_index(pts), 0, np.array(g.shape) - 1)
    counts = np.zeros(g.shape)
    np.add.at(counts, tuple(idx.T), w)
    np.testing.assert_allclose(g.values, counts, rtol=1e-5)
    c = g.centers()
    assert c.shape == (8, 4, 2, 3)
    np.testing.assert_allclose(c[0, 0, 0], g.origin + 0.125)
    np.testing.assert_array_equal(g.world_to_index(c[3, 2, 1]), [3, 2, 1])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(), "exactly one"),
        (dict(voxel_size=0.1, resolution=10), "exactly one"),
        (dict(voxel_size=0.0), "voxel_size"),
        (dict(voxel_size=-1.0), "voxel_size"),
        (dict(resolution=0), "resolution"),
        (dict(voxel_size=0.1, padding_voxels=-1), "padding"),
        (dict(voxel_size=1e-6), "too large"),
    ],
)
def test_voxel_density_argument_errors(kwargs, match):
    pts = np.random.default_rng(1).uniform(size=(10, 3))
    with pytest.raises(ValueError, match=match):
        voxel_density(pts, np.ones(10), **kwargs)


def test_voxel_density_input_errors():
    with pytest.raises(ValueError, match="empty"):
        voxel_density(np.zeros((0, 3)), np.zeros(0), voxel_size=0.1)
    bad = np.zeros((3, 3))
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        voxel_density(bad, np.ones(3), voxel_size=0.1)
    with pytest.raises(ValueError, match="shape"):
        voxel_density(np.zeros((3, 2)), np.ones(3), voxel_size=0.1)
    with pytest.raises(ValueError, match="weights"):
        voxel_density(np.zeros((3, 3)), np.ones(4), voxel_size=0.1)
    with pytest.raises(ValueError, match="non-negative"):
        voxel_density(np.eye(3), -np.ones(3), voxel_size=0.1)
    with pytest.raises(ValueError, match="coincide"):
        voxel_density(np.ones((4, 3)), np.ones(4), resolution=8)
    # a single point is fine with a voxel size
    g = voxel_density(np.ones((1, 3)), np.array([0.3]), voxel_size=0.1)
    assert g.shape == (1, 1, 1) and g.values[0, 0, 0] == pytest.approx(0.3)


@pytest.mark.parametrize("h", [0.1, 1.0, 2.5, 7.5])
def test_kde_equals_scipy_gaussian_filter(h):
    rng = np.random.default_rng(2)
    pts = np.concatenate([rng.normal(0, 0.3, size=(3000, 3)), rng.uniform(-1, 1, size=(500, 3))])
    g = voxel_density(pts, rng.uniform(0.05, 1, size=len(pts)), voxel_size=0.1, padding_voxels=3)
    kde = gaussian_kde_grid(g, h)
    ref = ndimage.gaussian_filter(g.values.astype(np.float64), sigma=h, mode="constant")
    ref = ref / ref.max()
    np.testing.assert_allclose(kde.values, ref, rtol=1e-6, atol=1e-7)
    assert kde.values.max() == pytest.approx(1.0)
    assert kde.shape == g.shape and kde.voxel_size == g.voxel_size
    np.testing.assert_array_equal(kde.origin, g.origin)
    # the float32 scipy call (what one would naively write) agrees too
    ref32 = ndimage.gaussian_filter(g.values, sigma=h, mode="constant")
    np.testing.assert_allclose(kde.values, ref32 / ref32.max(), rtol=1e-5, atol=1e-6)
    raw = gaussian_kde_grid(g, h, normalize=False)
    np.testing.assert_allclose(
        raw.values,
        ndimage.gaussian_filter(g.values.astype(np.float64), h, mode="constant"),
        rtol=1e-6,
        atol=1e-7,
    )


def test_kde_matches_paper_formula_without_truncation():
    """f(c(s)) = 1/|S| sum K_h(c(s) - c(s')) rho(s') up to a constant, when the kernel is not truncated."""
    rng = np.random.default_rng(3)
    g = DensityGrid(
        values=rng.uniform(size=(6, 5, 4)) * (rng.uniform(size=(6, 5, 4)) > 0.6),
        origin=np.zeros(3),
        voxel_size=0.2,
    )
    h = 1.3  # voxels
    c = g.centers().reshape(-1, 3)
    d2 = ((c[:, None, :] - c[None, :, :]) ** 2).sum(-1) / g.voxel_size**2
    k = np.exp(-d2 / (2 * h * h)) / (2 * np.pi * (h * g.voxel_size) ** 2) ** 1.5
    f = (k @ g.values.reshape(-1).astype(np.float64)) / c.shape[0]
    kde = gaussian_kde_grid(g, h, truncate=20.0)
    np.testing.assert_allclose(kde.values.reshape(-1), f / f.max(), rtol=1e-5, atol=1e-7)


def test_kde_errors_and_zero_grid():
    g = DensityGrid(values=np.zeros((3, 3, 3)), origin=np.zeros(3), voxel_size=1.0)
    assert gaussian_kde_grid(g, 2.0).values.max() == 0.0
    with pytest.raises(ValueError):
        gaussian_kde_grid(g, -1.0)
    with pytest.raises(ValueError):
        gaussian_kde_grid(g, float("nan"))


def test_density_npz_roundtrip(tmp_path):
    rng = np.random.default_rng(4)
    g = voxel_density(rng.uniform(size=(100, 3)), rng.uniform(size=100), resolution=7)
    kde = gaussian_kde_grid(g, 1.5)
    path = g.save_npz(tmp_path / "sub" / "density.npz", extras={"kde": kde.values})
    assert path.is_file()
    g2, extras = load_density_npz(path)
    np.testing.assert_array_equal(g2.values, g.values)
    np.testing.assert_array_equal(g2.origin, g.origin)
    assert g2.voxel_size == g.voxel_size
    np.testing.assert_array_equal(extras["kde"], kde.values)
    assert DensityGrid.load_npz(path).shape == g.shape
    with pytest.raises(ValueError, match="clash"):
        g.save_npz(tmp_path / "x.npz", extras={"values": kde.values})


def test_sample_grid_nearest_trilinear_and_outside():
    vals = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    g = DensityGrid(values=vals, origin=np.array([1.0, 2.0, 3.0]), voxel_size=0.5)
    centres = g.centers()
    # nearest at the centres and anywhere inside the voxel
    np.testing.assert_allclose(sample_grid(g, centres), vals)
    np.testing.assert_allclose(sample_grid(g, centres + 0.2), vals)
    # trilinear is exact at centres and linear in between
    np.testing.assert_allclose(sample_grid(g, centres, mode="trilinear"), vals, atol=1e-9)
    mid = (centres[0, 0, 0] + centres[1, 1, 1]) / 2
    assert sample_grid(g, mid, mode="trilinear") == pytest.approx(vals[:2, :2, :2].mean())
    # outside reads `outside` (default 0), for numpy and torch alike
    far = np.array([[0.0, 0.0, 0.0], [1.0 + 1.01, 2.5, 3.5], [1.5, 2.5, 2.99]])
    np.testing.assert_array_equal(sample_grid(g, far), [0, 0, 0])
    np.testing.assert_array_equal(sample_grid(g, far, outside=-1.0), [-1, -1, -1])
    np.testing.assert_array_equal(sample_grid(g, far, mode="trilinear"), [0, 0, 0])
    tp = torch.tensor(centres.reshape(-1, 3), dtype=torch.float32)
    out = sample_grid(g, tp)
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float32
    np.testing.assert_allclose(out.numpy(), vals.reshape(-1))
    # points on the far face belong to the last voxel
    assert sample_grid(g, g.upper) == vals[-1, -1, -1]


# -------------------------------------------------------------------------------------------- ray search


def _slab_grid() -> DensityGrid:
    """10x10x10 unit voxels at the origin, density 1, with zero slabs z in [3, 7) and [8, 9)."""
    vals = np.ones((10, 10, 10), dtype=np.float32)
    vals[:, :, 3:7] = 0.0
    vals[:, :, 8:9] = 0.0
    return DensityGrid(values=vals, origin=np.zeros(3), voxel_size=1.0)


def test_min_density_finds_pocket_on_kde():
    """A uniform cloud with a spherical hole: the KDE minimum along a ray through the hole is its centre."""
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 4, size=(60000, 3))
    hole = np.array([2.0, 2.0, 2.6])
    pts = pts[np.linalg.norm(pts - hole, axis=1) > 0.6]
    kde = gaussian_kde_grid(voxel_density(pts, np.full(len(pts), 0.5), voxel_size=0.1), 2.0)
    origin = np.array([[2.0, 2.0, -1.0]])
    direction = np.array([[0.0, 0.0, 1.0]])
    t_min, t_max, n = 1.3, 4.9, 512  # z from 0.3 to 3.9: inside the cloud
    for tb in ("first", "nearest-surface", "middle"):
        r = min_density_points(kde, origin, direction, t_min, np.array([t_max]), n_samples=n, tie_break=tb)
        assert r.valid[0]
        spacing = (t_max - t_min) / (n - 1)
        assert abs(r.t[0] - (hole[2] + 1.0)) <= 0.1 + spacing  # within a voxel of the hole centre
        np.testing.assert_allclose(r.points[0], origin[0] + r.t[0] * direction[0])
        assert r.density[0] == pytest.approx(float(sample_grid(kde, r.points[0])))


def test_min_density_known_pocket_and_outside_reads_zero():
    g = _slab_grid()
    g.values[:, :, 3:7] = 0.5
    g.values[:, :, 8:9] = 1.0
    g.values[5, 5, 5] = 0.1  # the pocket: z in [5, 6)
    o = np.array([[5.5, 5.5, -5.0]])
    d = np.array([[0.0, 0.0, 1.0]])
    n = 1000
    r = min_density_points(g, o, d, 5.2, np.array([14.8]), n_samples=n, tie_break="middle")
    spacing = 9.6 / (n - 1)
    assert 10.0 - spacing <= r.t[0] <= 11.0 + spacing
    assert r.density[0] == pytest.approx(0.1)
    # starting outside the grid: the samples in front of it read 0 (empty space is the least dense)
    r = min_density_points(g, o, d, 0.3, np.array([14.8]), n_samples=n, tie_break="first")
    assert r.t[0] == pytest.approx(0.3) and r.density[0] == 0.0
    r = min_density_points(g, o, d, 0.3, np.array([14.8]), n_samples=n, tie_break="nearest-surface")
    assert r.t[0] < 5.0 and r.density[0] == 0.0  # the last empty sample before the box face (z = 0)
    assert r.t[0] > 5.0 - 2 * 14.5 / (n - 1)


def test_tie_break_rules():
    g = _slab_grid()
    o = np.array([[5.5, 5.5, 0.0]])
    d = np.array([[0.0, 0.0, 1.0]])
    t_min, t_max, n = 0.5, 9.5, 901  # spacing 0.01
    res = {
        tb: min_density_points(g, o, d, t_min, np.array([t_max]), n_samples=n, tie_break=tb)
        for tb in ("first", "nearest-surface", "middle")
    }
    assert res["first"].t[0] == pytest.approx(3.0, abs=0.011)  # start of the first zero run
    assert res["nearest-surface"].t[0] == pytest.approx(9.0, abs=0.011)  # end of the last zero run
    assert res["middle"].t[0] == pytest.approx(5.0, abs=0.011)  # middle of the first zero run [3, 7)
    for r in res.values():
        assert r.density[0] == 0.0
    # the tolerance widens the candidate set
    g2 = _slab_grid()
    g2.values[:, :, 8:9] = 1e-3
    r = min_density_points(g2, o, d, t_min, np.array([t_max]), n_samples=n, tie_break="nearest-surface")
    assert r.t[0] == pytest.approx(7.0, abs=0.011)
    r = min_density_points(
        g2, o, d, t_min, np.array([t_max]), n_samples=n, tie_break="nearest-surface", tie_tol=1e-2
    )
    assert r.t[0] == pytest.approx(9.0, abs=0.011)


def test_invalid_rays_and_chunking_invariance():
    rng = np.random.default_rng(6)
    pts = rng.normal(size=(5000, 3))
    kde = gaussian_kde_grid(voxel_density(pts, rng.uniform(size=5000), voxel_size=0.2), 2.5)
    m = 37
    o = np.tile([[0.0, 0.0, -5.0]], (m, 1)) + rng.normal(0, 0.2, size=(m, 3))
    d = rng.normal(0, 0.3, size=(m, 3))
    d[:, 2] = 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_max = rng.uniform(4, 9, size=m)
    t_max[[3, 10]] = 0.1  # < t_min
    t_max[20] = np.nan
    for tb in ("first", "nearest-surface", "middle"):
        big = min_density_points(kde, o, d, 0.3, t_max, n_samples=300, tie_break=tb, mode="trilinear")
        small = min_density_points(
            kde, o, d, 0.3, t_max, n_samples=300, tie_break=tb, mode="trilinear", max_samples_per_chunk=700
        )  # 2 rays per chunk
        one = min_density_points(
            kde, o, d, 0.3, t_max, n_samples=300, tie_break=tb, mode="trilinear", max_samples_per_chunk=1
        )
        for r in (small, one):
            np.testing.assert_array_equal(r.valid, big.valid)
            np.testing.assert_array_equal(r.t, big.t)
            np.testing.assert_array_equal(r.points, big.points)
        valid = big.valid
        assert valid.dtype == bool and valid.sum() == m - 3
        assert not valid[[3, 10, 20]].any()
        assert np.isnan(big.points[~valid]).all() and np.isnan(big.t[~valid]).all()
        assert np.isfinite(big.points[valid]).all()
        assert (big.t[valid] >= 0.3 - 1e-12).all() and (big.t[valid] <= t_max[valid] + 1e-12).all()
    # torch in, torch out, same numbers
    rt = min_density_points(
        kde, torch.from_numpy(o), torch.from_numpy(d), 0.3, torch.from_numpy(t_max), n_samples=300
    )
    rn = min_density_points(kde, o, d, 0.3, t_max, n_samples=300)
    assert isinstance(rt.points, torch.Tensor) and rt.valid.dtype == torch.bool
    np.testing.assert_allclose(rt.t.numpy(), rn.t, equal_nan=True)
    # all rays invalid, and no rays at all, do not crash
    r = min_density_points(kde, o[:2], d[:2], 1.0, np.array([0.5, 0.2]))
    assert not r.valid.any()
    r = min_density_points(kde, np.zeros((0, 3)), np.zeros((0, 3)), 0.3, np.zeros(0))
    assert r.points.shape == (0, 3)


def test_min_density_argument_errors():
    g = _slab_grid()
    o, d = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="tie_break"):
        min_density_points(g, o, d, 0.3, 1.0, tie_break="last")
    with pytest.raises(ValueError, match="n_samples"):
        min_density_points(g, o, d, 0.3, 1.0, n_samples=0)
    with pytest.raises(ValueError, match="origins"):
        min_density_points(g, o, d[:, :2], 0.3, 1.0)


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def test_pixel_rays_match_nerfstudio_cameras():
    from nerfstudio.cameras.cameras import Cameras, CameraType

    c2w = np.zeros((3, 4))
    c2w[:, :3] = _rot([0.3, -1.0, 0.5], 0.9) @ _rot([1, 0, 0], -0.4)
    c2w[:, 3] = [0.7, -1.2, 2.5]
    W, H, fx, fy, cx, cy = 40, 30, 52.0, 47.0, 21.3, 14.1
    cams = Cameras(
        camera_to_worlds=torch.tensor(c2w[None], dtype=torch.float32),
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        width=W,
        height=H,
        camera_type=CameraType.PERSPECTIVE,
    )
    bundle = cams.generate_rays(camera_indices=0)
    pix = np.array([[0, 0], [39, 0], [0, 29], [39, 29], [21, 14], [7, 22]])  # (col, row)
    o, d, cos = pixel_rays(c2w, fx, fy, cx, cy, pix)
    ref_o = bundle.origins[pix[:, 1], pix[:, 0]].numpy()
    ref_d = bundle.directions[pix[:, 1], pix[:, 0]].numpy()
    np.testing.assert_allclose(o, ref_o, atol=1e-5)
    np.testing.assert_allclose(d, ref_d, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # nerfstudio's directions_norm is the camera-space length of (x, y, -1) = 1 / cos_theta
    ref_norm = bundle.metadata["directions_norm"][pix[:, 1], pix[:, 0], 0].numpy()
    np.testing.assert_allclose(1.0 / cos, ref_norm, rtol=1e-5)
    # cos_theta is the projection on the optical axis (-Z of the camera)
    np.testing.assert_allclose(cos, d @ -c2w[:, 2], atol=1e-12)
    # a point at z-depth z along the optical axis is at t = z / cos_theta
    z = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    t = zdepth_to_ray_t(z, cos)
    p = o + t[:, None] * d
    np.testing.assert_allclose((p - c2w[:, 3]) @ -c2w[:, 2], z, atol=1e-9)
    # torch in, torch out
    ot, dt, ct = pixel_rays(torch.tensor(c2w, dtype=torch.float32), fx, fy, cx, cy, torch.tensor(pix))
    assert isinstance(dt, torch.Tensor) and dt.dtype == torch.float32
    np.testing.assert_allclose(dt.numpy(), ref_d, atol=1e-5)


# ------------------------------------------------------------------------------------------------- noise


def test_noise_schedules_match_paper():
    s = math.sqrt(0.5) * 100
    expected = {
        "linear": (100, 50, 0),
        "cosine": (100, s, 0),
        "sqrt": (100, s, 0),
        "constant": (100, 100, 100),
    }
    for decay, vals in expected.items():
        got = [noise_sigma(t, 1000, 100.0, decay) for t in (0, 500, 1000)]
        assert got == pytest.approx(vals, abs=1e-9), decay
    assert noise_sigma(-5, 1000, 30.0, "linear") == 30.0  # clamped to t = 0
    assert noise_sigma(5000, 1000, 30.0, "sqrt") == 0.0  # clamped to t = T
    assert noise_sigma(250, 1000, 100.0, "linear") == pytest.approx(75.0)
    assert noise_sigma(250, 1000, 100.0, "cosine") == pytest.approx(100 * math.cos(math.pi / 8))
    for bad in (dict(decay="exp"), dict(total_steps=0), dict(sigma0=-1.0), dict(sigma0=float("nan"))):
        kw = dict(step=0, total_steps=10, sigma0=1.0, decay="linear") | bad
        with pytest.raises(ValueError):
            noise_sigma(**kw)


def test_noisy_image_statistics_and_determinism():
    img = torch.full((128, 128, 3), 0.5)
    before = img.clone()
    a = noisy_image(img, 10.0, seed=0, view_index=3, step=7)
    torch.testing.assert_close(img, before)  # not modified in place
    assert a.shape == img.shape and a.dtype == img.dtype
    std = float(((a - 0.5) * 255).std())
    assert std == pytest.approx(10.0, rel=0.03)
    assert float(((a - 0.5) * 255).mean()) == pytest.approx(0.0, abs=0.2)
    torch.testing.assert_close(noisy_image(img, 10.0, 0, 3, 7), a)  # deterministic
    assert not torch.equal(noisy_image(img, 10.0, 0, 4, 7), a)  # other view
    assert not torch.equal(noisy_image(img, 10.0, 0, 3, 8), a)  # other step
    assert not torch.equal(noisy_image(img, 10.0, 1, 3, 7), a)  # other seed
    # uint8: rounded, clipped, same dtype
    u = torch.full((128, 128, 3), 128, dtype=torch.uint8)
    nu = noisy_image(u, 10.0, 0, 3, 7)
    assert nu.dtype == torch.uint8 and torch.equal(u, torch.full_like(u, 128))
    assert float((nu.float() - 128).std()) == pytest.approx(10.0, rel=0.03)
    # same noise field for uint8 and float versions of the image
    np.testing.assert_allclose(
        nu.float().numpy(), np.clip(np.round(128 + (a.numpy() - 0.5) * 255), 0, 255), atol=1.0
    )
    # clipping
    big = noisy_image(torch.full((64, 64, 3), 0.98), 100.0, 0, 0, 0)
    assert float(big.max()) <= 1.0 and float(big.min()) >= 0.0 and float(big.max()) == 1.0
    # sigma = 0 is an unchanged copy
    z = noisy_image(img, 0.0, 0, 0, 0)
    assert torch.equal(z, img) and z.data_ptr() != img.data_ptr()
    # numpy in, numpy out
    nn = noisy_image(np.full((8, 8, 3), 100, dtype=np.uint8), 5.0, 0, 1, 2)
    assert isinstance(nn, np.ndarray) and nn.dtype == np.uint8
    with pytest.raises(ValueError):
        noisy_image(img, -1.0, 0, 0, 0)


# --------------------------------------------------------------------------------------------- illusions


@pytest.fixture
def no_network(monkeypatch):
    """Fail loudly if anything tries to download (pooch import or any socket connection)."""

    def refuse(*args, **kwargs):
        raise AssertionError("network access attempted")

    monkeypatch.setitem(sys.modules, "pooch", None)
    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    builtin_illusion.cache_clear()
    yield
    builtin_illusion.cache_clear()


def test_builtin_illusions_are_real_cutouts(no_network):
    assert len(BUILTIN_ILLUSIONS) >= 3
    for name in BUILTIN_ILLUSIONS:
        ill = builtin_illusion(name)
        assert ill.name == name
        assert ill.rgb.dtype == np.float32 and ill.alpha.dtype == np.float32
        assert ill.rgb.min() >= 0 and ill.rgb.max() <= 1 and ill.alpha.min() >= 0 and ill.alpha.max() <= 1
        m = ill.mask
        rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
        fill = m.sum() / ((rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1))
        assert 0.2 < fill < 0.9, (name, fill)
        # one object: a single connected component without holes
        assert ndimage.label(m)[1] == 1, name
        assert np.array_equal(ndimage.binary_fill_holes(m), m), name
        assert min(m.shape) >= 48
        # colourful: the object is not grey
        sat = ill.rgb[m].max(axis=1) - ill.rgb[m].min(axis=1)
        assert float(sat.mean()) > 0.15, name
    assert builtin_illusion(BUILTIN_ILLUSIONS[0]) is builtin_illusion(BUILTIN_ILLUSIONS[0])  # cached
    with pytest.raises(StealthNSError, match="unknown built-in"):
        builtin_illusion("unicorn")


def _rgba(h=40, w=60):
    rng = np.random.default_rng(7)
    rgba = np.zeros((h, w, 4), dtype=np.uint8)
    rgba[..., :3] = rng.integers(0, 256, size=(h, w, 3))
    yy, xx = np.mgrid[0:h, 0:w]
    rgba[..., 3] = np.where((yy - h / 2) ** 2 + (xx - w / 2) ** 2 < (h / 3) ** 2, 255, 0)
    return rgba


def test_load_illusion_rgba_and_rgb_mask(tmp_path):
    rgba = _rgba()
    save_png(tmp_path / "obj.png", rgba)
    ill = load_illusion(tmp_path / "obj.png")
    assert ill.name == "obj" and ill.rgb.shape == (40, 60, 3)
    np.testing.assert_allclose(ill.rgb, rgba[..., :3] / 255.0, atol=1e-6)
    np.testing.assert_array_equal(ill.mask, rgba[..., 3] > 128)
    # RGB + greyscale mask
    save_png(tmp_path / "rgb.png", rgba[..., :3])
    save_png(tmp_path / "mask.png", rgba[..., 3])
    ill2 = load_illusion(tmp_path / "rgb.png", tmp_path / "mask.png")
    np.testing.assert_array_equal(ill2.mask, ill.mask)
    np.testing.assert_allclose(ill2.rgb, ill.rgb)
    # RGB mask, bool mask saved as 0/255
    save_png(tmp_path / "mask_rgb.png", np.repeat(rgba[..., 3:4], 3, axis=2))
    np.testing.assert_array_equal(
        load_illusion(tmp_path / "rgb.png", tmp_path / "mask_rgb.png").mask, ill.mask
    )
    save_png(tmp_path / "mask_bool.png", rgba[..., 3] > 0)
    np.testing.assert_array_equal(
        load_illusion(tmp_path / "rgb.png", tmp_path / "mask_bool.png").mask, ill.mask
    )
    # a mask file overrides the alpha channel
    inv = (255 - rgba[..., 3]).astype(np.uint8)
    save_png(tmp_path / "inv.png", inv)
    np.testing.assert_array_equal(load_illusion(tmp_path / "obj.png", tmp_path / "inv.png").mask, ~ill.mask)


def test_load_illusion_errors(tmp_path):
    rgba = _rgba()
    save_png(tmp_path / "rgb.png", rgba[..., :3])
    save_png(tmp_path / "obj.png", rgba)
    (tmp_path / "notes.png").write_text("this is not an image")
    save_png(tmp_path / "small_mask.png", np.ones((10, 10), dtype=bool))
    save_png(tmp_path / "empty_mask.png", np.zeros((40, 60), dtype=np.uint8))
    clear = rgba.copy()
    clear[..., 3] = 0
    save_png(tmp_path / "clear.png", clear)
    cases = [
        ((tmp_path / "missing.png",), "missing.png does not exist"),
        ((tmp_path / "notes.png",), "notes.png cannot be read as an image"),
        ((tmp_path / "rgb.png",), "rgb.png has no alpha channel"),
        (
            (tmp_path / "rgb.png", tmp_path / "small_mask.png"),
            "small_mask.png is 10x10 px but the image rgb.png is 60x40",
        ),
        ((tmp_path / "rgb.png", tmp_path / "empty_mask.png"), "empty_mask.png is empty"),
        ((tmp_path / "clear.png",), "clear.png is fully transparent"),
        ((tmp_path / "rgb.png", tmp_path / "nomask.png"), "nomask.png does not exist"),
        ((tmp_path,), "is not a file"),
    ]
    for args, msg in cases:
        with pytest.raises(StealthNSError, match=msg) as info:
            load_illusion(*args)
        assert "\n" not in str(info.value)


def test_place_illusion_sizes_and_errors():
    ill = Illusion(rgb=np.ones((40, 60, 3)) * [1.0, 0.0, 0.0], alpha=_rgba()[..., 3] / 255.0, name="disc")
    rgb, alpha = place_illusion(ill, (100, 200), center=(0.25, 0.5), scale=0.5)
    assert rgb.shape == (100, 200, 3) and alpha.shape == (100, 200)
    assert rgb.dtype == np.float32 and alpha.dtype == np.float32
    # 50 px high, 75 px wide box centred at (50, 50)
    rows, cols = np.flatnonzero(alpha.any(1)), np.flatnonzero(alpha.any(0))
    assert rows[0] >= 25 and rows[-1] < 75 and cols[0] >= 12 and cols[-1] < 88
    m = alpha > 0.5
    mr, mc = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
    assert (mr[0] + mr[-1]) / 2 == pytest.approx(49.5, abs=1.0)
    assert (mc[0] + mc[-1]) / 2 == pytest.approx(49.5, abs=1.0)
    assert mr[-1] - mr[0] + 1 == pytest.approx(2 / 3 * 50, abs=2)  # the disc is 2/3 of the illusion height
    # premultiplied resize: no dark fringe, colour stays pure red wherever alpha > 0
    assert np.allclose(rgb[alpha > 1e-3], [1.0, 0.0, 0.0], atol=1e-5)
    # near the border the box is shifted inside the image
    _, a2 = place_illusion(ill, (100, 200), center=(1.0, 0.0), scale=0.5)
    cols2, rows2 = np.flatnonzero(a2.any(0)), np.flatnonzero(a2.any(1))
    assert cols2[-1] <= 199 and rows2[0] >= 0 and a2[a2 > 0].size == alpha[alpha > 0].size
    with pytest.raises(StealthNSError, match="scale must be > 0"):
        place_illusion(ill, (100, 200), scale=0.0)
    with pytest.raises(
        StealthNSError, match=r"illusion of 150x100 px does not fit in the 120x100 image at scale 1.0"
    ):
        place_illusion(ill, (100, 120), scale=1.0)
    with pytest.raises(StealthNSError, match="outside the image"):
        place_illusion(ill, (100, 200), center=(1.2, 0.5))
    dot = np.zeros((50, 50))
    dot[25, 25] = 1.0
    with pytest.raises(StealthNSError, match="mask is empty"):
        place_illusion(Illusion(rgb=np.ones((50, 50, 3)), alpha=dot, name="dot"), (100, 100), scale=0.05)


def test_composite_math():
    img = np.full((4, 5, 3), 0.2, dtype=np.float32)
    fg = np.zeros((4, 5, 3), dtype=np.float32)
    fg[..., 0] = 1.0
    alpha = np.zeros((4, 5), dtype=np.float32)
    alpha[1, 2] = 1.0
    alpha[2, 3] = 0.25
    out = composite(img, fg, alpha)
    assert out.dtype == np.float32 and out.shape == img.shape
    np.testing.assert_allclose(out[1, 2], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(out[2, 3], [0.25 + 0.75 * 0.2, 0.75 * 0.2, 0.75 * 0.2], rtol=1e-6)
    np.testing.assert_allclose(out[0, 0], img[0, 0])
    assert np.all(img == 0.2)  # not modified
    u8 = np.full((4, 5, 3), 100, dtype=np.uint8)
    ou = composite(u8, fg, alpha)
    assert ou.dtype == np.uint8
    np.testing.assert_array_equal(ou[1, 2], [255, 0, 0])
    np.testing.assert_array_equal(ou[2, 3], [round(0.25 * 255 + 75), 75, 75])
    t = composite(torch.from_numpy(u8), fg, alpha)
    assert isinstance(t, torch.Tensor) and t.dtype == torch.uint8
    np.testing.assert_array_equal(t.numpy(), ou)


# ------------------------------------------------------------------------------------------------- views


def _look_at(pos, target, up=(0.0, 0.0, 1.0)):
    z = np.asarray(pos, float) - np.asarray(target, float)
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.zeros((3, 4))
    c2w[:, 0], c2w[:, 1], c2w[:, 2], c2w[:, 3] = x, y, z, pos
    return c2w


def _ring(n=40, radius=4.0, height=1.0):
    angles = 2 * np.pi * np.arange(n) / n
    return np.stack(
        [_look_at([radius * math.cos(a), radius * math.sin(a), height], [0, 0, 0]) for a in angles]
    )


def test_median_view():
    assert median_view(1) == 0
    assert median_view(52) == 26
    assert median_view(51) == 25
    with pytest.raises(StealthNSError):
        median_view(0)


def test_multi_view_indices_on_a_ring():
    poses = _ring()
    np.testing.assert_allclose(scene_center(poses), [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(scene_up(poses), [0, 0, 1], atol=0.3)  # tilted-down cameras: up is approximate
    assert multi_view_indices(poses, 4) == [20, 30, 0, 10]  # base 20, then +90, +180, +270 degrees
    assert multi_view_indices(poses, 1) == [20]
    assert multi_view_indices(poses, 2, base=5) == [5, 15]
    # the same ring in a rotated, shifted world frame gives the same views
    r = _rot([1.0, 2.0, 0.5], 1.1)
    moved = np.concatenate(
        [r @ poses[:, :, :3], (r @ poses[:, :, 3:]) + np.array([[3.0], [-2.0], [1.0]])], axis=2
    )
    assert multi_view_indices(moved, 4) == [20, 30, 0, 10]
    # uneven sampling: the nearest azimuth is picked and views are distinct
    sub = poses[[0, 3, 9, 12, 19, 21, 24, 33]]
    idx = multi_view_indices(torch.tensor(sub), 4, center=[0.0, 0.0, 0.0])
    assert idx[0] == 4 and len(set(idx)) == 4
    az = np.degrees(np.arctan2(sub[idx, 1, 3], sub[idx, 0, 3])) % 360
    assert [round(a) for a in az] == [171, 297, 0, 81]
    with pytest.raises(StealthNSError, match="1 to 4"):
        multi_view_indices(poses, 5)
    with pytest.raises(StealthNSError, match="out of range"):
        multi_view_indices(poses, 2, base=40)
    with pytest.raises(StealthNSError, match="only 2 training views"):
        multi_view_indices(poses[:2], 3)


def test_resolve_views():
    names = [f"/data/scene/images/frame_{i:05d}.png" for i in range(0, 60) if i % 8 != 0][:52]
    assert len(names) == 52
    assert resolve_views([0, 51, np.int64(3)], names) == [0, 51, 3]
    assert resolve_views(["frame_00002.png", "images/frame_00003.png", "frame_00004", names[10]], names) == [
        1,
        2,
        3,
        10,
    ]
    assert resolve_views(["7"], names) == [7]  # digits that name no image are an index
    with pytest.raises(StealthNSError, match=r"view index 99 is out of range: 52 training views \(0\.\.51\)"):
        resolve_views([99], names)
    with pytest.raises(StealthNSError, match="out of range"):
        resolve_views([-1], names)
    with pytest.raises(
        StealthNSError, match=r"unknown view name 'frame_00003.jpg'.*did you mean 'frame_00003.png'"
    ):
        resolve_views(["frame_00003.jpg"], names)
    with pytest.raises(StealthNSError, match="already given"):
        resolve_views([2, "frame_00003.png"], names)
    with pytest.raises(StealthNSError, match="already given"):
        resolve_views([4, 4], names)
    dup = ["a/x.png", "b/x.png", "c/y.png"]
    with pytest.raises(StealthNSError, match="matches 2 images"):
        resolve_views(["x.png"], dup)
    assert resolve_views(["b/x.png"], dup) == [1]
    numbered = ["1.png", "2.png", "3.png"]
    with pytest.raises(StealthNSError, match="ambiguous"):
        resolve_views(["1"], numbered)  # image '1.png' is view 0, but 1 is also a view index
    assert resolve_views(["1.png", 1], numbered) == [0, 1]
