"""Check a dataset before training: one line naming the file, the frame and the problem.

nerfstudio's parser meets a missing or malformed ``transforms.json``, a missing or truncated image or
a NaN in a pose with a traceback deep inside data loading; training meets an image whose size is not
the camera's, absurd intrinsics or an unusable seed cloud the same way. :func:`check_dataset` reads
what nerfstudio reads, as it reads it, first: the transforms file parses and has frames; every file
it names stays inside the dataset folder, links resolved (:func:`check_references`); each pose is
finite and the cameras are not all at one place; the intrinsics (a top-level value wins over the
frame's, as in nerfstudio) are sane; each frame's image -- ``images_N/NAME`` at downscale factor N,
chosen as nerfstudio does -- decodes at the camera's size (nerfstudio, like COLMAP, ignores EXIF
orientation: a JPEG that fits only once turned as its tag says is refused and said so); the split
lists name frames; the seed points are usable (:func:`check_seed_points`). A COLMAP folder is read
with pycolmap (:func:`check_colmap`; a model not where ``--colmap-path`` says is looked for in the
folder, and the flag that reads it named), a Blender folder as blender-data reads it
(:func:`check_blender`). Raises :class:`~stealth_ns.foundation.errors.StealthNSError` with one line for the
first problem. The datamanager runs it at start-up (``ns-train``, with the dataparser it was given) and
``stealth-ns check-data --data DIR`` runs it on demand. The seed-point and path rules are
:mod:`stealth_ns.datasets.seed_check` and :mod:`stealth_ns.datasets.references`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.datasets.references import (
    Origins,
    check_frame_references,
    check_reference,
    check_references,
    leaves,
    read_json_object,
)
from stealth_ns.datasets.seed_check import (
    MAX_POINT_DISTANCE,
    MIN_SEED_POINTS,
    camera_spread,
    check_ply,
    check_seed_points,
    ply_vertex_count,
)
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import image_size, read_image

__all__ = [
    "MAX_POINT_DISTANCE", "MIN_SEED_POINTS", "DatasetSummary", "check_blender", "check_colmap",
    "check_dataset", "check_references", "check_seed_points", "ply_vertex_count", "read_json_object",
    "transforms_path",
]  # fmt: skip

INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
"""Camera parameters nerfstudio-data needs, globally or in every frame."""
DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
SPLITS = ("train", "val", "test")
CAMERA_MODELS = (
    "SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE", "EQUIRECTANGULAR",
    "OMNIDIRECTIONALSTEREO_L", "OMNIDIRECTIONALSTEREO_R", "VR180_L", "VR180_R", "ORTHOPHOTO", "FISHEYE624",
)  # fmt: skip
"""nerfstudio's ``CAMERA_MODEL_TO_TYPE`` keys (any other ``camera_model`` is a KeyError there)."""
MAX_AUTO_RESOLUTION = 1600
"""nerfstudio-data's: without a downscale factor, the first image's larger side is brought below it."""
MAX_INTRINSIC_RATIO = 1000.0
"""A focal length above this many times the image's larger side (a field of view under 0.06 degrees),
or below its 1/this (a pinhole view of 179.9 degrees), or a principal point further than this many
image sizes away, is no lens: it is a typo or an overflow (``fl_x`` 1e308 is inf in float32)."""
_EXIF_TURNS = {5: "mirror, turn 270 degrees", 6: "turn 90 degrees", 7: "mirror, turn 90 degrees",
               8: "turn 270 degrees"}  # fmt: skip


