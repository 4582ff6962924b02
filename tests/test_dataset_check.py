"""A broken nerfstudio-data dataset gives one line naming the file and the frame, from
``stealth-ns check-data`` and from ns-train's datamanager, never a traceback (issue 13, item 8)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from attack_helpers import build_pipeline

from stealth_ns.attack.config import AttackConfig
from stealth_ns.cli import main
from stealth_ns.dataset_check import check_dataset
from stealth_ns.errors import StealthNSError

IMAGE = "images/frame_00003.png"


def _edit_transforms(scene: Path, edit) -> None:
    path = scene / "transforms.json"
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))  # NaN / Infinity are written as JSON's extension literals


def _frame_index(scene: Path, name: str) -> int:
    frames = json.loads((scene / "transforms.json").read_text())["frames"]
    return next(i for i, f in enumerate(frames) if f["file_path"] == name)


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _nan_pose(meta: dict) -> None:
    next(f for f in meta["frames"] if f["file_path"] == IMAGE)["transform_matrix"][1][3] = float("nan")


def _no_focal(meta: dict) -> None:
    del meta["fl_x"]


MUTATIONS = {
    # name: (mutate(scene), what the one line must say)
    "missing transforms": (lambda s: (s / "transforms.json").unlink(), ["transforms.json", "does not exist"]),
    "malformed json": (
        lambda s: (s / "transforms.json").write_text('{"frames": [ {"file_path": '),
        ["transforms.json", "is not valid JSON", "line 1"],
    ),
    "no frames": (lambda s: _edit_transforms(s, lambda m: m.update(frames=[])), ["has no frames"]),
    "missing image": (lambda s: (s / IMAGE).unlink(), ["frame {i} (" + IMAGE + ")", "does not exist"]),
    "truncated image": (lambda s: _truncate(s / IMAGE), ["frame {i} (" + IMAGE + ")", "cannot be read"]),
    "not an image": (
        lambda s: (s / IMAGE).write_text("hello"),
        ["frame {i} (" + IMAGE + ")", "cannot be read"],
    ),
    "nan pose": (
        lambda s: _edit_transforms(s, _nan_pose),
        ["frame {i} (" + IMAGE + ")", "transform_matrix", "nan"],
    ),
    "no focal length": (lambda s: _edit_transforms(s, _no_focal), ["frame 0 (", "no fl_x"]),
}


@pytest.fixture
def scene(tiny_orbit_scene, tmp_path) -> Path:
    return Path(shutil.copytree(tiny_orbit_scene, tmp_path / "scene"))


def test_a_good_dataset_passes(tiny_orbit_scene, capsys):
    summary = check_dataset(tiny_orbit_scene)
    assert (summary.n_frames, summary.sizes) == (16, ((64, 48),))
    assert summary.n_points and summary.n_points > 0
    main(["check-data", "--data", str(tiny_orbit_scene)])
    out = capsys.readouterr().out
    assert out.startswith("Dataset OK:") and "16 frames (64x48)" in out
    assert "seed points in sparse_pc.ply" in out


@pytest.mark.parametrize("case", list(MUTATIONS))
def test_broken_dataset_is_one_line_naming_file_and_frame(scene, case, capsys):
    index = _frame_index(scene, IMAGE)
    mutate, needles = MUTATIONS[case]
    mutate(scene)
    with pytest.raises(StealthNSError) as info:
        check_dataset(scene)
    message = str(info.value)
    assert "\n" not in message
    for needle in needles:
        assert needle.format(i=index) in message, message
    # the command: the same line on stderr, exit status 1
    with pytest.raises(SystemExit) as exc:
        main(["check-data", "--data", str(scene)])
    assert exc.value.code == 1
    assert capsys.readouterr().err.strip() == f"stealth-ns: error: {message}"


@pytest.mark.parametrize("case", ["missing transforms", "truncated image", "nan pose"])
def test_training_start_up_refuses_a_broken_dataset(scene, case):
    index = _frame_index(scene, IMAGE)
    mutate, needles = MUTATIONS[case]
    mutate(scene)
    with pytest.raises(SystemExit) as exc:
        build_pipeline(scene, AttackConfig(enabled=False))
    message = str(exc.value)
    assert message.startswith("stealth-ns: error: ") and "\n" not in message
    for needle in needles:
        assert needle.format(i=index) in message, message
