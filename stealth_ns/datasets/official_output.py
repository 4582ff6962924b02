"""An output folder of the official 3DGS code (graphdeco-inria/gaussian-splatting's ``train.py``), read
and checked: its cameras, its newest Gaussians and its options, with no dataset needed.

=================================  ================================================================
file                               what it holds
=================================  ================================================================
``cameras.json``                   every camera of the dataset (``utils/camera_utils.py:
                                   camera_to_JSON``): ``id``, ``img_name``, ``width``, ``height``
                                   (pixels), ``position`` (the camera centre in the world),
                                   ``rotation`` (3 x 3, camera-to-world, in COLMAP/OpenCV camera axes:
                                   x right, y down, z forward), ``fx``, ``fy`` (pixels); no principal
                                   point (the official rasterizer puts it at the image centre). The
                                   held-out cameras first (``--eval``), then the training ones
``point_cloud/iteration_N/``       the Gaussians saved at iteration N (the newest is the model)
``point_cloud.ply``
``cfg_args``                       ``train.py``'s options as a ``Namespace(...)`` repr: ``source_path``
                                   (the dataset, with its photos), ``eval``, ``resolution``, ...
``input.ply``                      the seed points (not read)
=================================  ================================================================

The official code trains in the frame of the dataset's own poses (a COLMAP model's, a Blender
scene's ``transforms_*.json``), so the PLY and cameras.json share one frame. :func:`write_camera_dataset`
writes those cameras as a nerfstudio-data folder with flat placeholder images, so that a model can be
set up on them when no photos are at hand (the placeholders are no evidence of anything).
"""

from __future__ import annotations

import ast
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.datasets.frames import applied_transform
from stealth_ns.datasets.source import SceneSource, inspect_folder
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.images.io import save_png

CAMERAS_FILE = "cameras.json"
OPTIONS_FILE = "cfg_args"
POINT_CLOUD_DIR = "point_cloud"
PLY_NAME = "point_cloud.ply"
CAMERA_KEYS: tuple[str, ...] = ("id", "img_name", "width", "height", "position", "rotation", "fx", "fy")
#: The official COLMAP reader holds out every 8th image (by name) with ``--eval``.
LLFF_HOLD = 8
#: The official ``loadCam`` scales images wider than this down to it (``--resolution -1``).
MAX_AUTO_WIDTH = 1600
#: How far ``R Rᵀ`` may be from the identity (largest entry) for ``rotation`` to count as one.
ROTATION_TOLERANCE = 1e-4
#: OpenCV camera axes (x right, y down, z forward) -> OpenGL's (x right, y up, z back): flip y and z.
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0])
#: The placeholder images' grey (never compared with anything).
PLACEHOLDER_GREY = 0.5
#: Suffixes that make a cameras.json ``img_name`` a file name already (no ``.png`` is added to it).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".exr")


@dataclass(frozen=True)
class OfficialCamera:
    """One camera of cameras.json."""

    id: int
    name: str
    """``img_name``: the image's file name without its extension."""
    width: int
    height: int
    """Pixels, as the dataset gives them (before the training resolution is applied)."""
    rotation: np.ndarray
    """``[3, 3]`` camera-to-world rotation, OpenCV camera axes."""
    position: np.ndarray
    """``[3]`` the camera centre in the world."""
    fx: float
    fy: float


@dataclass(frozen=True)
class OfficialOutput:
    """An official 3DGS output folder, read and checked."""

    folder: Path
    cameras: tuple[OfficialCamera, ...]
    """In cameras.json's order."""
    ply: Path
    """The newest ``point_cloud/iteration_N/point_cloud.ply``."""
    iteration: int
    options: dict[str, Any] = field(default_factory=dict)
    """cfg_args (empty when the folder has none)."""

    @property
    def cameras_file(self) -> Path:
        return self.folder / CAMERAS_FILE

    @property
    def source_path(self) -> Path | None:
        """cfg_args' ``source_path`` (the dataset it was trained on), None when it names none."""
        source = self.options.get("source_path")
        return Path(source) if isinstance(source, str) and source else None


