"""`stealth-ns seed-points`: triangulated seed points for known-pose captures (pycolmap)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from stealth_ns.datasets import seed_points
from stealth_ns.datasets.seed_points import SeedPointsSummary, make_seed_points
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image, save_png
from stealth_ns.scene_generator import make_scene
from stealth_ns.scene_generator.writer import read_ply

pytest.importorskip("pycolmap")

FOX = Path("/work/shared/data/fox")


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A 32-view orbit scene (known poses, z-depth maps); its own sparse_pc.ply is left in place."""
    out = tmp_path_factory.mktemp("orbit") / "scene"
    make_scene(preset="orbit", output=out, resolution="128x96", views=32, seed=0)
    return out


@pytest.fixture(scope="module")
def seeded(scene: Path, tmp_path_factory) -> tuple[Path, SeedPointsSummary, bytes]:
    """The default mode run on a copy of the scene: (folder, summary, original transforms.json bytes)."""
    data = tmp_path_factory.mktemp("default") / "scene"
    shutil.copytree(scene, data)
    original = (data / "transforms.json").read_bytes()
    return data, make_seed_points(data), original


def _depth_errors(xyz: np.ndarray, c2w: np.ndarray, fx, fy, cx, cy, depth: np.ndarray) -> np.ndarray:
    """Per point, the relative z-depth error against the view's depth map at the pixel it projects
    to (OpenGL camera-to-world ``c2w``; pixel centres at integer + 0.5); inf where it projects
    outside the view, behind the camera or onto background."""
    p = (xyz - c2w[:3, 3]) @ c2w[:3, :3]  # camera frame: x right, y up, looking down -z
    z = -p[:, 2]
    zs = np.where(z > 1e-6, z, np.nan)
    u = fx * p[:, 0] / zs + cx
    v = -fy * p[:, 1] / zs + cy
    h, w = depth.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    gt = np.zeros(len(xyz))
    gt[inside] = depth[v[inside].astype(int), u[inside].astype(int)]
    err = np.full(len(xyz), np.inf)
    ok = inside & (gt > 0)
    err[ok] = np.abs(z[ok] - gt[ok]) / gt[ok]
    return err


def _check_against_depth(views: list[tuple[np.ndarray, float, float, float, float, np.ndarray]], xyz) -> None:
    """Each point is seen by some views; where it is seen (the best-matching view), its depth must
    match the true surface: the median over points of the best relative error is small."""
    best = np.min([_depth_errors(xyz, *view) for view in views], axis=0)
    assert np.isfinite(best).mean() > 0.9, "points project outside every view"
    assert np.median(best) < 0.005, f"median relative depth error {np.median(best):.4f}"
    assert np.mean(best < 0.02) > 0.8, f"only {np.mean(best < 0.02):.0%} of the points lie on a surface"


def _scene_views(data: Path) -> list:
    meta = json.loads((data / "transforms.json").read_text())
    intr = [meta[k] for k in ("fl_x", "fl_y", "cx", "cy")]
    return [
        (np.array(fr["transform_matrix"]), *intr, np.load(data / fr["depth_file_path"]))
        for fr in meta["frames"]
    ]


def test_default_mode_points_lie_on_the_surfaces(seeded) -> None:
    data, summary, original = seeded
    assert summary.n_points >= 100 and summary.n_images == 28  # the training split
    assert summary.mean_error_px < 1.0
    assert (data / "transforms.json").read_bytes() == original  # the user's file untouched
    assert summary.ply == data / "sparse_pc_seeded.ply"  # sparse_pc.ply was taken
    assert summary.dataset == data / "transforms_seeded.json"
    seeded_meta = json.loads(summary.dataset.read_text())
    assert seeded_meta["ply_file_path"] == "sparse_pc_seeded.ply"
    assert seeded_meta["frames"] == json.loads(original)["frames"]
    xyz, rgb = read_ply(summary.ply)
    assert xyz.shape == (summary.n_points, 3) and rgb.shape == (summary.n_points, 3)
    _check_against_depth(_scene_views(data), xyz.astype(np.float64))
    text = str(summary)
    assert "nerfstudio-data --data" in text and str(summary.dataset) in text


