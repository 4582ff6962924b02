"""stealth-ns scan on an official 3DGS output folder (graphdeco-inria/gaussian-splatting's train.py):
cameras.json read as the official code writes it, the scan with photos (--data, cfg_args' source_path)
and without (the cameras alone), and a one-line error for each broken folder."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from stealth_ns.foundation.errors import StealthNSError

ITERATION = 300


def camera_to_json(index: int, c2w_opengl: np.ndarray, name: str, meta: dict) -> dict:
    """A camera of a Blender-style transforms file as the official code writes it: its reader's R and T
    (``readCamerasFromTransforms``), then ``utils/camera_utils.py: camera_to_JSON``."""
    c2w = np.array(c2w_opengl, dtype=np.float64)
    c2w[:3, 1:3] *= -1  # OpenGL camera axes -> COLMAP's
    w2c = np.linalg.inv(c2w)
    r, t = w2c[:3, :3].T, w2c[:3, 3]
    rt = np.zeros((4, 4))
    rt[:3, :3], rt[:3, 3], rt[3, 3] = r.T, t, 1.0
    inverse = np.linalg.inv(rt)
    return {
        "id": index, "img_name": name, "width": meta["w"], "height": meta["h"],
        "position": inverse[:3, 3].tolist(), "rotation": [row.tolist() for row in inverse[:3, :3]],
        "fy": meta["fl_y"], "fx": meta["fl_x"],
    }  # fmt: skip


def official_cameras(scene: Path) -> list[dict]:
    """cameras.json of an official run with --eval on ``scene``: the held-out cameras first, then the
    training ones, each sorted by name (the tiny scene holds out every 8th, as the official reader)."""
    meta = json.loads((scene / "transforms.json").read_text())
    frames = {f["file_path"]: f["transform_matrix"] for f in meta["frames"]}
    order = sorted(meta["test_filenames"]) + sorted(meta["train_filenames"])
    return [camera_to_json(i, frames[p], Path(p).stem, meta) for i, p in enumerate(order)]


def write_official_output(config: Path, scene: Path, folder: Path, source_path: str) -> Path:
    """An official output folder of the run ``config``: its Gaussians in the dataset's frame at
    :data:`ITERATION` (an earlier, emptied iteration beside it), cameras.json, cfg_args, input.ply."""
    from stealth_ns.datasets.frames import frame_transforms
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.gaussians.ply import write_gaussian_ply
    from stealth_ns.gaussians.transform import transform_cloud
    from stealth_ns.method.model_cloud import cloud_of_model
    from stealth_ns.runs.loaded import load_run

    run = load_run(config)
    outputs = run.pipeline.datamanager.train_dataparser_outputs
    to_ns = frame_transforms(outputs, inspect_folder("--data", str(scene)))["dataset"]
    cloud = cloud_of_model(run.model)
    cloud.extra.clear()  # the official code writes no poison tag
    (folder / "point_cloud" / f"iteration_{ITERATION}").mkdir(parents=True)
    (folder / "point_cloud" / "iteration_7").mkdir()  # 7 > 300 as text: the newest is chosen by number
    write_gaussian_ply(
        folder / "point_cloud" / f"iteration_{ITERATION}" / "point_cloud.ply",
        transform_cloud(cloud, np.linalg.inv(to_ns)),
    )
    (folder / "cameras.json").write_text(json.dumps(official_cameras(scene)))
    (folder / "cfg_args").write_text(
        f"Namespace(sh_degree=3, source_path={source_path!r}, model_path={str(folder)!r}, images='images', "
        "resolution=-1, white_background=False, data_device='cuda', eval=True)"
    )
    (folder / "input.ply").write_bytes(b"")
    return folder


@pytest.fixture(scope="module")
def official_outputs(tiny_poisoned_run, tiny_run_pair, tiny_orbit_scene, tmp_path_factory) -> dict[str, Path]:
    """The tiny poisoned (300 steps) and clean runs as official output folders whose cfg_args names a
    dataset that is not on this machine."""
    base = tmp_path_factory.mktemp("official")
    return {
        name: write_official_output(config, tiny_orbit_scene, base / name, "/elsewhere/orbit_tiny")
        for name, config in (("poisoned", tiny_poisoned_run), ("clean", tiny_run_pair[1]))
    }


def _scan(model: Path, out: Path, data: Path | None = None) -> dict:
    from stealth_ns.scan.command import run_scan
    from stealth_ns.scan.config import ScanConfig

    return run_scan(model, data, out, ScanConfig())


def test_cameras_json_is_read_in_the_official_conventions(tiny_orbit_scene, tmp_path):
    """Each camera's OpenGL camera-to-world is the dataset's own; the held-out split, the training size
    and the newest iteration are the official code's."""
    from stealth_ns.datasets.official_output import (
        OfficialCamera,
        is_official_output,
        opengl_camera_to_world,
        read_cameras,
        read_official_output,
        training_size,
        training_split,
    )

    meta = json.loads((tiny_orbit_scene / "transforms.json").read_text())
    (tmp_path / "point_cloud" / "iteration_30").mkdir(parents=True)
    (tmp_path / "point_cloud" / "iteration_30" / "point_cloud.ply").write_bytes(b"")
    (tmp_path / "point_cloud" / "iteration_7").mkdir()
    (tmp_path / "cameras.json").write_text(json.dumps(official_cameras(tiny_orbit_scene)))
    assert is_official_output(tmp_path) and not is_official_output(tiny_orbit_scene)
    output = read_official_output(tmp_path)
    assert output.iteration == 30 and output.options == {} and output.source_path is None
    frames = {Path(f["file_path"]).stem: f["transform_matrix"] for f in meta["frames"]}
    for camera in output.cameras:
        assert np.allclose(opengl_camera_to_world(camera), frames[camera.name], atol=1e-9)
    assert training_split(output.cameras, {}).held_out == ()
    split = training_split(output.cameras, {"eval": True})
    assert sorted(output.cameras[i].name + ".png" for i in split.held_out) == sorted(
        Path(p).name for p in meta["test_filenames"]
    )
    assert len(split.training) == len(meta["train_filenames"])
    shuffled = read_cameras(tmp_path / "cameras.json")[::-1]
    assert training_split(shuffled, {"eval": True}).held_out == ()  # the split does not show: all views
    big = OfficialCamera(0, "a", 4000, 3000, np.eye(3), np.zeros(3), 1.0, 1.0)
    assert training_size(big, -1) == (1600, 1200) and training_size(big, 4) == (1000, 750)
    assert training_size(big, 800) == (800, 600)