@dataclass(frozen=True)
class DatasetSummary:
    """What :func:`check_dataset` found; ``str()`` gives a one-paragraph summary."""

    transforms: Path
    """The transforms file (nerfstudio-data) or the dataset folder (COLMAP)."""
    n_frames: int
    sizes: tuple[tuple[int, int], ...]
    """The distinct image sizes (width, height), as nerfstudio reads them."""
    ply: Path | None
    """The seed-point file (the PLY, or COLMAP's points3D file)."""
    n_points: int | None
    splits: dict[str, int]
    model: str | None = None
    """COLMAP: the model folder, relative to :attr:`transforms`; None for nerfstudio-data."""
    blender: bool = False
    """A Blender folder (:attr:`transforms` is the folder; :attr:`splits` counts each split's frames)."""

    def __str__(self) -> str:
        sizes = ", ".join(f"{w}x{h}" for w, h in self.sizes)
        splits = ", ".join(f"{n} {name}" for name, n in self.splits.items()) or "no split lists"
        if self.ply is None:
            points = f"no seed points (no {'--ply-path' if self.blender else 'ply_file_path'})"
        else:
            points = f"{self.n_points} seed points in {self.ply.name}"
        head = f"Dataset OK: {self.transforms}"
        if self.model is not None:
            head += f" (COLMAP model {self.model})"
        if self.blender:
            head += " (Blender)"
        return (
            f"{head}\n  {self.n_frames} frames ({sizes}), {splits}; {points}; "
            "every image decodes, every pose is finite"
        )


def transforms_path(data: Path) -> Path:
    """The transforms file of a nerfstudio-data folder, or ``data`` itself when it is a JSON file."""
    data = Path(data).expanduser()
    return data if data.suffix == ".json" else data / "transforms.json"


def _load(path: Path) -> dict[str, Any]:
    if not path.parent.exists():
        raise StealthNSError(f"dataset folder {path.parent} does not exist")
    if not path.parent.is_dir():
        raise StealthNSError(f"{path.parent} is neither a dataset folder nor a transforms JSON file")
    if not path.is_file():
        raise StealthNSError(f"{path} does not exist: not a nerfstudio-data dataset (transforms.json)")
    meta = read_json_object(path)
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise StealthNSError(f'{path} has no frames (a non-empty "frames" list)')
    return meta


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_image(path: Path, where: str, decode: bool) -> tuple[int, int]:
    """``(width, height)`` of a frame's image: all its pixels decoded (a truncated file fails), or
    without ``decode`` its header only."""
    what = f"{where}: image"
    if not decode:
        return image_size(path, what)
    image = read_image(path, what)
    return int(image.shape[1]), int(image.shape[0])


def _image_sizes(images: Sequence[tuple[Path, str]], decode: bool) -> list[tuple[int, int]]:
    """:func:`_check_image` of each ``(path, where)`` of ``images``, in order. Decoding runs on every
    core at once (the decoders release the GIL); the failure raised is the first in ``images``' order."""
    if not decode or len(images) < 2:
        return [_check_image(path, where, decode) for path, where in images]
    pool = ThreadPoolExecutor(max_workers=min(len(images), os.cpu_count() or 1))
    try:
        return list(pool.map(lambda item: _check_image(item[0], item[1], True), images))
    finally:
        pool.shutdown(cancel_futures=True)


# ---------------------------------------------------------------------------------- cameras
def _check_camera_model(path: Path, meta: dict[str, Any]) -> None:
    model = meta.get("camera_model")
    if model is not None and model not in CAMERA_MODELS:
        raise StealthNSError(
            f"{path}: camera_model {model!r} is not one nerfstudio knows ({', '.join(CAMERA_MODELS)})"
        )


