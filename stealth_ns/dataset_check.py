"""Check a nerfstudio-data dataset before training: one line naming the file and the frame.

nerfstudio's parser meets a missing or malformed ``transforms.json``, a missing or truncated
image, or a NaN in a pose with an assertion or a traceback deep inside data loading (a truncated
image's error does not even name the file). :func:`check_dataset` reads the same things first --
the transforms file parses and has frames; each frame's image exists and decodes (with Pillow,
through :mod:`stealth_ns.image_io`, as nerfstudio decodes it); each ``transform_matrix`` is 4x4
and finite; the intrinsics are present and finite; the split lists name frames; a
``ply_file_path`` exists -- and raises
:class:`~stealth_ns.errors.StealthNSError` with one line for the first problem. The datamanager
runs it at start-up (``ns-train``) and ``stealth-ns check-data --data DIR`` runs it on demand.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stealth_ns.errors import StealthNSError
from stealth_ns.image_io import image_size, read_image

__all__ = ["DatasetSummary", "check_dataset", "ply_vertex_count", "read_json_object", "transforms_path"]

INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
"""Camera parameters nerfstudio-data needs, globally or in every frame."""
SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class DatasetSummary:
    """What :func:`check_dataset` found; ``str()`` gives a one-paragraph summary."""

    transforms: Path
    n_frames: int
    sizes: tuple[tuple[int, int], ...]
    """The distinct image sizes (width, height)."""
    ply: Path | None
    n_points: int | None
    splits: dict[str, int]

    def __str__(self) -> str:
        sizes = ", ".join(f"{w}x{h}" for w, h in self.sizes)
        splits = ", ".join(f"{n} {name}" for name, n in self.splits.items()) or "no split lists"
        if self.ply is None:
            points = "no seed points (no ply_file_path)"
        else:
            points = f"{self.n_points} seed points in {self.ply.name}"
        return (
            f"Dataset OK: {self.transforms}\n"
            f"  {self.n_frames} frames ({sizes}), {splits}; {points}; "
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


def check_dataset(data: Path, decode: bool = True, downscale_factor: int | None = None) -> DatasetSummary:
    """Check the nerfstudio-data dataset ``data`` (a folder with ``transforms.json`` or the JSON file).

    ``decode``: decode every image (else only its header is read). ``downscale_factor`` > 1:
    an image may also be in ``images_N/`` as nerfstudio's parser looks there. Raises
    :class:`StealthNSError` with one line naming the file and the frame (index and ``file_path``).
    """
    path = transforms_path(data)
    meta = _load(path)
    root = path.parent
    frames = meta["frames"]
    sizes: set[tuple[int, int]] = set()
    names: set[str] = set()
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise StealthNSError(f"{path}: frame {i} is not a JSON object")
        file_path = frame.get("file_path")
        if not isinstance(file_path, str) or not file_path.strip():
            raise StealthNSError(f"{path}: frame {i} has no file_path")
        where = f"{path}: frame {i} ({file_path})"
        matrix = frame.get("transform_matrix")
        if (
            not isinstance(matrix, list)
            or len(matrix) != 4
            or not all(isinstance(row, list) and len(row) == 4 for row in matrix)
        ):
            raise StealthNSError(f"{where}: transform_matrix must be a 4x4 list of numbers")
        bad = [v for row in matrix for v in row if not _finite(v)]
        if bad:
            raise StealthNSError(
                f"{where}: transform_matrix holds a non-finite or non-number value ({bad[0]!r})"
            )
        for key in INTRINSICS:
            value = frame.get(key, meta.get(key))
            if value is None:
                raise StealthNSError(
                    f"{where}: no {key} (camera intrinsics), neither in the frame nor in {path.name}"
                )
            if not _finite(value) or (key not in ("cx", "cy") and value <= 0):
                raise StealthNSError(f"{where}: {key} must be a finite positive number, got {value!r}")
        image = root / file_path
        if downscale_factor is not None and downscale_factor > 1 and not image.exists():
            image = root / f"images_{downscale_factor}" / Path(file_path).name
        sizes.add(_check_image(image, where, decode))
        mask = frame.get("mask_path")
        if mask is not None and not (root / str(mask)).is_file():
            raise StealthNSError(f"{where}: mask {root / str(mask)} does not exist")
        names.add(str(Path(file_path)))
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
    ply, n_points = None, None
    if meta.get("ply_file_path") is not None:
        ply = root / str(meta["ply_file_path"])
        if not ply.is_file():
            raise StealthNSError(
                f"{path}: ply_file_path {ply} (seed points) does not exist; triangulate them with "
                f"`stealth-ns seed-points --data {Path(data)}` or remove ply_file_path"
            )
        n_points = ply_vertex_count(ply)
    return DatasetSummary(
        transforms=path,
        n_frames=len(frames),
        sizes=tuple(sorted(sizes)),
        ply=ply,
        n_points=n_points,
        splits=splits,
    )