def test_the_camera_dataset_names_its_views_as_cameras_json_does(tiny_orbit_scene, tmp_path):
    """A camera named with its file's suffix (``image010.png``, as some trainers write it) keeps that name;
    one named without (the official code's ``image011``) gets ``.png``; two that would share a file are
    told apart by their index."""
    from stealth_ns.datasets.official_output import read_official_output, write_camera_dataset

    cameras = official_cameras(tiny_orbit_scene)[:5]
    for camera, name in zip(cameras, ["image010.png", "image011", "photo 12.JPG", "a", "a.png"], strict=True):
        camera["img_name"] = name
    model = tmp_path / "model"
    (model / "point_cloud" / "iteration_30").mkdir(parents=True)
    (model / "point_cloud" / "iteration_30" / "point_cloud.ply").write_bytes(b"")
    (model / "cameras.json").write_text(json.dumps(cameras))
    write_camera_dataset(read_official_output(model), tmp_path / "dataset")
    meta = json.loads((tmp_path / "dataset" / "transforms.json").read_text())
    names = [frame["file_path"] for frame in meta["frames"]]
    assert names == ["images/image010.png", "images/image011.png", "images/photo_12.JPG", "images/a_3.png",
                     "images/a_4.png"]  # fmt: skip
    assert all((tmp_path / "dataset" / name).is_file() for name in names)


def test_an_official_output_is_scanned_on_its_cameras_alone_as_with_its_photos(
    official_outputs, tiny_poisoned_run, tiny_orbit_scene, tmp_path
):
    from stealth_ns.gaussians.ply import read_gaussian_ply

    record = json.loads((tiny_poisoned_run.parent / "attack" / "attack.json").read_text())
    truth = [v["name"] for v in record["poisoned_views"]]
    folder = official_outputs["poisoned"]
    blind = _scan(folder, tmp_path / "cameras")
    assert blind["verdict"] == "suspicious" and [t["name"] for t in blind["targeted_views"]] == truth
    assert blind["model"]["kind"] == f"official 3DGS output (iteration {ITERATION})"
    assert blind["model"]["frame"] == "dataset" and blind["training_views"] == 14
    assert blind["data"] == str(folder / "cameras.json")
    photos = blind["photos"]
    assert not photos["used"] and "/elsewhere/orbit_tiny does not exist" in photos["note"]
    assert photos["steps"] == {
        "render match": "skipped: needs the photos", "view-support": "cameras",
        "camera-proximity": "cameras", "groups": "cameras",
    }  # fmt: skip
    written = json.loads((tmp_path / "cameras" / "scan.json").read_text())
    assert written["model"]["render_match_above_flat"] is None and written["photos"] == photos
    assert "Scanned without photos" in (tmp_path / "cameras" / "scan.html").read_text()
    cleaned = read_gaussian_ply(tmp_path / "cameras" / "cleaned.ply")  # in the official frame, as read
    assert len(cleaned) == blind["model"]["gaussians"] - blind["removed"]

    # the same folder with its cfg_args naming the dataset, here: the photos are used
    moved = tmp_path / "with-source"
    shutil.copytree(folder, moved)
    cfg = (moved / "cfg_args").read_text().replace("/elsewhere/orbit_tiny", str(tiny_orbit_scene))
    (moved / "cfg_args").write_text(cfg)
    seen = _scan(moved, tmp_path / "photos")
    assert seen["photos"]["used"] and seen["photos"]["origin"] == "cfg_args' source_path"
    assert set(seen["photos"]["steps"].values()) == {"photos", "cameras"}
    assert seen["model"]["render_match_above_flat"] > 0 and seen["data"] == str(tiny_orbit_scene)
    for key in ("verdict", "targeted_views", "flagged", "removed", "training_views"):
        assert seen[key] == blind[key], key
    assert seen["signals"].keys() == blind["signals"].keys()