def _check_intrinsics(path: Path, meta: dict[str, Any], frame: dict[str, Any], where: str) -> dict[str, Any]:
    """The frame's intrinsics as nerfstudio takes them (a top-level value wins), checked."""
    values: dict[str, Any] = {}
    for key in INTRINSICS:
        value = meta[key] if key in meta else frame.get(key)
        if value is None:
            raise StealthNSError(
                f"{where}: no {key} (camera intrinsics), neither in the frame nor in {path.name}"
            )
        values[key] = value
    at = {key: (str(path) if key in meta else where) for key in INTRINSICS}
    for key in ("w", "h"):
        value = values[key]
        if not _finite(value) or value != int(value) or value < 1:
            raise StealthNSError(f"{at[key]}: {key} must be a positive integer (pixels), got {value!r}")
    size = max(values["w"], values["h"])
    for key in ("fl_x", "fl_y", "cx", "cy"):
        value = values[key]
        if not _finite(value) or (key.startswith("fl") and value <= 0):
            what = "a finite positive" if key.startswith("fl") else "a finite"
            raise StealthNSError(f"{at[key]}: {key} must be {what} number, got {value!r}")
        low, high = (size / MAX_INTRINSIC_RATIO, size * MAX_INTRINSIC_RATIO)
        if (key.startswith("fl") and not low <= value <= high) or abs(value) > high:
            bound = "between 1/{r:g} and {r:g} times" if key.startswith("fl") else "within {r:g} times"
            raise StealthNSError(
                f"{at[key]}: {key} {value!r} is absurd for a {values['w']}x{values['h']} image (it must be "
                f"{bound.format(r=MAX_INTRINSIC_RATIO)} the image size)"
            )
    _check_distortion(path, meta, frame, where)
    return values


def _check_distortion(path: Path, meta: dict[str, Any], frame: dict[str, Any], where: str) -> None:
    fixed = any(k in meta for k in (*DISTORTION, "distortion_params"))
    source, at = (meta, str(path)) if fixed else (frame, where)
    for key in DISTORTION:
        if key in source and not _finite(source[key]):
            raise StealthNSError(f"{at}: distortion {key} must be a finite number, got {source[key]!r}")
    params = source.get("distortion_params")
    if params is not None and not (isinstance(params, list) and all(_finite(v) for v in params)):
        raise StealthNSError(f"{at}: distortion_params must be a list of finite numbers, got {params!r}")


def _check_matrix(matrix: Any, where: str) -> None:
    rows = matrix if isinstance(matrix, list) else []
    if len(rows) != 4 or not all(isinstance(row, list) and len(row) == 4 for row in rows):
        raise StealthNSError(f"{where}: transform_matrix must be a 4x4 list of numbers")
    bad = [v for row in matrix for v in row if not _finite(v)]
    if bad:
        raise StealthNSError(f"{where}: transform_matrix holds a non-finite or non-number value ({bad[0]!r})")


# ---------------------------------------------------------------------------------- images
def _downscale_factor(root: Path, first: str, where: str, given: int | None) -> int:
    """The factor nerfstudio-data's parser uses: ``given``, else from the first frame's image."""
    if given is not None:
        return int(given)
    largest, df = max(image_size(root / first, f"{where}: image")), 0
    while (
        largest / 2**df > MAX_AUTO_RESOLUTION
        and (root / f"images_{2 ** (df + 1)}" / Path(first).name).exists()
    ):
        df += 1
    return 2**df


def _scaled(n: int, factor: int) -> int:
    """``n`` pixels at 1/``factor``, as nerfstudio's cameras compute it (float32, rounded down)."""
    return int(np.float32(n) * np.float32(1.0 / factor))


def _exif_note(image: Path, size: tuple[int, int], camera: tuple[int, int]) -> str:
    """Why ``image`` looks right elsewhere when its EXIF orientation swaps its sides into ``camera``."""
    if size[::-1] != camera:
        return ""
    try:
        from PIL import Image

        with Image.open(image) as im:
            orientation = int(im.getexif().get(0x0112, 1))  # EXIF Orientation
    except Exception:  # no EXIF to read: nothing to add
        return ""
    if orientation not in _EXIF_TURNS:
        return ""
    return (
        f": its EXIF orientation {orientation} ({_EXIF_TURNS[orientation]}) makes it {camera[0]}x{camera[1]} "
        "in a viewer, but nerfstudio ignores EXIF orientation and reads the pixels as stored; write the "
        "pixels turned as the tag says (PIL's ImageOps.exif_transpose) and without the tag"
    )


