"""A broken Blender (NeRF-synthetic) folder gives one line naming the file, the frame and the problem,
from ``stealth-ns check-data`` and from ns-train's start-up check with ``blender-data``, as nerfstudio-data
and COLMAP folders do; before, check-data did not read Blender folders at all, blender-data met a
missing image or malformed JSON with a traceback and trained on a NaN pose (issue 57, class 4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stealth_ns.cli import main
from stealth_ns.datasets.check import check_blender, check_dataset
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.scene_generator import make_scene

TRAIN = "transforms_train.json"
FRAME = 3  # the frame the mutations break, in transforms_train.json
IMAGE = "train/r_3.png"


@pytest.fixture
def scene(tmp_path) -> Path:
    """An ``object`` scene at 32x32 with 12 views (8 train, 2 val, 2 test), in the Blender format."""
    out = tmp_path / "object"
    make_scene(preset="object", output=out, resolution="32x32", views=12, seed=0)
    return out


def _edit(scene: Path, edit, name: str = TRAIN) -> None:
    path = scene / name
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))  # NaN / Infinity as JSON's extension literals, as Python reads them


def _frame(meta: dict) -> dict:
    return meta["frames"][FRAME]


def _pose(value: float):
    return lambda meta: _frame(meta)["transform_matrix"][0].__setitem__(3, value)


def _other_size(scene: Path) -> None:
    from PIL import Image

    Image.new("RGBA", (32, 30)).save(scene / IMAGE)


def _with_extension(scene: Path) -> None:
    _edit(scene, lambda m: _frame(m).update(file_path="./train/r_3.png"))


def _outside(scene: Path) -> None:
    (scene.parent / "secret.png").write_bytes((scene / IMAGE).read_bytes())
    _edit(scene, lambda m: _frame(m).update(file_path="/" + str(scene.parent / "secret")))


WHERE = f"{TRAIN}: frame {FRAME} (./train/r_3)"
MUTATIONS = {
    # name: (mutate(scene), what the one line must say)
    "missing image": (lambda s: (s / IMAGE).unlink(), [WHERE, f"{IMAGE} does not exist"]),
    "truncated image": (
        lambda s: (s / IMAGE).write_bytes((s / IMAGE).read_bytes()[:200]),
        [WHERE, "cannot be read"],
    ),
    "image of another size": (_other_size, [WHERE, "is 32x30", "(r_0.png) is 32x32"]),
    "file_path with its extension": (
        _with_extension,
        [f"{TRAIN}: frame {FRAME} (./train/r_3.png)", "r_3.png.png does not exist", "file_path + '.png'"],
    ),
    "image outside the folder": (_outside, [f"{TRAIN}: frame {FRAME}", "leaves the dataset folder"]),
    "malformed json": (
        lambda s: (s / TRAIN).write_text('{"frames": [ {"file_path": '),
        [TRAIN, "is not valid JSON", "line 1"],
    ),
    "missing transforms_train.json": (lambda s: (s / TRAIN).unlink(), [TRAIN, "does not exist"]),
    "missing transforms_val.json": (
        lambda s: (s / "transforms_val.json").unlink(),
        ["transforms_val.json does not exist", "evaluation views"],
    ),
    "no frames": (lambda s: _edit(s, lambda m: m.update(frames=[])), [TRAIN, "has no frames"]),
    "no camera_angle_x": (lambda s: _edit(s, lambda m: m.pop("camera_angle_x")), [TRAIN, "camera_angle_x"]),
    "camera_angle_x a string": (
        lambda s: _edit(s, lambda m: m.update(camera_angle_x="0.69")),
        [TRAIN, "camera_angle_x", "'0.69'"],
    ),
    "camera_angle_x 4 radians": (
        lambda s: _edit(s, lambda m: m.update(camera_angle_x=4.0)),
        [TRAIN, "camera_angle_x", "(0, pi)", "4.0"],
    ),
    "frame without file_path": (
        lambda s: _edit(s, lambda m: _frame(m).pop("file_path")),
        [f"{TRAIN}: frame {FRAME} has no file_path"],
    ),
    "nan pose": (lambda s: _edit(s, _pose(float("nan"))), [WHERE, "transform_matrix", "nan"]),
    "inf pose": (lambda s: _edit(s, _pose(float("inf"))), [WHERE, "transform_matrix", "inf"]),
    "pose not 4x4": (
        lambda s: _edit(s, lambda m: _frame(m).update(transform_matrix=[[1, 0, 0]])),
        [WHERE, "4x4"],
    ),
    "test split nan pose": (
        lambda s: _edit(
            s,
            lambda m: m["frames"][1]["transform_matrix"][2].__setitem__(1, float("nan")),
            "transforms_test.json",
        ),
        ["transforms_test.json: frame 1 (./test/r_1)", "nan"],
    ),  # fmt: skip
}


def test_a_good_blender_folder_passes(scene, capsys):
    summary = check_dataset(scene)
    assert summary.blender and summary.transforms == scene
    assert (summary.n_frames, summary.sizes, summary.splits) == (
        12,
        ((32, 32),),
        {"train": 8, "val": 2, "test": 2},
    )
    main(["check-data", "--data", str(scene)])
    out = capsys.readouterr().out
    assert (
        out.startswith(f"Dataset OK: {scene} (Blender)")
        and "12 frames (32x32), 8 train, 2 val, 2 test" in out
    )


@pytest.mark.parametrize("case", list(MUTATIONS))
def test_a_broken_blender_folder_is_one_line(scene, case, capsys):
    mutate, needles = MUTATIONS[case]
    mutate(scene)
    with pytest.raises(StealthNSError) as info:
        check_dataset(scene)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(scene)), message
    for needle in needles:
        assert needle in message, message
    with pytest.raises(SystemExit) as exc:
        main(["check-data", "--data", str(scene)])
    assert exc.value.code == 1
    assert capsys.readouterr().err.strip() == f"stealth-ns: error: {message}"


def test_the_splits_nerfstudio_reads_are_required(scene):
    """ns-train reads train and val (check-data too); ns-eval reads test; a split nobody asked for is
    checked when it is there."""
    (scene / "transforms_test.json").unlink()
    assert check_dataset(scene).splits == {"train": 8, "val": 2}
    with pytest.raises(
        StealthNSError, match=r"transforms_test.json does not exist: blender-data reads ns-eval"
    ):
        check_blender(scene, ("train", "test"))


def test_blender_data_ply_path_is_checked(scene):
    from stealth_ns.scene_generator.writer import write_ply

    rng = np.random.default_rng(0)
    write_ply(
        scene / "points.ply", rng.normal(size=(50, 3)).astype(np.float32), np.full((50, 3), 128, np.uint8)
    )
    summary = check_blender(scene, ply=Path("points.ply"))
    assert (summary.ply, summary.n_points) == (scene / "points.ply", 50)
    with pytest.raises(StealthNSError, match=r"--ply-path .*missing.ply \(seed points\) does not exist"):
        check_blender(scene, ply=Path("missing.ply"))
    write_ply(scene / "one.ply", np.zeros((1, 3), np.float32), np.full((1, 3), 128, np.uint8))
    with pytest.raises(StealthNSError, match=r"one.ply has 1 point: at least 4"):
        check_blender(scene, ply=Path("one.ply"))


def test_the_wrong_dataparser_is_named(scene, tiny_orbit_scene):
    with pytest.raises(StealthNSError) as info:
        check_dataset(scene, dataparser="nerfstudio-data")
    assert f"is a Blender dataset; train it with `blender-data --data {scene}`" in str(info.value)
    with pytest.raises(StealthNSError, match="it is a nerfstudio-data folder: train it with nerfstudio-data"):
        check_blender(tiny_orbit_scene)


# ---------------------------------------------------------------------------------- ns-train's start-up
def _blender_pipeline(scene: Path, test_mode: str = "val"):
    """stealth-splat-lite's pipeline (attack off) on ``scene`` through blender-data, set up."""
    import copy

    from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig

    from stealth_ns.method_configs.registry import method_config

    config = copy.deepcopy(method_config("stealth-splat-lite")).pipeline
    config.datamanager.dataparser = BlenderDataParserConfig(data=scene)
    config.attack.enabled = False
    return config.setup(device="cpu", test_mode=test_mode)


@pytest.mark.parametrize(
    "case", ["missing image", "malformed json", "nan pose", "missing transforms_val.json"]
)
def test_training_start_up_refuses_a_broken_blender_folder(scene, case):
    """Before: FileNotFoundError / JSONDecodeError tracebacks, and a NaN pose trained silently."""
    mutate, needles = MUTATIONS[case]
    mutate(scene)
    with pytest.raises(SystemExit) as exc:
        _blender_pipeline(scene)
    message = str(exc.value)
    assert message.startswith(f"stealth-ns: error: {scene}") and "\n" not in message, message
    for needle in needles:
        assert needle in message, message


def test_training_start_up_takes_a_good_blender_folder(scene):
    pipeline = _blender_pipeline(scene)
    assert len(pipeline.datamanager.train_dataset) == 8
