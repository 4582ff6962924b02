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
with pycolmap (:func:`check_colmap`). Raises :class:`~stealth_ns.errors.StealthNSError` with one
line for the first problem. The datamanager runs it at start-up (``ns-train``) and
``stealth-ns check-data --data DIR`` runs it on demand.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.errors import StealthNSError
from stealth_ns.image_io import image_size, read_image

__all__ = [
    "DatasetSummary", "check_colmap", "check_dataset", "check_references", "check_seed_points",
    "ply_vertex_count", "read_json_object", "transforms_path",
]  # fmt: skip

INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
"""Camera parameters nerfstudio-data needs, globally or in every frame."""
DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
SPLITS = ("train", "val", "test")
FRAME_FILE_KEYS = ("file_path", "depth_file_path", "mask_path")  # a frame's files
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
MIN_SEED_POINTS = 4
"""A Gaussian's first size is the mean distance to its 3 nearest seed points (splatfacto, which
raises with fewer points), and the density-guided injection voxelises the cloud's bounding box."""
MAX_POINT_DISTANCE = 1e6
"""Seed points further than this many times the cameras' spread (the largest distance of a camera
from their mean; nerfstudio scales it to about 1) from the cameras' mean are absurd: float32, in
which nerfstudio loads and trains them, has steps of 0.06 spreads there, and one such point
stretches the attack's density grid (over the cloud's bounding box) 1e6 times past the scene. Far
backgrounds of real captures are within 1e3 spreads; coordinates far from the origin (UTM, in
metres) are fine when the cameras are there too."""
_EXIF_TURNS = {5: "mirror, turn 270 degrees", 6: "turn 90 degrees", 7: "mirror, turn 90 degrees",
               8: "turn 270 degrees"}  # fmt: skip
_ORIGIN_FILES = ("transforms.json", "transforms_train.json", "transforms_val.json", "transforms_test.json")


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

    def __str__(self) -> str:
        sizes = ", ".join(f"{w}x{h}" for w, h in self.sizes)
        splits = ", ".join(f"{n} {name}" for name, n in self.splits.items()) or "no split lists"
        if self.ply is None:
            points = "no seed points (no ply_file_path)"
        else:
            points = f"{self.n_points} seed points in {self.ply.name}"
        head = f"Dataset OK: {self.transforms}"
        if self.model is not None:
            head += f" (COLMAP model {self.model})"
        return (
            f"{head}\n  {self.n_frames} frames ({sizes}), {splits}; {points}; "
            "every image decodes, every pose is finite"
        )


def transforms_path(data: Path) -> Path:
    """The transforms file of a nerfstudio-data folder, or ``data`` itself when it is a JSON file."""
    data = Path(data).expanduser()
    return data if data.suffix == ".json" else data / "transforms.json"