def _frame_image(root: Path, frame: dict[str, Any], factor: int) -> Path:
    """The image nerfstudio reads for ``frame`` at downscale ``factor``."""
    file_path = str(frame["file_path"])
    return root / file_path if factor == 1 else root / f"images_{factor}" / Path(file_path).name


def _check_frame_image(
    root: Path,
    frame: dict[str, Any],
    where: str,
    camera: tuple[int, int, str],
    factor: int,
    image: Path,
    size: tuple[int, int],
) -> tuple[int, int]:
    """``size``, that of ``frame``'s ``image``, which must be the ``camera``'s (``w``, ``h``, where they
    are given) at ``factor``; the frame's mask must exist."""
    w, h, given = camera
    expected = (_scaled(w, factor), _scaled(h, factor))
    if size != expected:
        if factor == 1:
            cam = f"is {w}x{h} (w, h in {given})"
        else:
            cam = f"({w}x{h} in {given}) at downscale factor {factor} is {expected[0]}x{expected[1]}"
        raise StealthNSError(
            f"{where}: image {image} is {size[0]}x{size[1]} but the camera {cam}"
            + _exif_note(image, size, expected)
        )
    mask = frame.get("mask_path")
    if mask is not None:
        mask_file = root / str(mask) if factor == 1 else root / f"masks_{factor}" / Path(str(mask)).name
        if not mask_file.is_file():
            raise StealthNSError(f"{where}: mask {mask_file} does not exist")
    return size


# ---------------------------------------------------------------------------------- the check
def _check_splits(path: Path, meta: dict[str, Any], names: set[str]) -> dict[str, int]:
    splits = {}
    for split in SPLITS:
        listed = meta.get(f"{split}_filenames")
        if listed is None:
            continue
        if not isinstance(listed, list):
            raise StealthNSError(f"{path}: {split}_filenames must be a list of frame file_paths")
        unknown = [n for n in listed if str(Path(str(n))) not in names]
        if unknown:
            raise StealthNSError(
                f"{path}: {split}_filenames names {unknown[0]!r}, which is no frame's file_path"
            )
        splits[split] = len(listed)
    return splits


