"""Where poison goes: camera visibility counts, the view-aware ray search, the scale-free t_min,
and the refusal to place poison by the density of a random cloud."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from attack_helpers import build_pipeline

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.density import DensityGrid
from stealth_ns.attack.injection import PoisonView, median_scene_depth, place_poison
from stealth_ns.attack.ray_search import min_density_points
from stealth_ns.attack.visibility import CameraDepths, count_seeing_cameras, count_seeing_cameras_reference
from stealth_ns.raster.projection import viewmat_from_c2w


def _camera(eye: tuple[float, float, float], depth: float, alpha: float = 1.0, size: int = 20):
    """An OpenCV camera at ``eye`` looking down +Z (focal 10 px, centre pixel), flat depth map."""
    viewmat = torch.eye(4)
    viewmat[:3, 3] = -torch.tensor(eye)
    K = torch.tensor([[10.0, 0.0, size / 2], [0.0, 10.0, size / 2], [0.0, 0.0, 1.0]])
    return viewmat, K, torch.full((size, size), depth), torch.full((size, size), alpha)


def _cameras(*cams) -> CameraDepths:
    return CameraDepths(
        viewmats=torch.stack([c[0] for c in cams]),
        Ks=torch.stack([c[1] for c in cams]),
        depths=[c[2] for c in cams],
        alphas=[c[3] for c in cams],
    )


def test_count_seeing_cameras_frustum_occlusion_and_empty_pixels():
    cams = _cameras(
        _camera((0.0, 0.0, 0.0), depth=5.0),  # surface at z = 5
        _camera((0.0, 0.0, 0.0), depth=5.0, alpha=0.0),  # shows no surface: occludes nothing
        _camera((3.0, 0.0, 0.0), depth=100.0),  # 3 units to the side, 90° fov
    )
    pts = torch.tensor(
        [
            [0.0, 0.0, 2.0],  # in front of the surface: cams 0, 1; cam 2 sees x' = -3 at z 2 -> outside
            [0.0, 0.0, 5.2],  # 4% behind the surface: within the 5% margin, seen by cam 0 (and 1, 2)
            [0.0, 0.0, 6.0],  # 20% behind the surface: hidden from cam 0 only (1, 2 see it)
            [0.0, 0.0, -1.0],  # behind every camera
            [2.5, 0.0, 4.0],  # cams 0, 1, 2
        ]
    )
    counts = count_seeing_cameras(pts, cams, margin=0.05)
    assert counts.tolist() == [2, 3, 2, 0, 3]
    assert count_seeing_cameras(pts[None], cams).shape == (1, 5)


def test_count_seeing_cameras_compiled_equals_reference():
    """The compiled kernel counts exactly what the torch reference counts: cameras of different sizes
    around the points, points behind cameras, on image borders, on the depth bound and off screen."""
    from stealth_ns.raster.cpp_backend import load_extension

    if load_extension() is None:
        pytest.skip("compiled kernels unavailable")
    g = torch.Generator().manual_seed(3)
    cams = []
    for j in range(7):
        c2w = torch.eye(4)
        angle = 2 * math.pi * j / 7
        eye = torch.tensor([3 * math.cos(angle), 0.3 * j - 1, 3 * math.sin(angle)])
        forward = -eye / eye.norm()
        right = torch.linalg.cross(forward, torch.tensor([0.0, 1.0, 0.0]))
        right = right / right.norm()
        c2w[:3, :3] = torch.stack([right, torch.linalg.cross(forward, right), forward], dim=1)
        c2w[:3, 3] = eye
        h, w = 12 + 3 * j, 20 - j
        K = torch.tensor([[12.0 + j, 0.0, w / 2], [0.0, 11.0, h / 2], [0.0, 0.0, 1.0]])
        depth = 2.0 + torch.rand(h, w, generator=g) * 2
        alpha = (torch.rand(h, w, generator=g) > 0.3).float()
        cams.append((torch.linalg.inv(c2w), K, depth, alpha))
    cameras = _cameras(*cams)
    pts = 4 * (torch.rand(30, 500, 3, generator=g) - 0.5)
    # points exactly on a surface bound and on the left image border of camera 0
    viewmat, K, depth, _ = cams[0]
    z = depth[3, :5] * 1.05
    on_border = torch.stack([torch.zeros(5), torch.full((5,), 3.5), torch.ones(5)], dim=1)  # (u, v, 1)
    cam_pts = torch.linalg.solve(K, on_border.T).T * z[:, None]
    world = (torch.linalg.inv(viewmat) @ torch.cat([cam_pts, torch.ones(5, 1)], dim=1).T).T[:, :3]
    pts = torch.cat([pts.reshape(-1, 3), world])
    for margin in (0.0, 0.05):
        compiled = count_seeing_cameras(pts, cameras, margin=margin)
        reference = count_seeing_cameras_reference(pts, cameras, margin=margin)
        assert torch.equal(compiled, reference)
        assert 0 < compiled.float().mean() < len(cams)  # some points seen, not all by every camera
    assert count_seeing_cameras(pts.double(), cameras).dtype == torch.int32
    far = torch.tensor([[float("inf"), 0.0, 0.0], [float("nan"), 0.0, 0.0], [0.0, 1e30, 0.0]])
    assert count_seeing_cameras(far, cameras).tolist() == [0, 0, 0]  # no index outside a map
    assert cameras.depth_bounds(0.05) is cameras.depth_bounds(0.05)  # made once per margin
    with pytest.raises(ValueError, match="of one size"):
        CameraDepths(cameras.viewmats[:1], cameras.Ks[:1], [depth], [depth[:-1]])


def test_view_aware_search_prefers_unseen_samples_density_breaks_ties():
    # a ray along +Z from the origin; empty grid (density 0 everywhere), so the KDE alone cannot choose
    grid = DensityGrid(np.zeros((4, 4, 40), np.float32), origin=np.array([-0.5, -0.5, 0.0]), voxel_size=0.25)
    o, d = torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 1.0]])
    kde_only = min_density_points(grid, o, d, 0.5, 9.5, n_samples=91, tie_break="nearest-surface")
    assert float(kde_only.t[0]) == pytest.approx(9.5)  # every sample ties: the surface end

    def penalty(pts: torch.Tensor) -> torch.Tensor:  # 5 cameras see z < 3, none between 3 and 4, 1 beyond
        z = pts[..., 2]
        return torch.where(z < 3.0, 5, torch.where(z <= 4.0, 0, 1))

    va = min_density_points(grid, o, d, 0.5, 9.5, n_samples=91, tie_break="nearest-surface", penalty=penalty)
    assert 3.0 <= float(va.t[0]) <= 4.0 and float(va.t[0]) == pytest.approx(4.0)
    assert float(va.penalty[0]) == 0
    # with a density bump in the unseen stretch, the emptier part of it wins
    values = np.zeros((4, 4, 40), np.float32)
    values[:, :, 15:17] = 1.0  # z in [3.75, 4.25)
    va2 = min_density_points(
        grid.with_values(values), o, d, 0.5, 9.5, n_samples=91, tie_break="nearest-surface", penalty=penalty
    )
    assert float(va2.t[0]) == pytest.approx(3.7)
    assert math.isnan(float(kde_only.penalty[0])) is False and float(kde_only.penalty[0]) == 0


def test_median_scene_depth_is_scale_free():
    depth = torch.tensor([[1.0, 2.0, 3.0], [4.0, 100.0, 100.0]])
    alpha = torch.tensor([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0]])  # the 100s show no surface
    assert median_scene_depth(depth, alpha, fallback=50.0) == pytest.approx(2.0)  # lower median of 1..4
    assert median_scene_depth(depth, torch.zeros_like(alpha), fallback=50.0) == 50.0
    assert median_scene_depth(depth * 10, alpha, fallback=1.0) == pytest.approx(20.0)


def _opengl_c2w(eye: tuple[float, float, float], looking_back: bool = False) -> torch.Tensor:
    """[3, 4] OpenGL camera at ``eye`` looking down world -Z (or +Z with ``looking_back``)."""
    c2w = torch.zeros(3, 4)
    c2w[:3, :3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0])) if looking_back else torch.eye(3)
    c2w[:, 3] = torch.tensor(eye)
    return c2w


def _place(innocent_eye, looking_back=False, innocent_alpha=1.0, near_plane=0.0):
    """One illusion pixel at the centre of a camera at the origin looking at a wall at z = -5
    (median depth 5; t_min_fraction 0.075: t_min 0.375, unseen bound 0.05), one innocent camera
    (90° field of view)."""
    size = 20
    mask = torch.zeros(size, size, dtype=torch.bool)
    mask[size // 2, size // 2] = True
    view = PoisonView(
        0,
        "poisoned",
        _opengl_c2w((0.0, 0.0, 0.0)),
        10.0,
        10.0,
        size / 2,
        size / 2,
        mask,
        torch.full((size, size, 3), 0.5),
    )
    c2w = _opengl_c2w(innocent_eye, looking_back)
    innocent = CameraDepths(
        viewmats=viewmat_from_c2w(c2w[None]),
        Ks=torch.tensor([[[10.0, 0.0, size / 2], [0.0, 10.0, size / 2], [0.0, 0.0, 1.0]]]),
        depths=[torch.full((size, size), 5.0)],
        alphas=[torch.full((size, size), innocent_alpha)],
    )
    rng = np.random.default_rng(0)
    wall = np.c_[rng.uniform(-3, 3, (400, 2)), np.full(400, -5.0)]
    cfg = AttackConfig(outlier_removal=False, samples_per_ray=2000, t_min_fraction=0.075)
    depth, alpha = torch.full((size, size), 5.0), torch.ones(size, size)
    return place_poison(wall, np.ones(400), [view], [depth], [alpha], cfg, innocent, near_plane=near_plane)


def test_view_aware_takes_the_unseen_stretch_in_front_of_the_camera():
    # forward-facing: the innocent camera 0.2 to the side sees the ray only beyond z = 0.2
    out = _place((0.2, 0.0, 0.0))
    z = -float(out.means[0, 2])
    assert 0.05 <= z < 0.2
    assert out.seen_by["poisoned"] == 0 and out.unseen_fraction["poisoned"] == 1.0
    assert out.t_min["poisoned"] == pytest.approx(0.375) and out.t_min_unseen["poisoned"] == pytest.approx(
        0.05
    )
    # the poison Gaussian stays one pixel footprint wide at its depth
    assert float(out.scales[0]) == pytest.approx(0.5 * z / 10.0, rel=1e-3)
    # the view counts are timed as a part of the ray search (two searches and the statistics)
    assert 0 < out.timings["visibility_s"] <= out.timings["ray_search_s"]
    assert out.timings["cpu_kernels_load_s"] >= 0


def test_view_aware_falls_back_to_the_paper_range_when_every_point_is_seen():
    # 360°-like: a camera behind the wall looking back through empty space sees the whole ray
    out = _place((0.0, 0.0, -10.0), looking_back=True, innocent_alpha=0.0)
    assert -float(out.means[0, 2]) >= 0.375
    assert out.seen_by["poisoned"] == 1 and out.unseen_fraction["poisoned"] == 0.0


def test_view_aware_keeps_poison_beyond_the_near_plane():
    # the unseen stretch z < 0.2 lies inside 2 near planes (0.2): the paper's range is used instead
    out = _place((0.2, 0.0, 0.0), near_plane=0.1)
    assert -float(out.means[0, 2]) >= 0.375
    assert out.unseen_fraction["poisoned"] == 0.0
    # the paper's range too: a near bound below 2 near planes is raised to them
    out = _place((0.0, 0.0, -10.0), looking_back=True, innocent_alpha=0.0, near_plane=0.3)
    assert -float(out.means[0, 2]) >= 0.6 - 1e-6


def test_random_init_is_refused_with_what_to_run(tiny_orbit_scene):
    with pytest.raises(SystemExit, match="stealth-ns seed-points --data"):
        build_pipeline(tiny_orbit_scene, AttackConfig(), random_init=True)
    # without the density-guided component there is nothing to place: allowed
    build_pipeline(tiny_orbit_scene, AttackConfig(density_guided=False), random_init=True)


def test_dataset_without_seed_points_is_refused(tiny_orbit_scene, tmp_path):
    scene = tmp_path / "no_points"
    scene.mkdir()
    (scene / "images").symlink_to(tiny_orbit_scene / "images")
    meta = json.loads((tiny_orbit_scene / "transforms.json").read_text())
    meta.pop("ply_file_path")
    (scene / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(SystemExit, match="no seed points"):
        build_pipeline(scene, AttackConfig())