def is_official_output(path: Path) -> bool:
    """Whether ``path`` is a folder that an official 3DGS run wrote (cameras.json, cfg_args or
    point_cloud/ in it) and no nerfstudio run (no config.yml)."""
    path = Path(path)
    if not path.is_dir() or (path / "config.yml").is_file():
        return False
    return any((path / name).exists() for name in (CAMERAS_FILE, OPTIONS_FILE, POINT_CLOUD_DIR))


def read_official_output(folder: Path) -> OfficialOutput:
    """The output folder ``folder`` read and checked; one-line StealthNSError for every problem."""
    folder = Path(folder)
    ply, iteration = newest_point_cloud(folder)
    cameras_file = folder / CAMERAS_FILE
    if not cameras_file.is_file():
        raise StealthNSError(
            f"{folder} has no {CAMERAS_FILE}: not a complete output of the official 3DGS code"
        )
    options = read_options(folder / OPTIONS_FILE) if (folder / OPTIONS_FILE).is_file() else {}
    return OfficialOutput(folder, read_cameras(cameras_file), ply, iteration, options)


def newest_point_cloud(folder: Path) -> tuple[Path, int]:
    """``(point_cloud/iteration_N/point_cloud.ply, N)`` with the largest N (by number)."""
    root = Path(folder) / POINT_CLOUD_DIR
    if not root.is_dir():
        raise StealthNSError(
            f"{folder} has no {POINT_CLOUD_DIR}/ folder: the official 3DGS code saved no model there"
        )
    found = []
    for sub in root.iterdir():
        match = re.fullmatch(r"iteration_(\d+)", sub.name)
        if match and (sub / PLY_NAME).is_file():
            found.append((int(match.group(1)), sub / PLY_NAME))
    if not found:
        raise StealthNSError(f"{root} holds no iteration_*/{PLY_NAME}: no saved model")
    iteration, ply = max(found)
    return ply, iteration


def read_options(path: Path) -> dict[str, Any]:
    """cfg_args (``Namespace(sh_degree=3, source_path='...', ...)``) as a dict, read without running it."""
    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8").strip(), mode="eval").body
        if not (
            isinstance(tree, ast.Call) and isinstance(tree.func, ast.Name) and tree.func.id == "Namespace"
        ):
            raise ValueError("not a Namespace(...)")
        if tree.args or any(k.arg is None for k in tree.keywords):
            raise ValueError("not a Namespace of named options")
        return {k.arg: ast.literal_eval(k.value) for k in tree.keywords if k.arg is not None}
    except (OSError, UnicodeDecodeError, SyntaxError, ValueError) as err:
        raise StealthNSError(f"cannot read {path} (train.py's options): {err}") from None


def read_cameras(path: Path) -> tuple[OfficialCamera, ...]:
    """cameras.json's cameras, each checked (its keys, finite numbers, a rotation, sizes of 1 or more)."""
    try:
        entries = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise StealthNSError(f"cannot read {path}: {err}") from None
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise StealthNSError(f"{path} is not a cameras.json of the official 3DGS code (a list of cameras)")
    return tuple(_camera(entry, f"{path}: camera {i}") for i, entry in enumerate(entries))


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise StealthNSError(f"{what} is {value!r}, not a finite number")
    return float(value)


