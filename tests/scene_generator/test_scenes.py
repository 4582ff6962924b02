"""Tests for the procedural scene generator (``stealth_ns.scene_generator``, ``stealth-ns make-scene``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import image_size, read_image, to_float32
from stealth_ns.scene_generator import make_scene
from stealth_ns.scene_generator.geometry import Geometry, cast_rays
from stealth_ns.scene_generator.writer import MANIFEST, read_ply

REPO = Path(__file__).resolve().parents[2]
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
    images = np.stack([to_float32(read_image(scene / f["file_path"])) for f in meta["frames"]])
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
        MANIFEST,
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
    img = Image.open(out / frame["file_path"])  # what nerfstudio decodes: an 8-bit RGB PNG
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


@pytest.mark.parametrize("scene_name", ["orbit_scene", "forward_scene", "facing_scene"])
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
    assert len(files) == 8 + 8 + 3 + 1  # images, depths, transforms/ply/scene.json, the manifest
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    for i in range(8):
        name = f"images/frame_{i:05d}.png"
        assert np.abs(read_image(a / name).astype(float) - read_image(c / name).astype(float)).mean() > 10


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


def _tree(folder: Path) -> dict[str, bytes]:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in files}


@pytest.mark.parametrize("preset", ["orbit", "object"])
def test_manifest_records_exactly_the_files_written(tmp_path, preset):
    out = tmp_path / "scene"
    make_scene(preset, out, resolution="16x12", views=8)
    recorded = json.loads((out / MANIFEST).read_text())["files"]
    assert set(recorded) == set(_tree(out)) - {MANIFEST}
    assert all(isinstance(h, str) and len(h) == 64 for h in recorded.values())


def test_overwrite_never_touches_a_users_files(tmp_path):
    # a user's dataset (no manifest): --overwrite refuses it and deletes nothing
    user = tmp_path / "mine"
    (user / "images").mkdir(parents=True)
    (user / "images" / "IMG_0001.jpg").write_bytes(b"my photo")
    (user / "transforms.json").write_text('{"frames": []}')
    before = _tree(user)
    with pytest.raises(StealthNSError) as info:
        make_scene("orbit", user, resolution="16x12", views=8, overwrite=True)
    message = str(info.value)
    assert "\n" not in message and "did not write" in message
    assert "images/IMG_0001.jpg" in message and "transforms.json" in message
    assert _tree(user) == before

    # a generated scene a user has added to or edited: refused too, nothing deleted
    out = tmp_path / "scene"
    make_scene("orbit", out, resolution="16x12", views=8)
    (out / "images" / "mine.png").write_bytes(b"user image")
    before = _tree(out)
    with pytest.raises(StealthNSError, match=r"did not write.*images/mine\.png"):
        make_scene("orbit", out, resolution="16x12", views=8, seed=1, overwrite=True)
    assert _tree(out) == before
    (out / "images" / "mine.png").unlink()
    (out / "transforms.json").write_text('{"edited": true}')
    with pytest.raises(StealthNSError, match=r"changed since.*transforms\.json"):
        make_scene("orbit", out, resolution="16x12", views=8, seed=1, overwrite=True)
    assert (out / "transforms.json").read_text() == '{"edited": true}'

    # the generator's own files (and only those) are replaced; a user's file beside them stays
    fresh = tmp_path / "fresh"
    make_scene("orbit", fresh, resolution="16x12", views=16)
    (fresh / "notes.txt").write_text("keep me")
    make_scene("forward", fresh, resolution="16x12", views=8, overwrite=True)
    assert json.loads((fresh / "scene.json").read_text())["preset"] == "forward"
    assert (fresh / "notes.txt").read_text() == "keep me"
    assert set(_tree(fresh)) == set(json.loads((fresh / MANIFEST).read_text())["files"]) | {
        MANIFEST,
        "notes.txt",
    }


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


# --------------------------------------------------------------------------------------------
# facing preset (LLFF like, nerfstudio-data)


@pytest.fixture(scope="module")
def facing_scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("facing") / "scene"
    make_scene("facing", out, resolution=RES, seed=2)  # default 24 views
    return out


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_facing_layout_split_and_cameras(facing_scene):
    assert sorted(p.name for p in facing_scene.iterdir()) == [
        ".stealth-ns-scene.json",
        "depths",
        "images",
        "scene.json",
        "sparse_pc.ply",
        "transforms.json",
    ]
    meta, images, depths, xyz, _ = _load(facing_scene)
    info = json.loads((facing_scene / "scene.json").read_text())
    assert info["preset"] == "facing" and info["views"] == 24 and info["format"] == "nerfstudio-data"
    assert (info["n_train"], info["n_test"]) == (21, 3)
    assert meta["test_filenames"] == [f"images/frame_{i:05d}.png" for i in (0, 8, 16)]
    assert len(meta["train_filenames"]) == 21 and images.shape == (24, 48, 64, 3)
    c2w = np.stack([np.asarray(f["transform_matrix"]) for f in meta["frames"]])
    axes = -c2w[:, :3, 2]
    # all optical axes point the same way (roughly -Z), within a few degrees of each other
    assert max(_angle_deg(a, b) for a in axes for b in axes) < 15
    assert all(_angle_deg(a, np.array([0.0, 0.0, -1.0])) < 15 for a in axes)
    # cameras on a small plane-like patch: baseline much smaller than the scene depth
    pos = c2w[:, :3, 3]
    span = pos.max(axis=0) - pos.min(axis=0)
    assert span[0] <= 0.5 + 1e-9 and span[1] <= 0.35 + 1e-9 and span[2] < 0.1
    assert span[0] > 0.25 and span[1] > 0.15
    baseline = max(np.linalg.norm(a - b) for a in pos for b in pos)
    assert baseline < 0.2 * np.median(depths[depths > 0])
    # a cluttered scene a few units deep in front of a back wall at ~7, (almost) no sky
    assert (depths > 0).mean() > 0.98
    assert 2.0 < np.percentile(depths[depths > 0], 5) and np.percentile(depths[depths > 0], 95) < 8.0
    assert np.median(depths[depths > 0]) < 7.0
    assert len(np.unique(np.round(depths[0], 1))) > 30
    assert info["n_points"] == len(xyz) > 5000 and info["n_outliers"] == round(0.02 * len(xyz))


def test_facing_seed_points_have_sfm_outliers(facing_scene):
    meta, images, depths, xyz, rgb = _load(facing_scene)
    best = np.full(len(xyz), np.inf)  # smallest relative depth error over the training views
    colour = np.full(len(xyz), np.inf)
    for i in _train_indices(meta):
        col, row, z, ok = _project(meta, meta["frames"][i]["transform_matrix"], xyz)
        rel = np.where(ok, np.abs(z - depths[i][row, col]) / np.where(ok, z, 1.0), np.inf)
        err = np.abs(images[i][row, col] - rgb).mean(axis=1)
        colour = np.where(rel < 0.02, np.minimum(colour, err), colour)  # over the views seeing it
        best = np.minimum(best, rel)
    inlier = best < 0.02
    # ~98% are surface samples (depth-proportional noise) matching the images' colours ...
    assert 0.96 < inlier.mean() < 0.995
    assert np.median(best) < 0.005 and np.median(colour[inlier]) < 0.02
    # ... and ~2% are off the surfaces, as mis-triangulated SfM points are
    assert 0.01 < (best > 0.1).mean() < 0.03


@pytest.mark.parametrize("split,count", [("train", 21), ("val", 3), ("test", 3)])
def test_nerfstudio_dataparser_loads_facing(facing_scene, split, count):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    outputs = (
        NerfstudioDataParserConfig(data=facing_scene, load_3D_points=True)
        .setup()
        .get_dataparser_outputs(split=split)
    )
    assert len(outputs.image_filenames) == count and len(outputs.cameras) == count
    assert outputs.metadata["points3D_xyz"].shape[0] == len(read_ply(facing_scene / "sparse_pc.ply")[0])
    assert all(p.exists() for p in outputs.image_filenames)


# --------------------------------------------------------------------------------------------
# object preset (NeRF-synthetic like, Blender format)


@pytest.fixture(scope="module")
def object_scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("object") / "scene"
    make_scene("object", out, resolution="48x48", views=24, seed=1)  # 16 train / 4 val / 4 test
    return out


def _blender_split(scene: Path, split: str):
    """transforms, RGBA images (V, H, W, 4) float [0, 1], depths (V, H, W), c2w (V, 4, 4)."""
    meta = json.loads((scene / f"transforms_{split}.json").read_text())
    images = np.stack([to_float32(read_image(scene / (f["file_path"][2:] + ".png"))) for f in meta["frames"]])
    depths = np.stack([np.load(scene / f["depth_file_path"]) for f in meta["frames"]])
    c2w = np.stack([np.asarray(f["transform_matrix"], dtype=np.float64) for f in meta["frames"]])
    return meta, images, depths, c2w


def _pixel_rays(width: int, height: int, angle_x: float, c2w: np.ndarray) -> np.ndarray:
    """Unnormalised world directions (H, W, 3) of the pixel centres, camera-space z = -1."""
    f = 0.5 * width / np.tan(0.5 * angle_x)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    cam = np.stack([(u - width / 2) / f, -(v - height / 2) / f, -np.ones_like(u)], axis=-1)
    return cam @ c2w[:3, :3].T


def test_object_layout_and_cameras(object_scene):
    assert sorted(p.name for p in object_scene.iterdir()) == [
        ".stealth-ns-scene.json",
        "depths",
        "scene.json",
        "test",
        "train",
        "transforms_test.json",
        "transforms_train.json",
        "transforms_val.json",
        "val",
    ]
    info = json.loads((object_scene / "scene.json").read_text())
    assert info["preset"] == "object" and info["format"] == "blender" and info["n_points"] == 0
    assert (info["n_train"], info["n_val"], info["n_test"]) == (16, 4, 4)
    assert info["resolution"] == [48, 48] and info["world_up"] == [0.0, 0.0, 1.0]
    for split, n in (("train", 16), ("val", 4), ("test", 4)):
        meta, images, depths, c2w = _blender_split(object_scene, split)
        assert meta["camera_angle_x"] == pytest.approx(0.6911112, abs=1e-6)
        assert [f["file_path"] for f in meta["frames"]] == [f"./{split}/r_{k}" for k in range(n)]
        assert sorted(p.name for p in (object_scene / split).iterdir()) == sorted(
            f"r_{k}.png" for k in range(n)
        )
        img = Image.open(object_scene / split / "r_0.png")  # as nerfstudio decodes it: 8-bit RGBA
        assert (img.mode, img.size) == ("RGBA", (48, 48))
        assert depths.dtype == np.float32 and depths.shape == (n, 48, 48)
        # cameras at radius 4 looking at the origin, on the upper hemisphere (Blender: +Z up)
        pos = c2w[:, :3, 3]
        np.testing.assert_allclose(np.linalg.norm(pos, axis=1), 4.0, atol=1e-6)
        np.testing.assert_allclose(-c2w[:, :3, 2], -pos / 4.0, atol=1e-6)
        gram = np.einsum("vji,vjk->vik", c2w[:, :3, :3], c2w[:, :3, :3])
        np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-6)
        assert (pos[:, 2] > 0.5).all() and (c2w[:, 2, 1] > 0).all()  # image up points up
        if split == "test":  # a ring at one elevation
            np.testing.assert_allclose(pos[:, 2], 4.0 * np.sin(np.deg2rad(30)), atol=1e-6)
    # train views cover the hemisphere: all azimuth quadrants, low and high elevations
    pos = _blender_split(object_scene, "train")[3][:, :3, 3]
    assert len(set((np.arctan2(pos[:, 1], pos[:, 0]) // (np.pi / 2)).astype(int))) == 4
    assert pos[:, 2].min() < 1.5 and pos[:, 2].max() > 3.0


def test_object_alpha_depth_and_extent(object_scene):
    for split in ("train", "val", "test"):
        meta, images, depths, c2w = _blender_split(object_scene, split)
        alpha, rgb = images[..., 3], images[..., :3]
        for img_alpha, img_rgb, depth, m in zip(alpha, rgb, depths, c2w, strict=True):
            dirs = _pixel_rays(48, 48, meta["camera_angle_x"], m)
            # background: rays that miss the unit sphere (the object's bound) are fully transparent
            o = m[:3, 3]
            unit = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
            miss = np.linalg.norm(np.cross(unit, -o), axis=-1) > 1.0 + 0.05
            assert miss.mean() > 0.2
            assert (img_alpha[miss] == 0).all() and (depth[miss] == 0).all()
            assert (img_rgb[img_alpha == 0] == 0).all()  # transparent black, as NeRF-synthetic
            # the object: opaque where the pixel-centre ray hits it, in the unit sphere
            hit = depth > 0
            assert 0.05 < hit.mean() < 0.8
            assert (img_alpha[hit] > 0).mean() > 0.99 and (img_alpha[hit] == 1).mean() > 0.8
            points = o + dirs[hit] * depth[hit][:, None]
            assert np.linalg.norm(points, axis=1).max() < 1.0 + 1e-3
            # no alpha far from any hit (the border is transparent)
            assert (img_alpha[0] == 0).all() and (img_alpha[-1] == 0).all()
    # the object just fits the unit sphere: some surface point comes close to it
    _, _, depths, c2w = _blender_split(object_scene, "train")
    far = max(
        np.linalg.norm(m[:3, 3] + _pixel_rays(48, 48, 0.6911112, m)[d > 0] * d[d > 0][:, None], axis=1).max()
        for d, m in zip(depths, c2w, strict=True)
    )
    assert far > 0.8


@pytest.mark.parametrize("split,count", [("train", 16), ("val", 4), ("test", 4)])
def test_blender_dataparser_loads_object(object_scene, split, count):
    from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig
    from nerfstudio.data.datasets.base_dataset import InputDataset

    outputs = BlenderDataParserConfig(data=object_scene).setup().get_dataparser_outputs(split=split)
    meta, images, _, c2w = _blender_split(object_scene, split)
    assert [p.relative_to(object_scene).as_posix() for p in outputs.image_filenames] == [
        f"{split}/r_{k}.png" for k in range(count)
    ]
    cams = outputs.cameras
    assert cams.width.flatten().tolist() == [48] * count and cams.height.flatten().tolist() == [48] * count
    assert cams.fx.flatten().tolist() == pytest.approx([24 / np.tan(0.6911112070083618 / 2)] * count)
    np.testing.assert_allclose(cams.camera_to_worlds.numpy(), c2w[:, :3], atol=1e-6)
    # nerfstudio composites the RGBA images on its alpha colour (white by default)
    image = InputDataset(outputs).get_image_float32(0).numpy()
    assert image.shape == (48, 48, 3)
    np.testing.assert_allclose(image[images[0, ..., 3] == 0], 1.0)
    hit = images[0, ..., 3] == 1
    np.testing.assert_allclose(image[hit], images[0, ..., :3][hit], atol=1 / 255)


def test_object_summary_default_resolution_and_overwrite(tmp_path):
    out = tmp_path / "obj"
    summary = make_scene("object", out, views=8, seed=4)  # default resolution: square 128x128
    assert image_size(out / "train" / "r_0.png") == (128, 128)
    assert (summary.n_train, summary.n_val, summary.n_test, summary.n_points) == (6, 1, 1, 0)
    text = str(summary)
    assert "6 train / 1 val / 1 test" in text and "128x128" in text and "no seed points" in text
    assert f"ns-train stealth-splat-lite --vis tensorboard blender-data --data {out}" in text
    # --overwrite with another preset removes the Blender entries, keeps unrelated files
    (out / "notes.txt").write_text("keep me")
    make_scene("facing", out, resolution="16x12", views=8, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == [
        MANIFEST,
        "depths",
        "images",
        "notes.txt",
        "scene.json",
        "sparse_pc.ply",
        "transforms.json",
    ]
    assert sorted(p.name for p in (out / "depths").iterdir()) == [f"frame_{i:05d}.npy" for i in range(8)]


def test_cli_make_scene_new_presets(tmp_path):
    from stealth_ns.cli import main

    main(["make-scene", "--preset", "object", "--output", str(tmp_path / "o"), "--views", "8"])
    assert image_size(tmp_path / "o" / "test" / "r_0.png") == (128, 128)
    main(["make-scene", "--preset", "facing", "--output", str(tmp_path / "f"), "--views", "8"])
    assert image_size(tmp_path / "f" / "images" / "frame_00000.png") == (128, 96)


@pytest.mark.parametrize("preset", ["facing", "object"])
def test_new_presets_are_deterministic(tmp_path, preset):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for out, seed in ((a, 7), (b, 7), (c, 8)):
        make_scene(preset, out, resolution="32x24", views=8, seed=seed)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    # images, depth maps, transforms/scene/points (facing) or transforms x3 + scene, the manifest
    assert len(files) == (8 + 8 + 3 if preset == "facing" else 8 + 8 + 3 + 1) + 1
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    images = [rel for rel in files if rel.suffix == ".png"]
    assert sum((a / rel).read_bytes() != (c / rel).read_bytes() for rel in images) == len(images)
