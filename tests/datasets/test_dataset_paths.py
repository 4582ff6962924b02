"""A dataset's files stay inside its folder (issue 32, class 2).

A ``transforms.json`` whose frame names ``../../../../etc/passwd`` (or an absolute path, or a link
that leads out) as its image, depth or mask, or whose ``ply_file_path`` is outside the folder, is
refused with one line naming the file, the frame and the key -- by ``check-data``, at ns-train
start-up and by ``poison-dataset`` before the outside file reaches the copy it writes for sharing.
The one legitimate case keeps working: a seeded copy (``stealth-ns seed-points --output``) names
the images (and depths, masks) of the dataset it was made from, which declares them as its own.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from attack_helpers import build_pipeline

from stealth_ns.attack.config import AttackConfig
from stealth_ns.cli import main
from stealth_ns.datasets.check import check_dataset
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image, save_png

IMAGE = "images/frame_00003.png"
PASSWD = "../" * 40 + "etc/passwd"  # the example: resolves to /etc/passwd from anywhere
DATA_ONLY = AttackConfig(view_noise=False, noise_decay="constant")


def _meta(folder: Path) -> dict:
    return json.loads((folder / "transforms.json").read_text(encoding="utf-8"))


def _write_meta(folder: Path, meta: dict) -> None:
    (folder / "transforms.json").write_text(json.dumps(meta), encoding="utf-8")


def _index(folder: Path, name: str = IMAGE) -> int:
    return next(i for i, f in enumerate(_meta(folder)["frames"]) if f["file_path"] == name)


@pytest.fixture
def ds(tiny_orbit_scene, tmp_path) -> Path:
    """A copy of the tiny scene at ``tmp/x/ds``, a secret text file at ``tmp/secret/passwd`` and a
    private picture (an image no dataset names) at ``tmp/photos/private.png``."""
    (tmp_path / "secret").mkdir()
    (tmp_path / "secret" / "passwd").write_text("root:x:0:0:secret\n")
    (tmp_path / "photos").mkdir()
    shutil.copy2(tiny_orbit_scene / IMAGE, tmp_path / "photos" / "private.png")
    return Path(shutil.copytree(tiny_orbit_scene, tmp_path / "x" / "ds"))


def _set_frame(folder: Path, key: str, value: str, name: str = IMAGE) -> None:
    meta = _meta(folder)
    frame = next(f for f in meta["frames"] if f["file_path"] == name)
    frame[key] = value
    if key == "file_path":  # the split lists name frames by their file_path
        for split in ("train_filenames", "val_filenames", "test_filenames"):
            meta[split] = [value if p == name else p for p in meta[split]]
    _write_meta(folder, meta)


def _outside_ply(folder: Path, absolute: bool) -> str:
    target = folder.parent.parent / "points" / "cloud.ply"
    target.parent.mkdir()
    shutil.copy2(folder / "sparse_pc.ply", target)
    return str(target) if absolute else os.path.relpath(target, folder)


def _link(folder: Path, rel: str, target: Path) -> str:
    (folder / rel).unlink()
    (folder / rel).symlink_to(target)
    return rel


#: case -> (key, make(ds) -> the value written under key); "ply_file_path" is the top-level key.
ESCAPES = {
    "file_path relative to a text file": ("file_path", lambda d: "../../secret/passwd"),
    "file_path relative to a picture": ("file_path", lambda d: "../../photos/private.png"),
    "file_path absolute": ("file_path", lambda d: str(d.parent.parent / "photos" / "private.png")),
    "file_path /etc/passwd": ("file_path", lambda d: PASSWD),
    "depth_file_path /etc/passwd": ("depth_file_path", lambda d: PASSWD),
    "depth_file_path absolute": ("depth_file_path", lambda d: str(d.parent.parent / "secret" / "passwd")),
    "mask_path relative": ("mask_path", lambda d: "../../secret/passwd"),
    "ply_file_path absolute": ("ply_file_path", lambda d: _outside_ply(d, absolute=True)),
    "ply_file_path relative": ("ply_file_path", lambda d: _outside_ply(d, absolute=False)),
    "image linked out": ("file_path", lambda d: _link(d, IMAGE, d.parent.parent / "photos" / "private.png")),
    "depth linked out": (
        "depth_file_path",
        lambda d: _link(d, "depths/frame_00003.npy", d.parent.parent / "secret" / "passwd"),
    ),
}


def _escape(ds: Path, case: str) -> tuple[str, str, int]:
    """Apply ``case`` to ``ds``; returns (key, value, frame index)."""
    key, make = ESCAPES[case]
    index = _index(ds)
    value = make(ds)
    if key == "ply_file_path":
        meta = _meta(ds)
        meta["ply_file_path"] = value
        _write_meta(ds, meta)
    elif "linked" not in case:
        _set_frame(ds, key, value)
    return key, value, index


@pytest.mark.parametrize("case", list(ESCAPES))
def test_a_path_leaving_the_dataset_is_one_line(ds, case, capsys):
    key, value, index = _escape(ds, case)
    with pytest.raises(StealthNSError) as info:
        check_dataset(ds)
    message = str(info.value)
    assert "\n" not in message
    where = (
        f"{ds / 'transforms.json'}: "
        if key == "ply_file_path"
        else f"{ds / 'transforms.json'}: frame {index}"
    )
    assert message.startswith(where), message
    assert f"{key} {value!r} leaves the dataset folder {ds}" in message, message
    if "linked" in case:
        assert "symbolic link" in message, message
    with pytest.raises(SystemExit) as exc:  # check-data: the same line, exit status 1
        main(["check-data", "--data", str(ds)])
    assert exc.value.code == 1
    assert capsys.readouterr().err.strip() == f"stealth-ns: error: {message}"


def test_training_start_up_refuses_a_depth_outside(ds):
    _escape(ds, "depth_file_path /etc/passwd")
    with pytest.raises(SystemExit) as exc:
        build_pipeline(ds, AttackConfig(enabled=False))
    message = str(exc.value)
    assert message.startswith("stealth-ns: error: ") and "\n" not in message
    assert f"depth_file_path {PASSWD!r} leaves the dataset folder {ds}" in message


# ---------------------------------------------------------------------------------- seeded copies
def _fake_triangulate(ply: Path):
    """Stands in for pycolmap's triangulation (the tiny scene is too small to match): the scene's
    own seed points."""
    from stealth_ns.datasets.triangulation import Points
    from stealth_ns.scene_generator.writer import read_ply

    def triangulate(frames, seed):
        xyz, rgb = read_ply(ply)
        n = len(xyz)
        return Points(xyz, rgb, np.full(n, 0.5), np.full(n, 5)), {"inliers": 0, "pairs": 0, "keypoints": 0}

    return triangulate


@pytest.fixture
def seeded(ds, tmp_path, monkeypatch) -> Path:
    """``stealth-ns seed-points --data ds --output tmp/runs/seeded``: the copy names the images and
    depths of ``ds`` by ``../../x/ds/...``."""
    from stealth_ns.datasets import seed_points

    monkeypatch.setattr(seed_points, "triangulate", _fake_triangulate(ds / "sparse_pc.ply"))
    out = tmp_path / "runs" / "seeded"
    seed_points.make_seed_points(ds, output=out)
    return out


def test_a_seeded_copy_names_the_files_of_its_dataset(seeded, ds):
    meta = _meta(seeded)
    assert meta["frames"][0]["file_path"].startswith("../../x/ds/images/")
    assert meta["frames"][0]["depth_file_path"].startswith("../../x/ds/depths/")
    summary = check_dataset(seeded)
    assert summary.n_frames == 16 and summary.n_points and summary.ply == seeded / "sparse_pc.ply"
    # an absolute path to the dataset's image is the same file (bench's stand-in writes those)
    for frame in meta["frames"]:
        frame["file_path"] = str((seeded / frame["file_path"]).resolve())
    for split in ("train_filenames", "val_filenames", "test_filenames"):
        meta[split] = [str((seeded / p).resolve()) for p in meta[split]]
    _write_meta(seeded, meta)
    assert check_dataset(seeded).n_frames == 16


def test_images_linked_from_another_dataset_are_its_files(ds, tiny_orbit_scene, tmp_path):
    scene = tmp_path / "linked"
    scene.mkdir()
    (scene / "images").symlink_to(tiny_orbit_scene / "images")
    meta = _meta(tiny_orbit_scene)
    for frame in meta["frames"]:
        del frame["depth_file_path"]
    del meta["ply_file_path"]
    _write_meta(scene, meta)
    assert check_dataset(scene).n_frames == 16


@pytest.mark.parametrize(
    "key, target",
    [
        ("file_path", "scene.json"),  # a file of the dataset, but none of its frames' images
        ("depth_file_path", IMAGE),  # its frame's image, not its depth: the key must match
        ("depth_file_path", "../../secret/passwd"),
    ],
)
def test_a_seeded_copy_may_name_only_what_its_dataset_declares(seeded, ds, key, target):
    name = _meta(seeded)["frames"][3]["file_path"]
    value = os.path.relpath(ds / target, seeded)
    _set_frame(seeded, key, value, name=name)
    with pytest.raises(StealthNSError) as info:
        check_dataset(seeded)
    message = str(info.value)
    assert message.startswith(f"{seeded / 'transforms.json'}: frame 3"), message
    assert message.endswith(f"{key} {value!r} leaves the dataset folder {seeded}"), message


# ---------------------------------------------------------------------------------- poisoned copies
def _holds(folder: Path, data: bytes) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file() and p.read_bytes() == data]


def test_poison_dataset_refuses_before_writing(ds, tmp_path):
    from stealth_ns.poisoned_datasets.data_only import poison_dataset

    _escape(ds, "depth_file_path absolute")
    out = tmp_path / "poisoned"
    with pytest.raises(StealthNSError, match=r"frame \d+ \(.*\): depth_file_path '.*' leaves the dataset"):
        poison_dataset(ds, out, DATA_ONLY)
    assert not out.exists()


@pytest.mark.parametrize("case", ["depth_file_path absolute", "file_path relative to a picture"])
def test_the_copy_never_takes_a_file_from_outside(ds, tmp_path, case):
    """The copy itself (as ipa-poison makes it before training) refuses before copying outside files."""
    from stealth_ns.poisoned_datasets.dataset_copy import copy_dataset, open_source

    _escape(ds, case)
    out = tmp_path / "poisoned"
    with pytest.raises(StealthNSError, match="leaves the dataset folder") as info:
        copy_dataset(open_source(ds), out)
    assert "\n" not in str(info.value)
    secret = (tmp_path / "secret" / "passwd").read_bytes()
    assert not (out / "external").exists() and not _holds(out, secret)


def test_absolute_paths_into_the_dataset_are_made_relative(ds, tmp_path):
    """A frame naming its own image by an absolute path: the copy must name the copy's image, not the
    input's (the poisoned image is written into the copy)."""
    from stealth_ns.poisoned_datasets.dataset_copy import copy_dataset, open_source

    meta = _meta(ds)
    for frame in meta["frames"]:
        frame["file_path"] = str(ds / frame["file_path"])
    for split in ("train_filenames", "val_filenames", "test_filenames"):
        meta[split] = [str(ds / p) for p in meta[split]]
    _write_meta(ds, meta)
    out = tmp_path / "poisoned"
    copy_dataset(open_source(ds), out)
    copied = _meta(out)
    assert [f["file_path"] for f in copied["frames"]] == [f"images/frame_{i:05d}.png" for i in range(16)]
    assert all(not os.path.isabs(p) for p in copied["train_filenames"] + copied["test_filenames"])
    assert check_dataset(out).n_frames == 16