def _array(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = np.zeros(0)
    if array.shape != shape:
        raise StealthNSError(f"{what} is not {' x '.join(map(str, shape))} numbers")
    if not np.isfinite(array).all():
        raise StealthNSError(f"{what} holds a NaN or infinite number")
    return array


def _size(value: Any, what: str) -> int:
    number = value if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
    if not (math.isfinite(number) and number >= 1 and number == int(number)):
        raise StealthNSError(f"{what} is {value!r}: sizes are whole numbers of pixels, at least 1")
    return int(number)


def _camera(entry: dict[str, Any], where: str) -> OfficialCamera:
    missing = [k for k in CAMERA_KEYS if k not in entry]
    if missing:
        raise StealthNSError(
            f"{where} lacks {', '.join(missing)} (cameras.json keys: {', '.join(CAMERA_KEYS)})"
        )
    where = f"{where} ({entry['img_name']})"
    rotation = _array(entry["rotation"], (3, 3), f"{where}: rotation")
    off = float(np.abs(rotation @ rotation.T - np.eye(3)).max())
    if off > ROTATION_TOLERANCE or np.linalg.det(rotation) < 0:
        raise StealthNSError(
            f"{where}: rotation is not a rotation matrix (R Rᵀ is {off:.2g} from the identity, "
            f"determinant {np.linalg.det(rotation):.3g})"
        )
    fx, fy = (_number(entry[k], f"{where}: {k}") for k in ("fx", "fy"))
    if fx <= 0 or fy <= 0:
        raise StealthNSError(f"{where}: focal lengths must be positive, got fx {fx:g}, fy {fy:g}")
    return OfficialCamera(
        id=int(_number(entry["id"], f"{where}: id")),
        name=str(entry["img_name"]),
        width=_size(entry["width"], f"{where}: width"),
        height=_size(entry["height"], f"{where}: height"),
        rotation=rotation,
        position=_array(entry["position"], (3,), f"{where}: position"),
        fx=fx,
        fy=fy,
    )


# ------------------------------------------------------------------------------------ the photos


@dataclass(frozen=True)
class PhotoSource:
    """Where the photos of an official output come from, if anywhere."""

    dataset: Path | None
    """The dataset folder with the photos; None when there is none."""
    origin: str
    """``--data``, ``cfg_args' source_path`` or "" (none)."""
    note: str
    """Where the photos come from, or why there are none, in a sentence."""


def photo_source(output: OfficialOutput, data: Path | None) -> PhotoSource:
    """``--data`` when given, else cfg_args' ``source_path`` when it is a dataset folder here, else none."""
    if data is not None:
        return PhotoSource(Path(data), "--data", f"the photos of --data {data}")
    source = output.source_path
    if source is None:
        why = "its cfg_args names no source_path" if output.options else f"it has no {OPTIONS_FILE}"
        return PhotoSource(None, "", f"no photos: no --data, and {why}")
    if not source.is_dir():
        return PhotoSource(
            None, "", f"no photos: no --data, and cfg_args' source_path {source} does not exist"
        )
    try:
        inspect_folder("source_path", str(source))
    except StealthNSError as err:
        return PhotoSource(None, "", f"no photos: no --data, and cfg_args' source_path is no dataset ({err})")
    return PhotoSource(source, "cfg_args' source_path", f"the photos of cfg_args' source_path {source}")


def official_frame(scene: SceneSource) -> str:
    """The frame (:mod:`stealth_ns.datasets.frames`) that the official code, which reads a COLMAP model
    or a Blender scene as it is, trains in on ``scene``: the COLMAP model's for a nerfstudio-data folder
    converted from one by ``ns-process-data``, the dataset's own otherwise."""
    return "colmap" if applied_transform(scene) is not None else "dataset"


# ------------------------------------------------------------------------------ the training views


@dataclass(frozen=True)
class TrainingSplit:
    """Which cameras of cameras.json the model was trained on (indices into cameras.json)."""

    training: tuple[int, ...]
    held_out: tuple[int, ...]
    note: str
    """How the split was found, in a sentence."""


def training_split(cameras: tuple[OfficialCamera, ...], options: dict[str, Any]) -> TrainingSplit:
    """The training cameras: every camera unless cfg_args says ``eval=True``; then the official COLMAP
    reader's hold-out (every :data:`LLFF_HOLD`-th image by name, written first) when cameras.json's order
    shows it, else every camera (a Blender scene's held-out views cannot be told apart by name)."""
    every = tuple(range(len(cameras)))
    if "eval" not in options:
        return TrainingSplit(every, (), f"all {len(cameras)} cameras (no cfg_args to tell a held-out split)")
    if not options["eval"]:
        return TrainingSplit(every, (), f"all {len(cameras)} cameras (trained without --eval)")
    names = sorted(c.name for c in cameras)
    held = names[::LLFF_HOLD]
    kept = [n for i, n in enumerate(names) if i % LLFF_HOLD]
    if [c.name for c in cameras] == held + kept:
        k = len(held)
        note = f"{len(cameras) - k} of {len(cameras)} cameras: every {LLFF_HOLD}th by name held out (--eval)"
        return TrainingSplit(every[k:], every[:k], note)
    return TrainingSplit(
        every,
        (),
        f"all {len(cameras)} cameras: trained with --eval, but its held-out ones cannot be told apart",
    )


def training_size(camera: OfficialCamera, resolution: Any) -> tuple[int, int]:
    """``(width, height)`` the official ``loadCam`` trains ``camera`` at for ``--resolution``: 1, 2, 4 or 8
    divide the size; -1 (the default) scales a width over :data:`MAX_AUTO_WIDTH` down to it; another
    positive number is the width."""
    w, h = camera.width, camera.height
    if resolution in (1, 2, 4, 8):
        return max(1, round(w / resolution)), max(1, round(h / resolution))
    scale = w / MAX_AUTO_WIDTH if w > MAX_AUTO_WIDTH else 1.0
    if isinstance(resolution, (int, float)) and not isinstance(resolution, bool) and resolution > 0:
        scale = w / resolution
    return max(1, int(w / scale)), max(1, int(h / scale))


def opengl_camera_to_world(camera: OfficialCamera) -> np.ndarray:
    """``[4, 4]`` the camera-to-world matrix in OpenGL camera axes (nerfstudio's ``transform_matrix``)."""
    c2w = np.eye(4)
    c2w[:3, :3] = camera.rotation @ OPENCV_TO_OPENGL
    c2w[:3, 3] = camera.position
    return c2w


def placeholder_paths(names: list[str]) -> list[str]:
    """A placeholder image's path per camera name as cameras.json holds it: ``images/NAME``, with ``.png``
    added only to a name without an image suffix (the official code writes ``image010``, other trainers
    ``image010.png``); characters a file name should not hold become ``_``; a path two cameras would share
    gets the camera's index before its suffix."""
    paths = []
    for name in names:
        clean = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".") or "view"
        paths.append(clean if Path(clean).suffix.lower() in IMAGE_SUFFIXES else f"{clean}.png")
    unique = []
    for i, path in enumerate(paths):
        if paths.count(path) > 1:
            path = f"{Path(path).stem}_{i}{Path(path).suffix}"
        unique.append(f"images/{path}")
    return unique


