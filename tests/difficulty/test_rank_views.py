"""The KDE difficulty protocol (``stealth_ns.difficulty``, ``stealth-ns rank-views``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from stealth_ns.attack.density import DensityGrid
from stealth_ns.difficulty import protocol
from stealth_ns.difficulty.protocol import frustum_samples, rank, view_densities
from stealth_ns.difficulty.rank import RankViews, rank_scene_views
from stealth_ns.difficulty.ranking import ViewRanking
from stealth_ns.foundation.errors import StealthNSError

W, H = 64, 48
FX = FY = W / (2 * math.tan(math.radians(30)))  # 60 degrees horizontal field of view
CX, CY = W / 2, H / 2


def yaw_c2w(deg: float, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """[3, 4] camera at ``centre`` turned ``deg`` degrees about +Y (0: looking along -Z)."""
    a = math.radians(deg)
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    return np.concatenate([rot, np.asarray(centre, dtype=np.float64)[:, None]], axis=1)


def blob_grid(centre=(0.0, 0.0, -1.0), sigma: float = 0.3) -> DensityGrid:
    """A Gaussian blob of density (peak 1) on a 40^3 grid covering [-2, 2]^3."""
    grid = DensityGrid(values=np.zeros((40, 40, 40)), origin=np.full(3, -2.0), voxel_size=0.1)
    r2 = ((grid.centers() - np.asarray(centre)) ** 2).sum(-1)
    return grid.with_values(np.exp(-r2 / (2 * sigma**2)))


def test_defaults_are_the_attacks_and_stay_light():
    """The protocol's KDE defaults come from AttackConfig, whose import loads neither nerfstudio
    nor torch (so ``stealth-ns rank-views`` starts fast)."""
    import subprocess
    import sys

    from stealth_ns.attack.config import AttackConfig

    assert protocol.DEFAULT_GRID_RESOLUTION == AttackConfig().grid_resolution
    assert protocol.DEFAULT_BANDWIDTH == AttackConfig().bandwidth
    assert RankViews.bandwidth == AttackConfig().bandwidth
    code = (
        "import sys, stealth_ns.difficulty.rank, stealth_ns.attack.config; "
        "print(sorted(m for m in ('torch', 'nerfstudio') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_frustum_samples_lie_in_the_fov_and_radius():
    rot = yaw_c2w(37.0)[:, :3]
    tilt = math.radians(-20.0)
    rx = np.array([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]])
    c2w = np.concatenate([rot @ rx, np.array([[0.3], [-1.2], [2.0]])], axis=1)
    cx, cy, radius = 30.0, 20.0, 0.7  # off-centre principal point
    pts, w = frustum_samples(c2w, FX, FY * 1.1, cx, cy, W, H, radius, n_dirs=12, n_depths=7)
    assert pts.shape == (12 * 9 * 7, 3) and w.shape == (12 * 9 * 7,)
    assert np.all(w > 0) and w.sum() == pytest.approx(1.0)
    cam = (pts - c2w[:, 3]) @ c2w[:, :3]  # world -> camera coordinates (rows times R)
    dist = np.linalg.norm(cam, axis=1)
    assert np.all(dist > 0) and np.all(dist <= radius + 1e-12)
    assert dist.max() > 0.95 * radius and dist.min() < 0.5 * radius
    assert np.all(cam[:, 2] < 0)  # in front: the camera looks along -Z
    u = FX * cam[:, 0] / -cam[:, 2] + cx
    v = -FY * 1.1 * cam[:, 1] / -cam[:, 2] + cy  # image v grows downwards, camera +Y is up
    assert np.all((u > 0) & (u < W) & (v > 0) & (v < H))
    assert u.min() < 0.1 * W and u.max() > 0.9 * W and v.min() < 0.1 * H and v.max() > 0.9 * H
    # Top rows of the image see the camera's +Y side.
    assert np.all(cam[v < cy - 1, 1] > 0)


def test_constant_density_averages_to_its_value():
    grid = DensityGrid(values=np.full((20, 20, 20), 0.25), origin=np.full(3, -2.0), voxel_size=0.2)
    c2ws = np.stack([yaw_c2w(a) for a in (0, 90, 200)])
    d = view_densities(grid, c2ws, FX, FY, CX, CY, W, H, radius=1.5, n_dirs=8, n_depths=5)
    np.testing.assert_allclose(d, 0.25, rtol=1e-6)
    # Space outside the grid counts as empty: a camera far away sees nothing.
    far = view_densities(grid, yaw_c2w(0, (10.0, 0, 0))[None], FX, FY, CX, CY, W, H, radius=1.0)
    assert far[0] == 0.0


def test_ranking_follows_a_known_density():
    """Cameras at the origin turned away from a blob in front (-Z): the further they turn, the emptier."""
    grid = blob_grid()
    angles = [90, 0, 180, 45, 135, 270]  # capture order, shuffled; 270 = -90 mirrors 90
    c2ws = np.stack([yaw_c2w(a) for a in angles])
    d = view_densities(grid, c2ws, FX, FY, CX, CY, W, H, radius=1.5, n_dirs=16, n_depths=12)
    assert d[1] > d[3] > d[0] > d[4] > d[2] >= 0  # 0 > 45 > 90 > 135 > 180 degrees
    assert d[0] == pytest.approx(d[5], rel=1e-3)  # symmetric turns see the same density
    easy, median, hard = rank(d)
    assert (easy, hard) == (2, 1)
    assert median == int(np.argsort(d, kind="stable")[(len(d) - 1) // 2])
    assert median in (0, 5)  # the two 90-degree views sit in the middle of the sorted list
    ranking = ViewRanking(
        names=[f"frame_{a:03d}.png" for a in angles], indices=list(range(6)), densities=d, radius=1.5
    )
    assert (ranking.easy, ranking.hard) == ("frame_180.png", "frame_000.png")
    assert ranking.easy_index == 2 and ranking.hard_index == 1
    assert list(ranking.densities[ranking.order]) == sorted(d)


def test_rank_ties_and_edge_cases():
    assert rank(np.array([3.0, 1.0, 2.0, 1.0])) == (1, 3, 0)  # stable: view 1 before view 3
    assert rank(np.array([5.0, 5.0, 5.0])) == (0, 1, 2)
    assert rank(np.array([0.2])) == (0, 0, 0)
    for bad in (np.array([]), np.array([1.0, np.nan]), np.ones((2, 2))):
        with pytest.raises(ValueError):
            rank(bad)
    one = ViewRanking(names=["a.png"], indices=[0], densities=[0.5], radius=1.0)
    assert "Easy/Median/Hard" in one.table()


@pytest.fixture(scope="module")
def forward_scene(tmp_path_factory) -> Path:
    from stealth_ns.scene_generator import make_scene

    out = tmp_path_factory.mktemp("rank") / "forward"
    make_scene(preset="forward", output=out, resolution="64x48", views=16, seed=0)
    return out


def test_forward_scene_ranking(forward_scene):
    ranking = rank_scene_views(forward_scene)
    meta = json.loads((forward_scene / "transforms.json").read_text())
    assert ranking.names == sorted(Path(p).name for p in meta["train_filenames"])
    assert ranking.indices == list(range(len(ranking.names))) and len(ranking.names) == 14
    d = ranking.densities
    assert d.shape == (14,) and np.all(np.isfinite(d)) and np.all((d >= 0) & (d <= 1)) and d.max() > 0
    assert ranking.radius == pytest.approx(0.1 * ranking.diagonal)
    order = np.argsort(d, kind="stable")
    assert [ranking.easy, ranking.median, ranking.hard] == [ranking.names[i] for i in order[[0, 6, -1]]]
    assert ranking.easy_index == order[0] and ranking.hard_index == order[-1]
    # A larger radius is a different (but still valid) measurement.
    wider = rank_scene_views(forward_scene, radius_fraction=0.2, n_dirs=8, n_depths=8)
    assert wider.radius == pytest.approx(2 * ranking.radius)


def write_colmap_copy(scene: Path, out: Path) -> None:
    """The scene's poses and seed points as a COLMAP text model in ``out/sparse/0`` (no images needed).

    Points and poses are written in COLMAP's world frame (the inverse of the world rotation nerfstudio's
    colmap dataparser applies), so both dataparsers must give the same cameras and points.
    """
    from nerfstudio.data.utils import colmap_parsing_utils as cu

    from stealth_ns.scene_generator.writer import read_ply

    meta = json.loads((scene / "transforms.json").read_text())
    to_ns = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # what the colmap dataparser applies to the world
    cams = {
        1: cu.Camera(1, "PINHOLE", meta["w"], meta["h"], [meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]])
    }
    images = {}
    for i, frame in enumerate(meta["frames"], start=1):
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)[:3]
        c2w[:, 1:3] *= -1  # OpenGL -> OpenCV camera axes
        c2w = to_ns.T @ c2w
        rot = c2w[:, :3].T
        name = Path(frame["file_path"]).name
        empty = np.zeros((0, 2))
        images[i] = cu.Image(i, cu.rotmat2qvec(rot), -rot @ c2w[:, 3], 1, name, empty, np.zeros(0, dtype=int))
    xyz, rgb = read_ply(scene / meta["ply_file_path"])
    pts = {
        i: cu.Point3D(
            i, to_ns.T @ p.astype(np.float64), c, 0.5, np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        )
        for i, (p, c) in enumerate(zip(xyz, rgb, strict=True), start=1)
    }
    (out / "sparse" / "0").mkdir(parents=True)
    cu.write_model(cams, images, pts, str(out / "sparse" / "0"), ext=".txt")


def test_colmap_dataset_gives_the_same_ranking(forward_scene, tmp_path):
    colmap = tmp_path / "colmap_scene"
    write_colmap_copy(forward_scene, colmap)
    from_colmap = rank_scene_views(colmap, n_dirs=12, n_depths=12)
    from_ns = rank_scene_views(forward_scene, n_dirs=12, n_depths=12)
    assert from_colmap.dataparser == "colmap" and from_ns.dataparser == "nerfstudio-data"
    assert from_colmap.names == from_ns.names
    np.testing.assert_allclose(from_colmap.densities, from_ns.densities, atol=1e-3)
    assert from_colmap.radius == pytest.approx(from_ns.radius, rel=1e-4)


def test_cli_writes_json_and_png(forward_scene, tmp_path, capsys):
    from stealth_ns.cli import main

    out = tmp_path / "ranking"
    main(
        ["rank-views", "--data", str(forward_scene), "--output", str(out)]
    )  # in-process: nerfstudio is loaded
    stdout = capsys.readouterr().out
    report = json.loads((out / "view_ranking.json").read_text())
    png = (out / "view_ranking.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 5000
    views = report["views"]
    assert len(views) == 14 and [v["index"] for v in views] == list(range(14))
    by_rank = sorted(views, key=lambda v: v["rank"])
    dens = [v["density"] for v in by_rank]
    assert dens == sorted(dens)
    assert report["easy"]["name"] == by_rank[0]["name"] and report["hard"]["name"] == by_rank[-1]["name"]
    assert report["median"]["name"] == by_rank[(14 - 1) // 2]["name"]
    assert report["radius"] == pytest.approx(0.1 * report["diagonal"])
    assert report["settings"]["grid_resolution"] == 160 and report["settings"]["bandwidth"] == 7.5
    # The table lists every view in ascending density (rank, index, view, density[, <- label]).
    rows = [ln.split() for ln in stdout.splitlines() if ln.split()[:1] and ln.split()[0].isdigit()]
    assert [row[2] for row in rows] == [v["name"] for v in by_rank]
    marked = {row[-1]: row[2] for row in rows if len(row) == 6 and row[4] == "<-"}
    assert marked == {label: report[label.lower()]["name"] for label in ("Easy", "Median", "Hard")}
    assert str(out / "view_ranking.json") in stdout


def test_cli_missing_folder_is_a_one_line_error(tmp_path):
    proc = run_cli("stealth-ns", "rank-views", "--data", str(tmp_path / "nope"), check=False, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("stealth-ns: error:") and proc.stderr.strip().count("\n") == 0
    assert "does not exist" in proc.stderr and "Traceback" not in proc.stderr


def test_datasets_without_seed_points_are_refused(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(StealthNSError, match="no transforms.json"):
        rank_scene_views(empty)
    blender = tmp_path / "blender"
    blender.mkdir()
    (blender / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": []}))
    with pytest.raises(StealthNSError, match="needs seed points") as refused:
        rank_scene_views(blender)
    assert f"stealth-ns seed-points --data {blender}" in str(refused.value)
    no_ply = tmp_path / "no_ply"
    no_ply.mkdir()
    (no_ply / "transforms.json").write_text(json.dumps({"fl_x": 50.0, "frames": []}))
    with pytest.raises(StealthNSError, match="needs the scene's seed points; triangulate them with"):
        rank_scene_views(no_ply)
    (no_ply / "transforms.json").write_text("{not json")
    with pytest.raises(StealthNSError, match="cannot read"):
        rank_scene_views(no_ply)
    with pytest.raises(StealthNSError, match="radius fraction"):
        rank_scene_views(no_ply, radius_fraction=0.0)


def test_cli_output_that_is_a_file_is_an_error(forward_scene, tmp_path):
    from stealth_ns.cli import main

    target = tmp_path / "file.txt"
    target.write_text("x")
    with pytest.raises(StealthNSError, match="is not a folder"):
        main(["rank-views", "--data", str(forward_scene), "--output", str(target)])


def test_a_folder_with_two_colmap_models_is_ranked_on_the_one_the_bench_attacks(tmp_path):
    """rank-views and the bench used to look for the COLMAP model in different orders (issue 32)."""
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.difficulty.dataset import detect_format

    for rel in ("colmap/sparse/0", "sparse/0"):
        model = tmp_path / rel
        model.mkdir(parents=True)
        for name in ("cameras.txt", "images.txt", "points3D.txt"):
            (model / name).write_text("")
    (tmp_path / "images").mkdir()
    assert detect_format(tmp_path) == ("colmap", Path(inspect_folder("x", str(tmp_path)).colmap_path))