def test_outside_files_of_the_same_name_do_not_overwrite_each_other(ds, tmp_path):
    """A seeded copy naming ``images/frame_00000.png`` of two datasets: both reach the copy."""
    from stealth_ns.poisoned_datasets.dataset_copy import copy_dataset, open_source

    other = Path(shutil.copytree(ds, tmp_path / "y" / "ds"))
    pixels = read_image(other / "images" / "frame_00000.png")
    save_png(other / "images" / "frame_00000.png", 255 - pixels)
    seeded = tmp_path / "seeded"
    seeded.mkdir()
    shutil.copy2(ds / "sparse_pc.ply", seeded / "sparse_pc.ply")
    meta = _meta(ds)
    for frame in meta["frames"]:
        del frame["depth_file_path"]
        frame["file_path"] = f"../x/ds/{frame['file_path']}"
    meta["frames"][1]["file_path"] = "../y/ds/images/frame_00000.png"
    names = [f["file_path"] for f in meta["frames"]]
    meta["train_filenames"] = [n for i, n in enumerate(names) if i not in (0, 8)]
    meta["val_filenames"] = meta["test_filenames"] = [names[0], names[8]]
    _write_meta(seeded, meta)
    check_dataset(seeded)

    out = tmp_path / "poisoned"
    copy_dataset(open_source(seeded), out)
    frames = _meta(out)["frames"]
    first, second = out / frames[0]["file_path"], out / frames[1]["file_path"]
    assert first != second
    assert first.read_bytes() == (ds / "images" / "frame_00000.png").read_bytes()
    assert second.read_bytes() == (other / "images" / "frame_00000.png").read_bytes()