def write_camera_dataset(output: OfficialOutput, folder: Path) -> TrainingSplit:
    """Write ``output``'s cameras into ``folder`` as a nerfstudio-data dataset in the output's own frame
    (no ``applied_transform``): each at its training size (:func:`training_size`), principal point at
    the image centre, the held-out ones (:func:`training_split`) as the test split, and a flat grey
    placeholder image each. Returns the split."""
    folder = Path(folder)
    split = training_split(output.cameras, output.options)
    names = placeholder_paths([c.name for c in output.cameras])
    frames = []
    for camera, name in zip(output.cameras, names, strict=True):
        w, h = training_size(camera, output.options.get("resolution", -1))
        sx, sy = w / camera.width, h / camera.height
        frames.append({
            "file_path": name,
            "transform_matrix": opengl_camera_to_world(camera).tolist(),
            "fl_x": camera.fx * sx, "fl_y": camera.fy * sy, "cx": w / 2.0, "cy": h / 2.0, "w": w, "h": h,
        })  # fmt: skip
        save_png(folder / name, np.full((h, w, 3), PLACEHOLDER_GREY, dtype=np.float32))
    training = [names[i] for i in split.training]
    held_out = [names[i] for i in split.held_out] or training[:1]  # nerfstudio wants a test split
    meta = {
        "camera_model": "OPENCV",
        "frames": frames,
        "train_filenames": training,
        "val_filenames": held_out,
        "test_filenames": held_out,
    }
    write_json_atomic(folder / "transforms.json", meta)
    return split