def check_dataset(
    data: Path, decode: bool = True, downscale_factor: int | None = None, dataparser: str | None = None
) -> DatasetSummary:
    """Check the dataset ``data``: nerfstudio-data (a folder with ``transforms.json`` or the JSON file),
    a COLMAP folder (:func:`check_colmap`) or a Blender folder (:func:`check_blender`).

    ``decode``: decode every image (else only its header is read). ``downscale_factor``: nerfstudio's
    (None: chosen as nerfstudio does); > 1: the images are read from ``images_N/``. ``dataparser``:
    "nerfstudio-data" when ns-train reads ``data`` with it, which refuses a COLMAP or Blender folder
    naming the dataparser that reads it; None: the folder's own format. Raises
    :class:`StealthNSError` with one line naming the file and the frame (index and ``file_path``).
    """
    path = transforms_path(data)
    if not path.is_file() and path.parent.is_dir():
        model, folder = _colmap_model(path.parent), path.parent
        blender = model is None and any((folder / f"transforms_{s}.json").is_file() for s in BLENDER_SPLITS)
        if dataparser == "nerfstudio-data" and (model or blender):
            what, flags = ("COLMAP", f"colmap --data {folder} --colmap-path {model}") if model else (
                "Blender", f"blender-data --data {folder}"
            )  # fmt: skip
            raise StealthNSError(
                f"{path} does not exist: {folder} is a {what} dataset; train it with `{flags}` in place "
                "of nerfstudio-data"
            )
        if model:
            return check_colmap(folder, model, decode=decode)
        if blender:
            return check_blender(folder, decode=decode)
    meta = _load(path)
    _check_camera_model(path, meta)
    root, frames, origins = path.parent, meta["frames"], Origins()
    sizes: set[tuple[int, int]] = set()
    names: set[str] = set()
    factor = downscale_factor
    cameras: list[tuple[str, tuple[int, int, str]]] = []  # each frame's where and camera
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise StealthNSError(f"{path}: frame {i} is not a JSON object")
        file_path = frame.get("file_path")
        if not isinstance(file_path, str) or not file_path.strip():
            raise StealthNSError(f"{path}: frame {i} has no file_path")
        where = f"{path}: frame {i} ({file_path})"
        check_frame_references(path, i, frame, origins)
        _check_matrix(frame.get("transform_matrix"), where)
        values = _check_intrinsics(path, meta, frame, where)
        camera = (int(values["w"]), int(values["h"]), path.name if "w" in meta else "the frame")
        if i == 0:
            factor = _downscale_factor(root, file_path, where, downscale_factor)
        cameras.append((where, camera))
        names.add(str(Path(file_path)))
    images = [_frame_image(root, frame, int(factor or 1)) for frame in frames]
    found = _image_sizes([(image, where) for image, (where, _) in zip(images, cameras, strict=True)], decode)
    for frame, (where, camera), image, size in zip(frames, cameras, images, found, strict=True):
        sizes.add(_check_frame_image(root, frame, where, camera, int(factor or 1), image, size))
    splits = _check_splits(path, meta, names)
    positions = [[row[3] for row in frame["transform_matrix"][:3]] for frame in frames]
    centre, spread = camera_spread(np.array(positions, dtype=np.float64), str(path))
    for key in ("ply_file_path", "mask_path"):
        if meta.get(key) is not None:
            check_reference(root, meta[key], str(path), key, None)
    ply, n_points = None, None
    if meta.get("ply_file_path") is not None:
        ply = root / str(meta["ply_file_path"])
        hint = f"; triangulate them with `stealth-ns seed-points --data {data}` or remove ply_file_path"
        n_points = check_ply(ply, str(path), "ply_file_path", hint, centre, spread)
    return DatasetSummary(path, len(frames), tuple(sorted(sizes)), ply, n_points, splits)


def _check_folder(folder: Path) -> None:
    """StealthNSError unless the dataset folder ``folder`` is a folder."""
    if not folder.is_dir():
        raise StealthNSError(
            f"dataset folder {folder} " + ("is not a folder" if folder.exists() else "does not exist")
        )


# ---------------------------------------------------------------------------------- Blender
BLENDER_SPLITS = {"train": "the training views", "val": "ns-train's evaluation views", "test": "ns-eval's"}
"""Blender's ``transforms_SPLIT.json`` files, with what blender-data reads each for."""


def blender_image(file_path: str) -> str:
    """The image blender-data reads for a frame's ``file_path`` (relative to the folder): every "./"
    dropped and ".png" added, whatever the name ends with."""
    return file_path.replace("./", "") + ".png"


def _blender_frame_image(folder: Path, file_path: str, where: str, origins: Origins) -> Path:
    """The image of a frame, which must be inside the folder and named as blender-data names it."""
    name = blender_image(file_path)
    check_reference(folder, name, where, "file_path", origins)
    image = folder / name
    if not image.exists() and (folder / file_path).is_file():
        raise StealthNSError(
            f"{where}: image {image} does not exist: blender-data reads file_path + '.png', so "
            f"file_path names {folder / file_path} only without its extension"
        )
    return image


