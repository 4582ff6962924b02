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
from stealth_ns.attack.visibility import (
    CameraDepths,
    SeenPenalty,
    count_seeing_cameras,
    count_seeing_cameras_reference,
)
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


def _ring_cameras(g: torch.Generator, n: int = 7) -> list[tuple]:
    """``n`` cameras of different sizes on a ring around the origin, looking at it, random depth
    maps of surfaces 2-4 units away, 30 % of pixels showing none."""
    cams = []
    for j in range(n):
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
    return cams


def test_count_seeing_cameras_compiled_equals_reference():
    """The compiled kernel counts exactly what the torch reference counts: cameras of different sizes
    around the points, points behind cameras, on image borders, on the depth bound and off screen."""
    from stealth_ns.raster.cpp_backend import load_extension

    if load_extension() is None:
        pytest.skip("compiled kernels unavailable")
    g = torch.Generator().manual_seed(3)
    cams = _ring_cameras(g)
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


def test_compiled_ray_search_equals_the_torch_search(monkeypatch):
    """One compiled pass (raster/csrc/ray_search_cpu.cpp) chooses exactly the samples of the torch
    search: every tie-break, with and without innocent and support cameras, rays that start or end
    outside the grid, empty space (exact ties) and invalid rays."""
    from stealth_ns.attack import ray_search
    from stealth_ns.raster.cpp_backend import load_extension

    if load_extension() is None:
        pytest.skip("compiled kernels unavailable")
    g = torch.Generator().manual_seed(5)
    cams = _ring_cameras(g)
    values = torch.rand(24, 20, 28, generator=g)
    values[values < 0.4] = 0.0  # empty voxels: many samples tie at exactly 0
    grid = DensityGrid(values.numpy(), origin=np.array([-1.5, -1.2, -1.6]), voxel_size=0.11)
    o = 5 * (torch.rand(400, 3, generator=g) - 0.5)
    d = torch.nn.functional.normalize(-o + torch.randn(400, 3, generator=g), dim=-1)
    t_max = 2 + 4 * torch.rand(400, generator=g)
    t_max[:5] = 0.1  # below t_min: invalid
    penalties = [
        None,
        SeenPenalty(_cameras(*cams), None, 0.05),
        SeenPenalty(_cameras(*cams[:5]), _cameras(*cams[5:]), 0.0),
    ]
    compiled_calls = []
    real = ray_search._search_compiled

    def counted(*a):
        found = real(*a)
        compiled_calls.append(found is not None)
        return found

    monkeypatch.setattr(ray_search, "_search_compiled", counted)
    for penalty in penalties:
        for tie_break in ("nearest-surface", "first", "middle"):
            for tie_tol, outside, n in ((1e-6, 0.0, 257), (0.05, 1.0, 64), (1e-6, 0.0, 1)):
                args = (grid, o, d, 0.3, t_max, n, tie_break, tie_tol, "nearest", outside)
                with monkeypatch.context() as m:
                    m.setattr(ray_search, "_extension", lambda: None)
                    torch_path = min_density_points(*args, penalty=penalty)
                compiled = min_density_points(*args, penalty=penalty)
                for name in ("points", "t", "density", "valid", "penalty"):
                    a, b = getattr(compiled, name), getattr(torch_path, name)
                    assert torch.equal(a.nan_to_num(-7.0), b.nan_to_num(-7.0)), (name, tie_break, n)
                assert float(torch_path.penalty[5:].max()) > 0 or penalty is None
    # the torch runs found no extension, the others ran the compiled pass
    assert compiled_calls == [False, True] * (3 * 3 * 3)


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


def _place(
    innocent_eye, looking_back=False, innocent_alpha=1.0, near_plane=0.0, innocent_depth=5.0, **cfg_kw
):
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
        depths=[torch.full((size, size), innocent_depth)],
        alphas=[torch.full((size, size), innocent_alpha)],
    )
    rng = np.random.default_rng(0)
    wall = np.c_[rng.uniform(-3, 3, (400, 2)), np.full(400, -5.0)]
    cfg = AttackConfig(outlier_removal=False, samples_per_ray=2000, t_min_fraction=0.075, **cfg_kw)
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
    # the view counts outside the compiled search (the statistics') and the kernels' load are timed as
    # parts of the ray search
    assert 0 < out.timings["visibility_s"] <= out.timings["ray_search_s"]
    assert 0 <= out.timings["cpu_kernels_load_s"] <= out.timings["ray_search_s"]


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


def _frustum_ratio(point: torch.Tensor, eye: tuple[float, float, float], scene_depth: float) -> float:
    """camera-proximity's ratio of ``point`` for an OpenGL camera at ``eye`` looking down -Z (90° fov)."""
    z = float(eye[2] - point[2])
    inside = z > 0 and abs(float(point[0] - eye[0])) < z and abs(float(point[1] - eye[1])) < z
    return z / scene_depth if inside else math.inf


@pytest.mark.parametrize("placement", ["view-aware", "kde"])
def test_depth_floor_keeps_poison_away_from_every_camera_that_has_it_in_view(placement):
    # without a floor, view-aware poison hides just in front of the poisoned camera (ratio < 0.04)
    free = _place((0.2, 0.0, 0.0), placement=placement)
    assert -float(free.means[0, 2]) < 0.2 or placement == "kde"
    # with it, it sits at >= 0.3 of the scene depth (5) from both cameras, where the innocent one sees it
    out = _place((0.2, 0.0, 0.0), placement=placement, depth_floor=0.3)
    point = out.means[0]
    for eye in ((0.0, 0.0, 0.0), (0.2, 0.0, 0.0)):
        assert _frustum_ratio(point, eye, 5.0) >= 0.3
    assert -float(point[2]) <= 5.0 and out.below_floor == {"poisoned": 0}
    if placement == "view-aware":
        assert out.seen_by["poisoned"] == 1  # the price of the floor: a view that sees the poison


def test_depth_floor_drops_rays_that_cannot_meet_it():
    # the innocent camera's scene is 100 away: 0.3 of it (30) lies beyond the wall the ray ends on
    out = _place((0.2, 0.0, 0.0), innocent_depth=100.0, depth_floor=0.3)
    assert (
        out.means.shape == (0, 3) and out.below_floor == {"poisoned": 1} and out.per_view == {"poisoned": 0}
    )
    # a camera that does not have the ray in view does not bind: looking away, behind the wall
    out = _place((0.0, 0.0, -10.0), innocent_depth=100.0, depth_floor=0.3)
    assert out.means.shape == (1, 3) and -float(out.means[0, 2]) >= 1.5


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
