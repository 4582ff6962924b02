"""Which files a dataset's transforms file may name: those inside its folder (links resolved), or a
file another dataset on this machine declares (a seeded copy names its source's images).

Split out of :mod:`stealth_ns.datasets.check`, which re-exports :func:`check_references` and
:func:`read_json_object`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from stealth_ns.foundation.errors import StealthNSError

__all__ = [
    "FRAME_FILE_KEYS", "Origins", "check_frame_references", "check_reference", "check_references",
    "leaves", "read_json_object", "real_path",
]  # fmt: skip

FRAME_FILE_KEYS = ("file_path", "depth_file_path", "mask_path")  # a frame's files
_ORIGIN_FILES = ("transforms.json", "transforms_train.json", "transforms_val.json", "transforms_test.json")


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


def real_path(path: Path) -> Path:
    """``path`` with every link resolved."""
    return Path(os.path.realpath(path))


class Origins:
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
                        files[key].add(real_path(transforms.parent / value))
            self._declared[transforms] = files
        return self._declared[transforms]


def check_reference(root: Path, value: Any, where: str, key: str, origins: Origins | None) -> None:
    """StealthNSError unless ``root / value`` is inside ``root`` (links resolved) or, with ``origins``,
    a file another dataset declares under ``key``."""
    if not isinstance(value, str) or not value.strip():
        raise StealthNSError(f"{where}: {key} must be a file path (a non-empty string), got {value!r}")
    how = leaves(root, root / value)
    if how is not None and not (origins is not None and origins.declares(real_path(root / value), key)):
        raise StealthNSError(f"{where}: {key} {value!r} leaves the dataset folder {root}{how}")


def leaves(root: Path, path: Path) -> str | None:
    """None when ``path`` is inside ``root`` with links resolved, else how it leaves (a link or not)."""
    real = real_path(path)
    if real.is_relative_to(real_path(root)):
        return None
    lexical = Path(os.path.normpath(os.path.abspath(path)))
    return f" (a symbolic link to {real})" if lexical.is_relative_to(os.path.abspath(root)) else ""


def check_frame_references(path: Path, i: int, frame: dict[str, Any], origins: Origins) -> None:
    for key in FRAME_FILE_KEYS:
        if key in frame:
            where = f"{path}: frame {i}" + ("" if key == "file_path" else f" ({frame.get('file_path')})")
            check_reference(path.parent, frame[key], where, key, origins)


def check_references(path: Path, meta: dict[str, Any]) -> None:
    """StealthNSError with one line for the first file the transforms file ``path`` (holding ``meta``)
    names outside its folder: a frame's ``file_path``, ``depth_file_path`` or ``mask_path`` (unless
    another dataset declares it, see :class:`Origins`), the ``ply_file_path`` or a top-level
    ``mask_path`` (always inside). Links are resolved before comparing."""
    origins = Origins()
    frames = meta.get("frames")
    for i, frame in enumerate(frames if isinstance(frames, list) else []):
        if isinstance(frame, dict):
            check_frame_references(path, i, frame, origins)
    for key in ("ply_file_path", "mask_path"):
        if meta.get(key) is not None:
            check_reference(path.parent, meta[key], str(path), key, None)