def test_the_clean_official_output_is_clean_with_and_without_photos(
    official_outputs, tiny_orbit_scene, tmp_path
):
    folder = official_outputs["clean"]
    blind = _scan(folder, tmp_path / "cameras")
    seen = _scan(folder, tmp_path / "photos", tiny_orbit_scene)
    assert blind["verdict"] == seen["verdict"] == "clean"
    assert seen["photos"]["origin"] == "--data" and not blind["photos"]["used"]
    assert [g["region_share"] for g in blind["groups"]] == [g["region_share"] for g in seen["groups"]]


def _broken(base: Path, folder: Path, edit) -> Path:
    """A copy of the official folder ``base`` into ``folder``, changed by ``edit(folder, cameras)``."""
    shutil.copytree(base, folder)
    cameras = json.loads((folder / "cameras.json").read_text())
    edit(folder, cameras)
    if (folder / "cameras.json").exists():
        (folder / "cameras.json").write_text(json.dumps(cameras))
    return folder


def test_broken_official_outputs_are_one_line(official_outputs, tiny_orbit_scene, tmp_path):
    from stealth_ns.cli import main
    from stealth_ns.runs.imported import load_model

    base = tmp_path / "base"
    (base / "point_cloud" / "iteration_1").mkdir(parents=True)
    (base / "point_cloud" / "iteration_1" / "point_cloud.ply").write_bytes(b"")
    (base / "cameras.json").write_text(json.dumps(official_cameras(tiny_orbit_scene)))

    def lacks_fx(folder, cameras):
        del cameras[3]["fx"]

    def nan(folder, cameras):
        cameras[2]["position"][1] = float("nan")

    def not_a_rotation(folder, cameras):
        cameras[5]["rotation"][0] = [2.0 * x for x in cameras[5]["rotation"][0]]

    def no_width(folder, cameras):
        cameras[0]["width"] = 0

    def no_point_cloud(folder, cameras):
        shutil.rmtree(folder / "point_cloud")

    def no_iteration(folder, cameras):
        (folder / "point_cloud" / "iteration_1" / "point_cloud.ply").unlink()

    def no_cameras(folder, cameras):
        (folder / "cameras.json").unlink()

    def bad_cfg_args(folder, cameras):
        (folder / "cfg_args").write_text("__import__('os').system('true')")

    far = _broken(official_outputs["poisoned"], tmp_path / "far", lambda folder, cameras: None)
    ply = far / "point_cloud" / f"iteration_{ITERATION}" / "point_cloud.ply"
    from stealth_ns.gaussians.ply import read_gaussian_ply, write_gaussian_ply

    cloud = read_gaussian_ply(ply)
    cloud.means += 1000.0
    write_gaussian_ply(ply, cloud)
    poisoned = str(official_outputs["poisoned"])
    cases = [
        ([str(_broken(base, tmp_path / "fx", lacks_fx))], "camera 3 lacks fx"),
        ([str(_broken(base, tmp_path / "nan", nan))], "position holds a NaN"),
        ([str(_broken(base, tmp_path / "rot", not_a_rotation))], "rotation is not a rotation matrix"),
        (
            [str(_broken(base, tmp_path / "width", no_width))],
            "width is 0: sizes are whole numbers of pixels, at least 1",
        ),
        ([str(_broken(base, tmp_path / "pc", no_point_cloud))], "has no point_cloud/ folder"),
        ([str(_broken(base, tmp_path / "it", no_iteration))], "holds no iteration_*/point_cloud.ply"),
        ([str(_broken(base, tmp_path / "cams", no_cameras))], "has no cameras.json"),
        ([str(_broken(base, tmp_path / "cfg", bad_cfg_args))], "cannot read"),
        ([poisoned, "--signals", "grad-concentration"], "--signals grad-concentration fine-tunes the model"),
        (
            [poisoned, "--frame", "colmap"],
            "without photos the model is taken in the frame of its cameras.json",
        ),
        ([poisoned, "--data", str(tiny_orbit_scene), "--frame", "colmap"], "no such frame"),
        ([str(far)], "does not sit on the cameras of"),
    ]
    for args, needle in cases:
        with pytest.raises(StealthNSError, match=re.escape(needle)) as info:
            main(["scan", "--model", *args, "--output", str(tmp_path / "o")])
        assert "\n" not in str(info.value)
    with pytest.raises(StealthNSError, match="inside the 3DGS output folder"):
        main(["scan", "--model", poisoned, "--output", str(Path(poisoned) / "scan")])
    # a report compares renders with photos: never on the cameras alone
    with pytest.raises(StealthNSError, match=re.escape("give --data, the dataset it was trained on")):
        load_model(Path(poisoned))
    assert not (tmp_path / "o").exists() and not (Path(poisoned) / "scan").exists()