def read_json_object(path: Path) -> dict[str, Any]:
    """A transforms file's JSON object; StealthNSError naming the file if it is not one."""
    try:
        meta = json.loads(Path(path).read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise StealthNSError(f"{path} is not a text (JSON) file") from None
    except json.JSONDecodeError as err:
        raise StealthNSError(
            f"{path} is not valid JSON: {err.msg} at line {err.lineno} column {err.colno}"
        ) from None
    except OSError as err:
        raise StealthNSError(f"cannot read {path}: {err.strerror or type(err).__name__}") from None
    if not isinstance(meta, dict):
        raise StealthNSError(f"{path} must hold a JSON object, got a {type(meta).__name__}")
    return meta


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


def ply_vertex_count(path: Path) -> int:
    """Points in a PLY file, from its header; StealthNSError naming the file if it is no PLY."""
    try:
        with open(path, "rb") as f:
            if f.readline().strip() != b"ply":
                raise StealthNSError(f"seed-point file {path} is not a PLY file")
            for _ in range(200):
                line = f.readline()
                if not line or line.strip() == b"end_header":
                    break
                parts = line.split()
                if parts[:2] == [b"element", b"vertex"] and len(parts) == 3 and parts[2].isdigit():
                    return int(parts[2])
    except OSError as err:
        raise StealthNSError(f"seed-point file {path} cannot be read: {err.strerror}") from None
    raise StealthNSError(f"seed-point file {path} has no vertex element in its header")


# ---------------------------------------------------------------------------------- paths
def _real(path: Path) -> Path:
    return Path(os.path.realpath(path))


class _Origins:
    """The files other datasets on this machine declare as their own, by key.

    A seeded copy (``stealth-ns seed-points --output``) names the images, depths and masks of the
    dataset it was made from (``../ds/images/0001.png``, or by an absolute path), and seed-points
    marks it in no other way. So a file outside the dataset folder is accepted only when
    a dataset folder holding it (an ancestor folder with a nerfstudio-data or Blender transforms
    file) names it under the same key as a frame's file: what a seeded copy names, and never
    ``/etc/passwd``, a private photo no dataset lists, or a depth that is another dataset's image.
    """

    def __init__(self) -> None:
        self._declared: dict[Path, dict[str, set[Path]]] = {}
        self._transforms: dict[Path, list[Path]] = {}

    def declares(self, file: Path, key: str) -> bool:
        """Whether a dataset folder above the (resolved) ``file`` names it as a frame's ``key``."""
        for folder in file.parents:
            if folder not in self._transforms:
                self._transforms[folder] = [folder / n for n in _ORIGIN_FILES if (folder / n).is_file()]
            if any(file in self._files(t)[key] for t in self._transforms[folder]):
                return True
        return False

    def _files(self, transforms: Path) -> dict[str, set[Path]]:
        if transforms not in self._declared:
            files: dict[str, set[Path]] = {key: set() for key in FRAME_FILE_KEYS}
            try:
                frames = read_json_object(transforms).get("frames")
            except StealthNSError:
                frames = None
            blender = transforms.name != "transforms.json"
            for frame in frames if isinstance(frames, list) else []:
                for key in FRAME_FILE_KEYS:
                    value = frame.get(key) if isinstance(frame, dict) else None
                    if isinstance(value, str) and value:
                        if blender and key == "file_path" and not Path(value).suffix:
                            value += ".png"  # as nerfstudio's blender parser and seed-points read it
                        files[key].add(_real(transforms.parent / value))
            self._declared[transforms] = files
        return self._declared[transforms]


def _check_reference(root: Path, value: Any, where: str, key: str, origins: _Origins | None) -> None:
    """StealthNSError unless ``root / value`` is inside ``root`` (links resolved) or, with ``origins``,
    a file another dataset declares under ``key``."""
    if not isinstance(value, str) or not value.strip():
        raise StealthNSError(f"{where}: {key} must be a file path (a non-empty string), got {value!r}")
    leaves = _leaves(root, root / value)
    if leaves is not None and not (origins is not None and origins.declares(_real(root / value), key)):
        raise StealthNSError(f"{where}: {key} {value!r} leaves the dataset folder {root}{leaves}")


def _leaves(root: Path, path: Path) -> str | None:
    """None when ``path`` is inside ``root`` with links resolved, else how it leaves (a link or not)."""
    real = _real(path)
    if real.is_relative_to(_real(root)):
        return None
    lexical = Path(os.path.normpath(os.path.abspath(path)))
    return f" (a symbolic link to {real})" if lexical.is_relative_to(os.path.abspath(root)) else ""


def _check_frame_references(path: Path, i: int, frame: dict[str, Any], origins: _Origins) -> None:
    for key in FRAME_FILE_KEYS:
        if key in frame:
            where = f"{path}: frame {i}" + ("" if key == "file_path" else f" ({frame.get('file_path')})")
            _check_reference(path.parent, frame[key], where, key, origins)


def check_references(path: Path, meta: dict[str, Any]) -> None:
    """StealthNSError with one line for the first file the transforms file ``path`` (holding ``meta``)
    names outside its folder: a frame's ``file_path``, ``depth_file_path`` or ``mask_path`` (unless
    another dataset declares it, see :class:`_Origins`), the ``ply_file_path`` or a top-level
    ``mask_path`` (always inside). Links are resolved before comparing."""
    origins = _Origins()
    frames = meta.get("frames")
    for i, frame in enumerate(frames if isinstance(frames, list) else []):
        if isinstance(frame, dict):
            _check_frame_references(path, i, frame, origins)
    for key in ("ply_file_path", "mask_path"):
        if meta.get(key) is not None:
            _check_reference(path.parent, meta[key], str(path), key, None)


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


def _camera_spread(positions: np.ndarray, what: str) -> tuple[np.ndarray, float]:
    """The cameras' mean position and spread (largest distance from it) for ``positions`` [C, 3];
    StealthNSError if they all are at one position (nerfstudio divides by the spread)."""
    centre = positions.mean(axis=0)
    spread = float(np.linalg.norm(positions - centre, axis=1).max())
    if spread <= 1e-6 * max(1.0, float(np.abs(centre).max())):
        raise StealthNSError(
            f"{what}: every frame's camera is at the same position ({_xyz(positions[0])}): nerfstudio "
            "scales the scene by how far apart the cameras are"
        )
    return centre, spread


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


def _check_frame_image(
    root: Path, frame: dict[str, Any], where: str, camera: tuple[int, int, str], factor: int, decode: bool
) -> tuple[int, int]:
    """The size of the image nerfstudio reads for ``frame``, which must be the ``camera``'s
    (``w``, ``h``, where they are given) at ``factor``."""
    file_path = str(frame["file_path"])
    image = root / file_path if factor == 1 else root / f"images_{factor}" / Path(file_path).name
    size = _check_image(image, where, decode)
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


# ---------------------------------------------------------------------------------- seed points
def _xyz(p: np.ndarray) -> str:
    return ", ".join(f"{float(v):.6g}" for v in p)


def check_seed_points(
    xyz: np.ndarray, what: str, centre: np.ndarray, spread: float, hint: str = "", ids: Any = None
) -> None:
    """StealthNSError naming ``what`` for a seed cloud ``xyz`` [N, 3] training cannot start from: no
    points, a non-finite one, fewer than :data:`MIN_SEED_POINTS`, all at one position, or one further
    than :data:`MAX_POINT_DISTANCE` times the cameras' ``spread`` from their ``centre``. A point is
    named by its index, or ``point3D ID`` from ``ids`` (COLMAP)."""

    def point(k: int) -> str:
        return f"point {k}" if ids is None else f"point3D {ids[k]}"

    n = len(xyz)
    if n == 0:
        raise StealthNSError(f"{what} has no points{hint}")
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if bad.size:
        raise StealthNSError(
            f"{what}: {point(bad[0])} is ({_xyz(xyz[bad[0]])}), not a finite position "
            f"({bad.size} such point{'s' * (bad.size != 1)})"
        )
    if n < MIN_SEED_POINTS:
        raise StealthNSError(
            f"{what} has {n} point{'s' * (n != 1)}: at least {MIN_SEED_POINTS} are needed (a Gaussian's "
            f"first size is its distance to its 3 nearest neighbours){hint}"
        )
    if float(np.ptp(xyz, axis=0).max()) == 0.0:
        raise StealthNSError(
            f"{what}: all {n} points coincide at ({_xyz(xyz[0])}); they span no volume{hint}"
        )
    distance = np.linalg.norm(xyz - centre, axis=1) / spread
    k = int(np.argmax(distance))
    if distance[k] > MAX_POINT_DISTANCE:
        raise StealthNSError(
            f"{what}: {point(k)} at ({_xyz(xyz[k])}) is {distance[k]:.3g} times the cameras' spread from "
            f"their centre (more than {MAX_POINT_DISTANCE:g}): an absurd position"
        )


def _check_ply(
    path: Path, meta: dict[str, Any], data: Path, centre: np.ndarray, spread: float
) -> tuple[Path, int]:
    ply = path.parent / str(meta["ply_file_path"])
    if not ply.is_file():
        raise StealthNSError(
            f"{path}: ply_file_path {ply} (seed points) does not exist; triangulate them with "
            f"`stealth-ns seed-points --data {data}` or remove ply_file_path"
        )
    hint = f"; triangulate them with `stealth-ns seed-points --data {data}` or remove ply_file_path"
    try:
        n = ply_vertex_count(ply)
    except StealthNSError as err:
        raise StealthNSError(f"{path}: {err}") from None
    xyz = np.zeros((0, 3))
    if n > 0:  # read as nerfstudio reads it
        import open3d as o3d

        xyz = np.asarray(o3d.io.read_point_cloud(str(ply)).points, dtype=np.float64)
        if len(xyz) != n:
            raise StealthNSError(f"{path}: open3d reads {len(xyz)} of the {n} points of {ply}")
    check_seed_points(xyz, f"{path}: seed-point file {ply}", centre, spread, hint)
    return ply, len(xyz)


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


def check_dataset(data: Path, decode: bool = True, downscale_factor: int | None = None) -> DatasetSummary:
    """Check the dataset ``data``: nerfstudio-data (a folder with ``transforms.json`` or the JSON file),
    or a COLMAP folder (:func:`check_colmap`).

    ``decode``: decode every image (else only its header is read). ``downscale_factor``: nerfstudio's
    (None: chosen as nerfstudio does); > 1: the images are read from ``images_N/``. Raises
    :class:`StealthNSError` with one line naming the file and the frame (index and ``file_path``).
    """
    path = transforms_path(data)
    if not path.is_file() and Path(data).expanduser().is_dir() and (model := _colmap_model(path.parent)):
        return check_colmap(path.parent, model, decode=decode)
    meta = _load(path)
    _check_camera_model(path, meta)
    root, frames, origins = path.parent, meta["frames"], _Origins()
    sizes: set[tuple[int, int]] = set()
    names: set[str] = set()
    factor = downscale_factor
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise StealthNSError(f"{path}: frame {i} is not a JSON object")
        file_path = frame.get("file_path")
        if not isinstance(file_path, str) or not file_path.strip():
            raise StealthNSError(f"{path}: frame {i} has no file_path")
        where = f"{path}: frame {i} ({file_path})"
        _check_frame_references(path, i, frame, origins)
        _check_matrix(frame.get("transform_matrix"), where)
        values = _check_intrinsics(path, meta, frame, where)
        camera = (int(values["w"]), int(values["h"]), path.name if "w" in meta else "the frame")
        if i == 0:
            factor = _downscale_factor(root, file_path, where, downscale_factor)
        sizes.add(_check_frame_image(root, frame, where, camera, int(factor or 1), decode))
        names.add(str(Path(file_path)))
    splits = _check_splits(path, meta, names)
    positions = [[row[3] for row in frame["transform_matrix"][:3]] for frame in frames]
    centre, spread = _camera_spread(np.array(positions, dtype=np.float64), str(path))
    for key in ("ply_file_path", "mask_path"):
        if meta.get(key) is not None:
            _check_reference(root, meta[key], str(path), key, None)
    ply, n_points = None, None
    if meta.get("ply_file_path") is not None:
        ply, n_points = _check_ply(path, meta, Path(data), centre, spread)
    return DatasetSummary(path, len(frames), tuple(sorted(sizes)), ply, n_points, splits)


# ---------------------------------------------------------------------------------- COLMAP
def _colmap_model(folder: Path) -> str | None:
    """The COLMAP model folder of ``folder`` (relative), as the bench and poison-dataset find it."""
    from stealth_ns.datasets.source import COLMAP_DIRS

    for rel in COLMAP_DIRS:
        if any((folder / rel / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return rel
    return None


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
    model_dir = Path(folder) / model
    rec = _read_colmap(model_dir)
    sizes: set[tuple[int, int]] = set()
    centres = []
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        where = f"{model_dir}: image {image_id} ({image.name})"
        file = Path(folder) / images / image.name
        if (leaves := _leaves(Path(folder), file)) is not None:
            raise StealthNSError(
                f"{model_dir}: image {image_id} {image.name!r} leaves the dataset folder {folder}{leaves}"
            )
        camera = _check_colmap_camera(rec.cameras[image.camera_id], str(model_dir))
        centre = np.asarray(image.projection_center(), dtype=np.float64)
        if not np.isfinite(centre).all():
            raise StealthNSError(f"{where}: its pose is not finite")
        centres.append(centre)
        size = _check_image(file, where, decode)
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
    centre, spread = _camera_spread(np.array(centres), str(model_dir))
    check_seed_points(xyz, str(points), centre, spread, ids=ids)
    return DatasetSummary(Path(folder), rec.num_images(), tuple(sorted(sizes)), points, len(xyz), {}, model)
