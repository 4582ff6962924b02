"""Tests for the procedural scene generator (``stealth_ns.scenes``, ``stealth-ns make-scene``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stealth_ns.errors import StealthNSError
from stealth_ns.scenes import make_scene
from stealth_ns.scenes.geometry import Geometry, cast_rays
from stealth_ns.scenes.writer import read_ply

REPO = Path(__file__).resolve().parents[1]
RES = "64x48"


@pytest.fixture(scope="module")
def orbit_scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("orbit") / "scene"
    make_scene("orbit", out, resolution=RES, views=16, seed=3)
    return out


@pytest.fixture(scope="module")
def forward_scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("forward") / "scene"
    make_scene("forward", out, resolution=RES, seed=1)
    return out


def _load(scene: Path):
    """transforms.json, images (V, H, W, 3) float [0, 1], depths (V, H, W), ply xyz, rgb float."""
    meta = json.loads((scene / "transforms.json").read_text())
    images = np.stack([np.asarray(Image.open(scene / f["file_path"])) for f in meta["frames"]]) / 255.0
    depths = np.stack([np.load(scene / f["depth_file_path"]) for f in meta["frames"]])
    xyz, rgb = read_ply(scene / meta["ply_file_path"])
    return meta, images, depths, xyz.astype(np.float64), rgb / 255.0


def _project(meta: dict, c2w: np.ndarray, xyz: np.ndarray):
    """Pixel indices (col, row), z-depth and in-frame mask of world points xyz (N, 3) (OpenGL)."""
    w2c = np.linalg.inv(np.asarray(c2w, dtype=np.float64))
    cam = xyz @ w2c[:3, :3].T + w2c[:3, 3]
    z = -cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = meta["fl_x"] * cam[:, 0] / z + meta["cx"]
        v = -meta["fl_y"] * cam[:, 1] / z + meta["cy"]
    ok = (z > 1e-3) & (u >= 0) & (u < meta["w"]) & (v >= 0) & (v < meta["h"])
    col = np.where(ok, np.floor(u), 0).astype(int)
    row = np.where(ok, np.floor(v), 0).astype(int)
    return col, row, z, ok


def _train_indices(meta: dict) -> list[int]:
    names = set(meta["train_filenames"])
    return [i for i, f in enumerate(meta["frames"]) if f["file_path"] in names]


def _centre_point(meta: dict, c2w, depth: np.ndarray) -> np.ndarray:
    """World point (3,) seen by the pixel nearest the image centre (from its z-depth)."""
    row, col = meta["h"] // 2, meta["w"] // 2
    d_cam = np.array(
        [(col + 0.5 - meta["cx"]) / meta["fl_x"], -(row + 0.5 - meta["cy"]) / meta["fl_y"], -1.0]
    )
    m = np.asarray(c2w)
    return m[:3, :3] @ (d_cam * depth[row, col]) + m[:3, 3]


# --------------------------------------------------------------------------------------------
# geometry


def test_ray_casting_primitives():
    g = Geometry()
    plane = g.add_plane((0, 1, 0), 0.0)
    sphere = g.add_sphere((0, 1, -5), 1.0)
    box = g.add_box((3, 1, -5), (0.5, 0.5, 0.5), yaw=np.pi / 4)
    cyl = g.add_cylinder((-3, -5), 0.5, 0.0, 2.0)
    origin = np.array([0.0, 1.0, 0.0])
    targets = np.array([[0, 1, -5], [3, 1, -5], [-3, 1, -5], [-3, 2.5, -5], [0, -1, -3], [0, 3, -1]], float)
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = cast_rays(g, origin, dirs)
    assert hits.prim.tolist() == [sphere, box, cyl, -1, plane, -1]
    np.testing.assert_allclose(hits.t[0], 4.0, atol=1e-9)
    np.testing.assert_allclose(hits.normal[0], [0, 0, 1], atol=1e-9)
    # rotated box: the ray through its centre meets the face with normal (-1, 0, 1) / sqrt(2)
    to_cam = (origin - [3, 1, -5]) / np.linalg.norm(origin - [3, 1, -5])
    face = np.array([-1.0, 0.0, 1.0]) / np.sqrt(2)
    np.testing.assert_allclose(hits.t[1], np.hypot(3, 5) - 0.5 / (to_cam @ face), atol=1e-9)
    np.testing.assert_allclose(hits.normal[1], face, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(hits.normal, axis=1)[[0, 1, 2, 4]], 1.0)
    np.testing.assert_allclose(hits.normal[4], [0, 1, 0])
    # per-ray origins give the same answer as a shared origin
    hits2 = cast_rays(g, np.broadcast_to(origin, dirs.shape).copy(), dirs)
    np.testing.assert_array_equal(hits.prim, hits2.prim)
    np.testing.assert_allclose(hits.t, hits2.t)
    # a ray from inside a box hits its far wall; a cylinder cap is hit from above
    inside = cast_rays(g, np.array([3.0, 1.0, -5.0]), np.array([[0.0, 1.0, 0.0]]))
    np.testing.assert_allclose(inside.t, [0.5])
    cap = cast_rays(g, np.array([-3.0, 5.0, -5.0]), np.array([[0.0, -1.0, 0.0]]))
    assert cap.prim[0] == cyl
    np.testing.assert_allclose(cap.t, [3.0])
    np.testing.assert_allclose(cap.normal[0], [0, 1, 0])


# --------------------------------------------------------------------------------------------
# output format


def test_layout_and_summary(tmp_path):
    summary = make_scene("orbit", tmp_path / "s", resolution="32x24", views=9, seed=5)
    out = tmp_path / "s"
    assert sorted(p.name for p in out.iterdir()) == [
        "depths",
        "images",
        "scene.json",
        "sparse_pc.ply",
        "transforms.json",
    ]
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV"
    assert (meta["w"], meta["h"], meta["cx"], meta["cy"]) == (32, 24, 16.0, 12.0)
    assert meta["fl_x"] == meta["fl_y"] == pytest.approx(16 / np.tan(np.deg2rad(30)), rel=1e-6)
    assert all(meta[k] == 0 for k in ("k1", "k2", "p1", "p2"))
    assert meta["ply_file_path"] == "sparse_pc.ply"
    assert meta["test_filenames"] == ["images/frame_00000.png", "images/frame_00008.png"]
    assert meta["val_filenames"] == meta["test_filenames"]
    assert len(meta["train_filenames"]) == 7
    frame = meta["frames"][3]
    assert frame["file_path"] == "images/frame_00003.png"
    assert frame["depth_file_path"] == "depths/frame_00003.npy"
    assert np.asarray(frame["transform_matrix"]).shape == (4, 4)
    img = Image.open(out / frame["file_path"])
    assert (img.mode, img.size) == ("RGB", (32, 24))
    depth = np.load(out / frame["depth_file_path"])
    assert depth.dtype == np.float32 and depth.shape == (24, 32) and depth.max() > 0
    info = json.loads((out / "scene.json").read_text())
    assert info["preset"] == "orbit" and info["seed"] == 5 and info["resolution"] == [32, 24]
    assert len(info["centre"]) == 3 and info["radius"] > 0
    # orbit cameras all look at the scene centre
    for f in meta["frames"]:
        m = np.asarray(f["transform_matrix"])
        to_centre = np.asarray(info["centre"]) - m[:3, 3]
        np.testing.assert_allclose(-m[:3, 2], to_centre / np.linalg.norm(to_centre), atol=1e-6)
    text = str(summary)
    assert str(out) in text and "7 train / 2 test" in text and "32x24" in text
    assert f"ns-train stealth-splat-lite --vis tensorboard nerfstudio-data --data {out}" in text
    assert summary.n_points == len(read_ply(out / "sparse_pc.ply")[0]) > 1000


@pytest.mark.parametrize("split,count", [("train", 14), ("val", 2), ("test", 2)])
def test_nerfstudio_dataparser_loads_scene(orbit_scene, split, count):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    meta = json.loads((orbit_scene / "transforms.json").read_text())
    outputs = (
        NerfstudioDataParserConfig(data=orbit_scene, load_3D_points=True)
        .setup()
        .get_dataparser_outputs(split=split)
    )
    names = [p.relative_to(orbit_scene).as_posix() for p in outputs.image_filenames]
    expected = meta["train_filenames"] if split == "train" else meta["test_filenames"]
    assert names == expected and len(names) == count
    cams = outputs.cameras
    assert cams.fx.flatten().tolist() == pytest.approx([meta["fl_x"]] * count)
    assert cams.cy.flatten().tolist() == pytest.approx([meta["cy"]] * count)
    assert cams.width.flatten().tolist() == [64] * count and cams.height.flatten().tolist() == [48] * count
    n_points = len(read_ply(orbit_scene / "sparse_pc.ply")[0])
    assert tuple(outputs.metadata["points3D_xyz"].shape) == (n_points, 3)
    assert tuple(outputs.metadata["points3D_rgb"].shape) == (n_points, 3)
    assert len(outputs.metadata["depth_filenames"]) == count
    # auto-scaled into the unit cube
    assert cams.camera_to_worlds[:, :3, 3].abs().max() <= 1.0 + 1e-5


# --------------------------------------------------------------------------------------------
# poses, depth and seed points agree


@pytest.mark.parametrize("scene_name", ["orbit_scene", "forward_scene"])
def test_seed_points_project_onto_matching_colours(scene_name, request):
    meta, images, depths, xyz, rgb = _load(request.getfixturevalue(scene_name))
    rng = np.random.default_rng(0)
    errors, baseline = [], []
    best = np.full(len(xyz), np.inf)  # each point's smallest colour error over the views that see it
    for i in _train_indices(meta):
        col, row, z, ok = _project(meta, meta["frames"][i]["transform_matrix"], xyz)
        d = depths[i][row, col]
        visible = ok & (d > 0) & (np.abs(z - d) < 0.02 * z)
        pixel = images[i][row[visible], col[visible]]
        err = np.abs(pixel - rgb[visible]).mean(axis=1)
        errors.append(err)
        best[visible] = np.minimum(best[visible], err)
        shuffled = rgb[rng.integers(len(rgb), size=int(visible.sum()))]
        baseline.append(np.abs(pixel - shuffled).mean(axis=1))
    errors, baseline = np.concatenate(errors), np.concatenate(baseline)
    assert errors.size > 3 * len(xyz)  # each point is visible in several views
    assert np.isfinite(best).mean() > 0.98
    # a seed point lands on the pixel it was sampled from in its source view ...
    assert np.median(best) < 0.02
    # ... and on similar colours in the other views (textures are high-frequency, so not exactly)
    assert np.median(errors) < 0.1
    assert np.median(baseline) > 2 * np.median(errors)


@pytest.mark.parametrize("scene_name", ["orbit_scene", "forward_scene"])
def test_depth_is_z_depth_at_seed_points(scene_name, request):
    meta, _, depths, xyz, _ = _load(request.getfixturevalue(scene_name))
    best = np.full(len(xyz), np.inf)
    for i in _train_indices(meta):
        col, row, z, ok = _project(meta, meta["frames"][i]["transform_matrix"], xyz)
        rel = np.where(ok, np.abs(z - depths[i][row, col]) / np.where(ok, z, 1.0), np.inf)
        best = np.minimum(best, rel)
    # every seed point was sampled at a pixel centre of some training view (plus 0.3% noise)
    assert np.median(best) < 0.005
    assert np.percentile(best, 95) < 0.02
    # sky pixels have depth 0, everything else is in front of the camera
    assert (depths >= 0).all() and (depths > 0).mean() > 0.5


def test_forward_view_coverage_varies(forward_scene):
    meta, _, depths, _, _ = _load(forward_scene)
    train = _train_indices(meta)
    counts, seen_before = [], []
    for i in train:
        p = _centre_point(meta, meta["frames"][i]["transform_matrix"], depths[i])[None]
        seen = []
        for j in train:
            if j == i:
                continue
            col, row, z, ok = _project(meta, meta["frames"][j]["transform_matrix"], p)
            seen.append(j if ok[0] and abs(depths[j][row[0], col[0]] - z[0]) < 0.03 * z[0] else None)
        seen = [j for j in seen if j is not None]
        counts.append(len(seen))
        seen_before.append(any(j < i for j in seen))
    counts = np.array(counts)
    # cameras move forward: what a view looks at was mostly seen by earlier views, and some regions
    # are covered by many more views than others
    assert np.mean(seen_before[1:]) > 0.6
    assert counts.max() - counts.min() >= len(train) // 3
    assert counts.std() > 4


@pytest.mark.parametrize("scene_name", ["orbit_scene", "forward_scene"])
def test_images_are_richly_textured(scene_name, request):
    _, images, _, _, _ = _load(request.getfixturevalue(scene_name))
    v, h, w, _ = images.shape
    blocks = images[:, : h // 4 * 4, : w // 4 * 4].reshape(v, h // 4, 4, w // 4, 4, 3)
    flat = (blocks.std(axis=(2, 4)).max(axis=-1) < 1.0 / 255).mean(axis=(1, 2))
    assert flat.max() < 0.1  # hardly any uniform 4x4 pixel block
    assert images.min() >= 0 and images.max() <= 1 and images.std() > 0.1


# --------------------------------------------------------------------------------------------
# determinism


def test_same_seed_gives_identical_files(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for out, seed in ((a, 7), (b, 7), (c, 8)):
        make_scene("forward", out, resolution="40x30", views=8, seed=seed)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert len(files) == 8 + 8 + 3
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    for i in range(8):
        name = f"images/frame_{i:05d}.png"
        assert (
            np.abs(np.asarray(Image.open(a / name), float) - np.asarray(Image.open(c / name), float)).mean()
            > 10
        )


# --------------------------------------------------------------------------------------------
# errors


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(resolution="128x"), "resolution must look like WIDTHxHEIGHT"),
        (dict(resolution="abc"), "resolution must look like WIDTHxHEIGHT"),
        (dict(resolution="0x96"), "positive width and height"),
        (dict(views=7), "views must be an integer of at least 8"),
        (dict(preset="spiral"), "unknown preset 'spiral'"),
        (dict(seed=-1), "seed must be a non-negative integer"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, message):
    args = dict(preset="orbit", output=tmp_path / "out", resolution="16x12", views=8) | kwargs
    with pytest.raises(StealthNSError, match=message) as info:
        make_scene(**args)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "out").exists()


def test_output_not_writable(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(StealthNSError, match="not writable"):
        make_scene("orbit", blocker / "scene", resolution="16x12", views=8)
    with pytest.raises(StealthNSError, match="exists and is not a folder"):
        make_scene("orbit", blocker, resolution="16x12", views=8)


def test_non_empty_output_needs_overwrite(tmp_path):
    out = tmp_path / "scene"
    make_scene("orbit", out, resolution="16x12", views=16)
    (out / "notes.txt").write_text("keep me")
    with pytest.raises(StealthNSError, match=r"exists and is not empty; pass --overwrite"):
        make_scene("orbit", out, resolution="16x12", views=8)
    make_scene("orbit", out, resolution="16x12", views=8, overwrite=True)
    assert len(list((out / "images").iterdir())) == 8  # no stale frames from the 16-view run
    assert len(list((out / "depths").iterdir())) == 8
    assert len(json.loads((out / "transforms.json").read_text())["frames"]) == 8
    assert (out / "notes.txt").read_text() == "keep me"


def test_cli_main_raises_for_bad_resolution(tmp_path):
    from stealth_ns.cli import main

    with pytest.raises(StealthNSError, match="resolution"):
        main(["make-scene", "--output", str(tmp_path / "o"), "--resolution", "abc"])
    main(
        [
            "make-scene",
            "--output",
            str(tmp_path / "ok"),
            "--resolution",
            "16x12",
            "--views",
            "8",
            "--preset",
            "forward",
        ]
    )
    assert (tmp_path / "ok" / "transforms.json").exists()


def test_console_script_reports_one_line_error(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [
        sys.executable,
        "-m",
        "stealth_ns.cli",
        "make-scene",
        "--output",
        str(tmp_path / "o"),
        "--views",
        "3",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stealth-ns: error: views must be")
    assert "Traceback" not in proc.stderr