def _check_blender_split(
    folder: Path, split: str, decode: bool, origins: Origins, positions: list[list[float]]
) -> tuple[int, tuple[int, int]]:
    """One ``transforms_SPLIT.json``: its frame count and image size; its cameras' positions appended."""
    path = folder / f"transforms_{split}.json"
    if not path.is_file():
        other = " (it is a nerfstudio-data folder: train it with nerfstudio-data)"
        raise StealthNSError(
            f"{path} does not exist: blender-data reads {BLENDER_SPLITS[split]} from it"
            + (other if (folder / "transforms.json").is_file() else "")
        )
    meta = _load(path)
    angle = meta.get("camera_angle_x")
    if not _finite(angle) or not 0 < angle < math.pi:
        got = f"got {angle!r}" if "camera_angle_x" in meta else "it has none"
        raise StealthNSError(
            f"{path}: camera_angle_x (the horizontal field of view) must be a number of radians in "
            f"(0, pi), {got}"
        )
    images: list[tuple[Path, str]] = []  # each frame's image and where
    for i, frame in enumerate(meta["frames"]):
        file_path = frame.get("file_path") if isinstance(frame, dict) else None
        if not isinstance(file_path, str) or not file_path.strip():
            raise StealthNSError(f"{path}: frame {i} has no file_path (or is not a JSON object)")
        where = f"{path}: frame {i} ({file_path})"
        _check_matrix(frame.get("transform_matrix"), where)
        images.append((_blender_frame_image(folder, file_path, where, origins), where))
        positions.append([row[3] for row in frame["transform_matrix"][:3]])
    first: tuple[Path, tuple[int, int]] | None = None
    for (image, where), size in zip(images, _image_sizes(images, decode), strict=True):
        if first is not None and size != first[1]:
            raise StealthNSError(
                f"{where}: image {image} is {size[0]}x{size[1]} but the first frame's ({first[0].name}) is "
                f"{first[1][0]}x{first[1][1]}: blender-data gives every camera of {path.name} that size"
            )
        first = first or (image, size)
    assert first is not None  # _load refuses an empty frame list
    return len(meta["frames"]), first[1]


def check_blender(
    folder: Path, splits: tuple[str, ...] = ("train", "val"), decode: bool = True, ply: Path | None = None
) -> DatasetSummary:
    """Check a Blender (NeRF-synthetic) folder as nerfstudio's blender-data reads it: the ``splits``
    it needs (ns-train: train and val; ns-eval: test) and any other present each parse, with a
    camera_angle_x in (0, pi) and frames; each frame's pose is finite and its image (file_path +
    ".png", inside the folder) decodes at the size of the split's first image; the seed points of
    blender-data's ``--ply-path`` ``ply`` (relative to the folder), if given, are usable."""
    folder = Path(folder).expanduser()
    _check_folder(folder)
    present = [s for s in BLENDER_SPLITS if s in splits or (folder / f"transforms_{s}.json").is_file()]
    counts, sizes, positions, origins = {}, set(), [], Origins()
    for split in present:
        counts[split], size = _check_blender_split(folder, split, decode, origins, positions)
        sizes.add(size)
    n_points = None
    if ply is not None:
        centre, spread = camera_spread(np.array(positions, dtype=np.float64), str(folder))
        hint = f"; make them with `stealth-ns seed-points --data {folder}` or leave --ply-path out"
        ply = folder / ply
        n_points = check_ply(ply, f"blender-data --data {folder}", "--ply-path", hint, centre, spread)
    return DatasetSummary(
        folder, sum(counts.values()), tuple(sorted(sizes)), ply, n_points, counts, blender=True
    )


# ---------------------------------------------------------------------------------- COLMAP
def _colmap_model(folder: Path) -> str | None:
    """The COLMAP model folder of ``folder`` (relative; :func:`~stealth_ns.datasets.source.colmap_models`)."""
    from stealth_ns.datasets.source import colmap_models

    return next(iter(colmap_models(folder)), None)


def _check_model_folder(folder: Path, model: str) -> None:
    """StealthNSError unless ``folder / model`` holds a COLMAP model, saying where the folder's model is
    and which ``--colmap-path`` reads it."""
    from stealth_ns.datasets.source import colmap_models, holds_colmap_model

    _check_folder(folder)
    if holds_colmap_model(folder / model):
        return
    default = " (nerfstudio's default --colmap-path)" if Path(model) == Path("colmap/sparse/0") else ""
    where = f"{folder / model}{default} holds no COLMAP model (cameras.bin or cameras.txt)"
    found = colmap_models(folder)
    if not found:
        raise StealthNSError(f"{where}, nor does any folder in {folder}: is it a COLMAP dataset?")
    others = f" (others: {', '.join(found[1:4])})" if len(found) > 1 else ""
    raise StealthNSError(
        f"{where}: the model of {folder} is in {found[0]}{others}; give --colmap-path {found[0]}"
    )


