"""A broken nerfstudio-data dataset gives one line naming the file and the frame, from
``stealth-ns check-data`` and from ns-train's datamanager, never a traceback (issue 13, item 8)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from attack_helpers import build_pipeline
from dataset_helpers import colmap_folder

from stealth_ns.attack.config import AttackConfig
from stealth_ns.cli import main
from stealth_ns.datasets.check import check_dataset
from stealth_ns.foundation.errors import StealthNSError

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


def _refused_in_one_line(scene: Path, mutation: tuple, capsys) -> str:
    """Break ``scene`` with ``mutation`` ``(mutate, needles)``: the check refuses it with one line that
    holds every needle (``{i}``: the frame's index), and ``check-data`` prints that line on stderr and
    exits 1. Returns the line."""
    index = _frame_index(scene, IMAGE)
    mutate, needles = mutation
    mutate(scene)
    with pytest.raises(StealthNSError) as info:
        check_dataset(scene)
    message = str(info.value)
    assert "\n" not in message
    for needle in needles:
        assert needle.format(i=index) in message, message
    with pytest.raises(SystemExit) as exc:
        main(["check-data", "--data", str(scene)])
    assert exc.value.code == 1
    assert capsys.readouterr().err.strip() == f"stealth-ns: error: {message}"
    return message


@pytest.mark.parametrize("case", list(MUTATIONS))
def test_broken_dataset_is_one_line_naming_file_and_frame(scene, case, capsys):
    _refused_in_one_line(scene, MUTATIONS[case], capsys)


def test_of_several_broken_images_the_first_frame_is_named(scene):
    """The images are decoded on every core at once; the error is still the first frame's in the
    transforms' order, whichever decode finishes first."""
    frames = json.loads((scene / "transforms.json").read_text())["frames"]
    for frame in frames[3:]:
        _truncate(scene / frame["file_path"])
    (scene / frames[-1]["file_path"]).write_text("hello")  # fails at once, before the truncated ones
    with pytest.raises(StealthNSError, match=rf"frame 3 \({frames[3]['file_path']}\).*cannot be read"):
        check_dataset(scene)


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


# ---------------------------------------------------------------------------------- issue 32, class 3
# check-data said OK and training then died with a traceback (or ran on something unusable).
def _jpeg(path: Path, pixels, orientation: int) -> None:
    from PIL import Image

    exif = Image.Exif()
    exif[0x0112] = orientation  # EXIF Orientation
    Image.fromarray(pixels).save(path, quality=95, exif=exif)


def _as_rotated_jpeg(scene: Path, rotate: bool) -> None:
    """IMAGE as a JPEG with EXIF orientation 6 (rotate 90 degrees to display): its pixels stored
    rotated (48x64, shown 64x48 by a viewer that honours EXIF), or as they are (64x48)."""
    import numpy as np

    from stealth_ns.images.io import read_image

    pixels = read_image(scene / IMAGE)
    jpg = IMAGE.replace(".png", ".jpg")
    _jpeg(scene / jpg, np.ascontiguousarray(np.rot90(pixels)) if rotate else pixels, 6)
    (scene / IMAGE).unlink()

    def rename(meta: dict) -> None:
        for frame in meta["frames"]:
            if frame["file_path"] == IMAGE:
                frame["file_path"] = jpg
        for split in SPLITS:
            meta[split] = [jpg if p == IMAGE else p for p in meta[split]]

    _edit_transforms(scene, rename)


def _per_frame_size(meta: dict) -> None:
    """w and h per frame (none globally), IMAGE's width wrong."""
    del meta["w"], meta["h"]
    for frame in meta["frames"]:
        frame["w"], frame["h"] = (60 if frame["file_path"] == IMAGE else 64), 48


def _points(scene: Path, xyz) -> None:
    import numpy as np

    from stealth_ns.scene_generator.writer import write_ply

    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    write_ply(scene / "sparse_pc.ply", xyz, np.full((len(xyz), 3), 128, dtype=np.uint8))


def _add_point(scene: Path, point) -> None:
    import numpy as np

    from stealth_ns.scene_generator.writer import read_ply

    xyz, _ = read_ply(scene / "sparse_pc.ply")
    _points(scene, np.concatenate([xyz, np.asarray([point], dtype=np.float32)]))


def _same_position(meta: dict) -> None:
    for frame in meta["frames"]:
        for row in range(3):
            frame["transform_matrix"][row][3] = 1.0


SPLITS = ("train_filenames", "val_filenames", "test_filenames")
PLY = "sparse_pc.ply"

UNUSABLE = {
    # name: (mutate(scene), what the one line must say); {i}: IMAGE's frame index
    "exif rotation": (
        lambda s: _as_rotated_jpeg(s, rotate=True),
        ["frame {i} (images/frame_00003.jpg)", "is 48x64", "64x48", "EXIF orientation 6", "ignores"],
    ),
    "w/h do not match": (
        lambda s: _edit_transforms(s, lambda m: m.update(w=65)),
        ["frame 0 (images/frame_00000.png)", "is 64x48", "65x48"],
    ),
    "per-frame w does not match": (
        lambda s: _edit_transforms(s, _per_frame_size),
        ["frame {i} (" + IMAGE + ")", "is 64x48", "60x48"],
    ),
    "fl_x 1e308": (lambda s: _edit_transforms(s, lambda m: m.update(fl_x=1e308)), ["fl_x", "1e+308"]),
    "fl_y 1e-300": (lambda s: _edit_transforms(s, lambda m: m.update(fl_y=1e-300)), ["fl_y", "1e-300"]),
    "cx 1e300": (lambda s: _edit_transforms(s, lambda m: m.update(cx=1e300)), ["cx", "1e+300"]),
    "w not an integer": (lambda s: _edit_transforms(s, lambda m: m.update(w=64.5)), ["w", "64.5", "integer"]),
    "h a string": (lambda s: _edit_transforms(s, lambda m: m.update(h="48")), ["h", "'48'"]),
    "k1 nan": (lambda s: _edit_transforms(s, lambda m: m.update(k1=float("nan"))), ["k1", "nan"]),
    "unknown camera model": (
        lambda s: _edit_transforms(s, lambda m: m.update(camera_model="PINHOL")),
        ["camera_model 'PINHOL'", "OPENCV"],
    ),
    "cameras at one position": (
        lambda s: _edit_transforms(s, _same_position),
        ["every frame's camera is at the same position"],
    ),
    "ply with 0 points": (lambda s: _points(s, []), [PLY, "has no points"]),
    "ply with 1 point": (lambda s: _points(s, [[0.1, 0.2, 0.3]]), [PLY, "1 point", "at least 4"]),
    "ply points coincide": (lambda s: _points(s, [[0.1, 0.2, 0.3]] * 6), [PLY, "all 6 points", "coincide"]),
    "ply nan point": (lambda s: _add_point(s, [float("nan"), 0, 0]), [PLY, "point 8008", "nan"]),
    "ply inf point": (lambda s: _add_point(s, [0, float("inf"), 0]), [PLY, "point 8008", "inf"]),
    "ply absurd point": (lambda s: _add_point(s, [1e20, 0, 0]), [PLY, "point 8008", "1e+20", "1e+06"]),
}


@pytest.mark.parametrize("case", list(UNUSABLE))
def test_unusable_dataset_is_one_line(scene, case, capsys):
    message = _refused_in_one_line(scene, UNUSABLE[case], capsys)
    assert message.startswith(str(scene)), message


@pytest.mark.parametrize("case", ["w/h do not match", "fl_x 1e308", "ply with 1 point", "ply nan point"])
def test_training_start_up_refuses_an_unusable_dataset(scene, case):
    """These died in training (an assertion on the image size, a ValueError on the intrinsics, on
    a degenerate or non-finite cloud) after check-data said OK."""
    mutate, needles = UNUSABLE[case]
    mutate(scene)
    with pytest.raises(SystemExit) as exc:
        build_pipeline(scene, AttackConfig(enabled=False))
    message = str(exc.value)
    assert message.startswith("stealth-ns: error: ") and "\n" not in message
    assert needles[0].format(i=_frame_index(scene, IMAGE)) in message, message


def test_exif_orientation_of_an_image_stored_as_the_camera_sees_it_is_fine(scene):
    """nerfstudio reads pixels as stored (no EXIF rotation), as COLMAP does: a JPEG whose stored
    size is the camera's trains as it is, whatever its orientation tag."""
    _as_rotated_jpeg(scene, rotate=False)
    assert check_dataset(scene).sizes == ((64, 48),)
    pipeline = build_pipeline(scene, AttackConfig(enabled=False))
    assert len(pipeline.datamanager.train_dataset) == 14


def _downscaled(scene: Path, factor: int, size: tuple[int, int]) -> None:
    from PIL import Image

    for image in sorted((scene / "images").iterdir()):
        folder = scene / f"images_{factor}"
        folder.mkdir(exist_ok=True)
        Image.open(image).resize(size).save(folder / image.name)


def test_downscaled_images_match_the_camera_scaled_as_nerfstudio_does(scene):
    """With --downscale-factor N nerfstudio reads images_N/NAME and scales w, h by 1/N (rounded down):
    those images must have that size; the full-size ones are not read."""
    with pytest.raises(StealthNSError, match=r"frame 0 \(images/frame_00000.png\): image .*images_2/"):
        check_dataset(scene, downscale_factor=2)  # no images_2/: nerfstudio would not find them
    _downscaled(scene, 2, (32, 24))
    _downscaled(scene, 3, (21, 16))  # 64 / 3 -> 21, 48 / 3 -> 16
    (scene / IMAGE).unlink()
    assert check_dataset(scene, downscale_factor=2).sizes == ((32, 24),)
    assert check_dataset(scene, downscale_factor=3).sizes == ((21, 16),)
    _downscaled(scene, 3, (22, 16))
    with pytest.raises(StealthNSError, match=r"is 22x16 but the camera .* at downscale factor 3 is 21x16"):
        check_dataset(scene, downscale_factor=3)


def test_camera_models_are_nerfstudios():
    from nerfstudio.cameras.cameras import CAMERA_MODEL_TO_TYPE
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import MAX_AUTO_RESOLUTION

    from stealth_ns.datasets import check as dataset_check

    assert set(dataset_check.CAMERA_MODELS) == set(CAMERA_MODEL_TO_TYPE)
    assert dataset_check.MAX_AUTO_RESOLUTION == MAX_AUTO_RESOLUTION


# ---------------------------------------------------------------------------------- COLMAP
def test_a_colmap_folder_is_checked(tiny_orbit_scene, tmp_path, capsys):
    pytest.importorskip("pycolmap")
    data = colmap_folder(tiny_orbit_scene, tmp_path / "colmap")
    summary = check_dataset(data)
    assert (summary.n_frames, summary.sizes, summary.n_points) == (16, ((64, 48),), 8008)
    main(["check-data", "--data", str(data)])
    out = capsys.readouterr().out
    assert out.startswith(f"Dataset OK: {data} (COLMAP model sparse/0)") and "8008 seed points" in out


@pytest.mark.parametrize(
    "points, needles",
    [
        ([], ["points3D.bin", "has no points"]),
        ([[0.0, 0.0, 0.0]], ["points3D.bin", "1 point", "at least 4"]),
        ([[0.0, 0.0, 0.0]] * 4 + [[float("nan"), 1.0, 1.0]], ["points3D.bin", "point3D 5", "nan"]),
    ],
    ids=["empty", "one point", "nan"],
)
def test_a_colmap_model_without_usable_points_is_one_line(
    tiny_orbit_scene, tmp_path, points, needles, capsys
):
    pytest.importorskip("pycolmap")
    data = colmap_folder(tiny_orbit_scene, tmp_path / "colmap", points)
    with pytest.raises(StealthNSError) as info:
        check_dataset(data)
    message = str(info.value)
    assert "\n" not in message and all(n in message for n in needles), message
    with pytest.raises(SystemExit) as exc:
        main(["check-data", "--data", str(data)])
    assert exc.value.code == 1
    assert capsys.readouterr().err.strip() == f"stealth-ns: error: {message}"


def test_a_colmap_image_outside_its_folder_is_refused(tiny_orbit_scene, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    data = colmap_folder(tiny_orbit_scene, tmp_path / "colmap")
    model = pycolmap.Reconstruction(str(data / "sparse" / "0"))
    (tmp_path / "secret.png").write_bytes((data / "images" / "frame_00003.png").read_bytes())
    model.image(4).name = "../../secret.png"
    model.write_binary(str(data / "sparse" / "0"))
    with pytest.raises(StealthNSError, match=r"image 4 '\.\./\.\./secret.png' leaves the dataset folder"):
        check_dataset(data)