def test_output_mode_and_determinism(scene: Path, seeded, tmp_path: Path) -> None:
    _, first, _ = seeded
    out = tmp_path / "out"
    summary = make_seed_points(scene, output=out)
    assert summary.dataset == out and summary.ply == out / "sparse_pc.ply"
    assert summary.ply.read_bytes() == first.ply.read_bytes()  # same input, same PLY
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["ply_file_path"] == "sparse_pc.ply"
    for fr in meta["frames"]:
        assert (out / fr["file_path"]).resolve() == (scene / "images" / Path(fr["file_path"]).name).resolve()
    assert all((out / f).is_file() for f in meta["train_filenames"] + meta["test_filenames"])
    # a non-empty output needs --overwrite; with it the result is the same again
    with pytest.raises(StealthNSError, match="not empty"):
        make_seed_points(scene, output=out)
    again = make_seed_points(scene, output=out, overwrite=True, max_points=50, seed=3)
    assert again.n_points == 50 and read_ply(again.ply)[0].shape == (50, 3)


def test_applied_transform_and_in_place_update(scene: Path, tmp_path: Path) -> None:
    """Poses saved through an ``applied_transform`` (as ns-process-data writes them): nerfstudio's
    parser must place the PLY points on the surfaces seen by its cameras."""
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    data = tmp_path / "scene"
    shutil.copytree(scene, data)
    (data / "sparse_pc.ply").unlink()
    meta = json.loads((data / "transforms.json").read_text())
    a = np.eye(4)
    c, s = math.cos(0.6), math.sin(0.6)
    a[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    a[:3, 3] = [0.4, -0.3, 0.2]
    for fr in meta["frames"]:
        fr["transform_matrix"] = (a @ np.array(fr["transform_matrix"])).tolist()
    meta["applied_transform"] = a[:3].tolist()
    del meta["ply_file_path"]
    (data / "transforms.json").write_text(json.dumps(meta, indent=2))

    summary = make_seed_points(data, overwrite=True)  # updates transforms.json in place
    assert summary.dataset == data and summary.ply == data / "sparse_pc.ply"
    assert not (data / "transforms_seeded.json").exists()
    assert json.loads((data / "transforms.json").read_text())["ply_file_path"] == "sparse_pc.ply"

    out = (
        NerfstudioDataParserConfig(data=data, load_3D_points=True)
        .setup()
        .get_dataparser_outputs(split="train")
    )
    xyz = out.metadata["points3D_xyz"].numpy().astype(np.float64)
    assert xyz.shape[0] == summary.n_points
    cams, scale = out.cameras, float(out.dataparser_scale)
    views = []
    for i in range(len(out.image_filenames)):
        c2w = np.eye(4)
        c2w[:3] = cams.camera_to_worlds[i].numpy()
        depth = np.load(data / "depths" / (Path(out.image_filenames[i]).stem + ".npy")) * scale
        views.append((c2w, *(float(getattr(cams, n)[i]) for n in ("fx", "fy", "cx", "cy")), depth))
    _check_against_depth(views, xyz)


def test_blender_folder(scene: Path, tmp_path: Path) -> None:
    """A Blender-format copy of the scene (RGBA, sky transparent, extension-less file paths)."""
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    meta = json.loads((scene / "transforms.json").read_text())
    angle = 2 * math.atan(0.5 * meta["w"] / meta["fl_x"])
    blender = tmp_path / "blender"
    splits = {"train": [i for i in range(32) if i % 8], "val": [0, 8], "test": [16, 24]}
    for split, idx in splits.items():
        (blender / split).mkdir(parents=True)
        frames = []
        for k, i in enumerate(idx):
            fr = meta["frames"][i]
            rgb = read_image(scene / fr["file_path"])
            alpha = np.where(np.load(scene / fr["depth_file_path"]) > 0, 255, 0).astype(np.uint8)
            save_png(blender / split / f"r_{k}.png", np.dstack([rgb, alpha]))
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": fr["transform_matrix"]})
        doc = {"camera_angle_x": angle, "frames": frames}
        (blender / f"transforms_{split}.json").write_text(json.dumps(doc))

    summary = make_seed_points(blender)
    assert summary.blender and summary.dataset == blender / "transforms_seeded.json"
    assert "background-color white" in summary.train_command
    assert summary.n_images == 28 and summary.n_points >= 100
    conv = json.loads(summary.dataset.read_text())
    assert conv["fl_x"] == pytest.approx(meta["fl_x"]) and conv["cx"] == pytest.approx(64.0)
    assert len(conv["frames"]) == 32 and len(conv["test_filenames"]) == 2
    xyz, _ = read_ply(summary.ply)
    _check_against_depth(_scene_views(scene), xyz.astype(np.float64))
    parser = NerfstudioDataParserConfig(data=summary.dataset).setup()
    assert len(parser.get_dataparser_outputs(split="train").image_filenames) == 28
    assert len(parser.get_dataparser_outputs(split="test").image_filenames) == 2


def _tiny_dataset(folder: Path, n: int = 3) -> Path:
    """``n`` uniform grey 64x48 views (no SIFT features) with valid poses and intrinsics."""
    folder.mkdir(parents=True)
    (folder / "images").mkdir()
    frames = []
    for i in range(n):
        save_png(folder / "images" / f"{i}.png", np.full((48, 64, 3), 128, np.uint8))
        c2w = np.eye(4)
        c2w[0, 3] = 0.1 * i
        frames.append({"file_path": f"images/{i}.png", "transform_matrix": c2w.tolist()})
    meta = {"fl_x": 50.0, "fl_y": 50.0, "cx": 32.0, "cy": 24.0, "w": 64, "h": 48, "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(meta))
    return folder


def _edit(folder: Path, fn) -> None:
    meta = json.loads((folder / "transforms.json").read_text())
    fn(meta)
    (folder / "transforms.json").write_text(json.dumps(meta))


def test_bad_input_gives_one_line_errors(tmp_path: Path, monkeypatch) -> None:
    with pytest.raises(StealthNSError, match="does not exist"):
        make_seed_points(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(StealthNSError, match="no transforms.json"):
        make_seed_points(tmp_path / "empty")

    d = _tiny_dataset(tmp_path / "a")
    _edit(d, lambda m: m.update(frames=[]))
    with pytest.raises(StealthNSError, match="has no frames"):
        make_seed_points(d)

    d = _tiny_dataset(tmp_path / "b")
    (d / "images" / "1.png").unlink()
    with pytest.raises(StealthNSError, match=r"images/1\.png does not exist"):
        make_seed_points(d)

    d = _tiny_dataset(tmp_path / "c")
    _edit(d, lambda m: m["frames"][2]["transform_matrix"][0].__setitem__(3, float("nan")))
    with pytest.raises(StealthNSError, match=r"frame 'images/2\.png'.*NaN"):
        make_seed_points(d)

    d = _tiny_dataset(tmp_path / "d", n=1)
    with pytest.raises(StealthNSError, match="at least 2 images"):
        make_seed_points(d)

    d = _tiny_dataset(tmp_path / "e")
    _edit(d, lambda m: m.update(w=65))
    with pytest.raises(StealthNSError, match="is 64x48 but the file says 65x48"):
        make_seed_points(d)

    d = _tiny_dataset(tmp_path / "f")  # uniform grey: no features at all
    with pytest.raises(StealthNSError, match="triangulation gave no points.*too few matches"):
        make_seed_points(d)
    assert not (d / "transforms_seeded.json").exists()
    with pytest.raises(StealthNSError, match="triangulation gave no points"):
        make_seed_points(d, output=tmp_path / "never" / "out")
    assert not (tmp_path / "never").exists()  # a failed run leaves no output folder

    d = _tiny_dataset(tmp_path / "g")
    (d / "transforms_seeded.json").write_text("{}")
    with pytest.raises(StealthNSError, match="already exists"):
        make_seed_points(d)
    with pytest.raises(StealthNSError, match="is the dataset folder"):
        make_seed_points(d, output=d)
    monkeypatch.setattr(seed_points, "_writable", lambda folder: False)
    with pytest.raises(StealthNSError, match="cannot write to the dataset folder .*: pass --output"):
        make_seed_points(d)


def test_cli_reports_errors_in_one_line(tmp_path: Path, capsys, monkeypatch) -> None:
    from stealth_ns import cli
    from stealth_ns.datasets.command_line import SeedPoints

    assert cli.COMMANDS["seed-points"] is SeedPoints
    monkeypatch.setattr("sys.argv", ["stealth-ns", "seed-points", "--data", str(tmp_path / "missing")])
    with pytest.raises(SystemExit) as exc:
        cli.entrypoint()
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("stealth-ns: error: dataset") and "does not exist" in err[0]


@pytest.mark.skipif(not FOX.is_dir(), reason=f"{FOX} (real phone capture) is not on this machine")
def test_fox_real_capture(tmp_path: Path) -> None:
    summary = make_seed_points(FOX, output=tmp_path / "fox")
    assert summary.n_images == 50 and summary.n_points > 1000
    assert summary.mean_error_px < 1.0


def test_views_of_a_seeded_copy_keep_the_dataset_names(tmp_path, monkeypatch):
    """A seeded --output copy refers to the read-only dataset's images by a relative path: views
    are still named ``images/0042.png``, not ``../../data/fox/images/0042.png``."""
    from stealth_ns.method.datamanager import dataset_image_names

    data = tmp_path / "data" / "fox"
    (data / "images").mkdir(parents=True)
    copy = tmp_path / "runs" / "fox_seeded"
    copy.mkdir(parents=True)
    names = ["0042.png", "0043.png"]
    for n in names:
        (data / "images" / n).touch()
    inside = [data / "images" / n for n in names]
    assert dataset_image_names(data / "transforms.json", inside) == ["images/0042.png", "images/0043.png"]
    outside = [copy / ".." / ".." / "data" / "fox" / "images" / n for n in names]
    assert dataset_image_names(copy / "transforms.json", outside) == ["images/0042.png", "images/0043.png"]
    # --data given relative to the working directory, as the dataparser then gives the images
    monkeypatch.chdir(tmp_path)
    relative = [Path("data/fox/images") / n for n in names]
    assert dataset_image_names(Path("data/fox"), relative) == ["images/0042.png", "images/0043.png"]


def test_poses_that_do_not_fit_the_images_are_named(scene: Path, tmp_path: Path) -> None:
    """Poses shuffled among the frames: the images still match each other, so the old message blamed
    the resolution; the verified matches lie far from the poses' epipolar lines, which is what it says."""
    data = Path(shutil.copytree(scene, tmp_path / "shuffled"))
    meta = json.loads((data / "transforms.json").read_text())
    poses = [f["transform_matrix"] for f in meta["frames"]]
    for frame, k in zip(meta["frames"], np.random.default_rng(0).permutation(len(poses)), strict=True):
        frame["transform_matrix"] = poses[k]
    (data / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(
        StealthNSError, match=r"the camera poses do not fit the images: .* px \(median\)"
    ) as err:
        make_seed_points(data, output=tmp_path / "out")
    assert "resolution" not in str(err.value) and not (tmp_path / "out").exists()


def test_epipolar_distances_vanish_for_the_true_poses_only() -> None:
    from scipy.spatial.transform import Rotation

    from stealth_ns.datasets.triangulation import epipolar_distances

    k = np.array([[100.0, 0, 64], [0, 100.0, 48], [0, 0, 1]])
    rng = np.random.default_rng(1)
    points = rng.uniform(-1, 1, (50, 3))
    c2w = []
    for angle in (0.0, 0.3):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_euler("y", angle).as_matrix()
        m[:3, 3] = m[:3, :3] @ np.array([0.0, 0.0, 5.0])  # looking at the origin (OpenGL: -z forward)
        c2w.append(m)

    def project(m: np.ndarray) -> np.ndarray:
        w2c = np.linalg.inv(m @ np.diag([1.0, -1.0, -1.0, 1.0]))
        cam = points @ w2c[:3, :3].T + w2c[:3, 3]
        uv = cam @ k.T
        return uv[:, :2] / uv[:, 2:]

    x1, x2 = project(c2w[0]), project(c2w[1])
    assert np.abs(epipolar_distances(x1, x2, k, k, c2w[0], c2w[1])).max() < 1e-6
    moved = c2w[1].copy()
    moved[:3, 3] += np.array([0.0, 1.0, 0.0])
    assert np.median(epipolar_distances(x1, x2, k, k, c2w[0], moved)) > 3


def test_overwrite_never_replaces_the_users_point_cloud(scene: Path, tmp_path: Path) -> None:
    """--overwrite updates the transforms file in place, but the sparse_pc.ply there is the user's (from
    their own reconstruction): it is kept, byte for byte, and the points go to another file (issue 32)."""
    data = Path(shutil.copytree(scene, tmp_path / "data"))
    xyz, rgb = read_ply(data / "sparse_pc.ply")
    header = f"ply\nformat ascii 1.0\nelement vertex {len(xyz)}\nproperty float x\nproperty float y\n"
    header += "property float z\nend_header\n"
    (data / "sparse_pc.ply").write_text(header + "".join(f"{a} {b} {c}\n" for a, b, c in xyz))
    theirs = (data / "sparse_pc.ply").read_bytes()
    summary = make_seed_points(data, overwrite=True)
    assert (data / "sparse_pc.ply").read_bytes() == theirs
    assert summary.ply == data / "sparse_pc_seeded.ply"
    assert json.loads((data / "transforms.json").read_text())["ply_file_path"] == "sparse_pc_seeded.ply"
    again = make_seed_points(data, overwrite=True)  # its own file is the one replaced next time
    assert again.ply == data / "sparse_pc_seeded.ply" and (data / "sparse_pc.ply").read_bytes() == theirs

    # --output with --overwrite over a folder holding a transforms.json of the user's: refused
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "transforms.json").write_text('{"frames": []}')
    with pytest.raises(StealthNSError, match="holds a transforms.json that seed-points did not write"):
        make_seed_points(data, output=mine, overwrite=True)
    assert (mine / "transforms.json").read_text() == '{"frames": []}'