def _read_colmap(model: Path) -> Any:
    import pycolmap  # a dependency of stealth-ns (seed-points, COLMAP copies)

    if not any((model / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
        raise StealthNSError(f"the COLMAP model {model} has no points3D (the seed points)")
    try:
        rec = pycolmap.Reconstruction(str(model))
    except Exception as err:  # pycolmap raises its own types for a truncated or malformed model
        reason = (str(err).strip().splitlines() or [type(err).__name__])[-1]
        raise StealthNSError(f"the COLMAP model {model} cannot be read ({reason})") from None
    if rec.num_cameras() == 0 or rec.num_images() == 0:
        raise StealthNSError(f"the COLMAP model {model} has no cameras or no images")
    return rec


def _check_colmap_camera(camera: Any, where: str) -> tuple[int, int]:
    w, h = int(camera.width), int(camera.height)
    params = np.asarray(camera.params, dtype=np.float64)
    focal = [float(params[k]) for k in camera.focal_length_idxs()]
    low, high = max(w, h) / MAX_INTRINSIC_RATIO, max(w, h) * MAX_INTRINSIC_RATIO
    if w < 1 or h < 1 or not np.isfinite(params).all() or not all(low <= f <= high for f in focal):
        what = f"size {w}x{h}, parameters {params.tolist()}"
        raise StealthNSError(f"{where}: camera {camera.camera_id} ({what}) is no usable camera")
    return w, h


def check_colmap(folder: Path, model: str, images: str = "images", decode: bool = True) -> DatasetSummary:
    """Check the COLMAP dataset ``folder`` (model ``folder/model``, images in ``folder/images``) as
    nerfstudio's colmap parser reads it: every image inside the folder, decoding, at its camera's size,
    with a finite pose; points3D usable seed points (:func:`check_seed_points`)."""
    _check_model_folder(Path(folder), model)
    model_dir = Path(folder) / model
    rec = _read_colmap(model_dir)
    sizes: set[tuple[int, int]] = set()
    centres = []
    checks: list[tuple[Path, str, tuple[int, int]]] = []  # each image's file, where and camera size
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        where = f"{model_dir}: image {image_id} ({image.name})"
        file = Path(folder) / images / image.name
        if (how := leaves(Path(folder), file)) is not None:
            raise StealthNSError(
                f"{model_dir}: image {image_id} {image.name!r} leaves the dataset folder {folder}{how}"
            )
        camera = _check_colmap_camera(rec.cameras[image.camera_id], str(model_dir))
        centre = np.asarray(image.projection_center(), dtype=np.float64)
        if not np.isfinite(centre).all():
            raise StealthNSError(f"{where}: its pose is not finite")
        centres.append(centre)
        checks.append((file, where, camera))
    found = _image_sizes([(file, where) for file, where, _ in checks], decode)
    for (file, where, camera), size in zip(checks, found, strict=True):
        if size != camera:
            raise StealthNSError(
                f"{where}: image {file} is {size[0]}x{size[1]} but its camera is {camera[0]}x{camera[1]}"
                + _exif_note(file, size, camera)
            )
        sizes.add(size)
    points = next(
        model_dir / f"points3D.{e}" for e in ("bin", "txt") if (model_dir / f"points3D.{e}").is_file()
    )
    ids = sorted(rec.points3D)
    xyz = np.array([rec.points3D[i].xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    centre, spread = camera_spread(np.array(centres), str(model_dir))
    check_seed_points(xyz, str(points), centre, spread, ids=ids)
    return DatasetSummary(Path(folder), rec.num_images(), tuple(sorted(sizes)), points, len(xyz), {}, model)
