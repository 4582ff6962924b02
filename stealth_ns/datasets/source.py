"""What a dataset folder holds: its format (nerfstudio-data, COLMAP, Blender), where its seed points
come from, and the content hash that identifies it. A folder is read, never written.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.fingerprint import file_sha256

FolderFormat = Literal["nerfstudio-data", "colmap", "blender"]


#: Where a COLMAP folder's model may be, relative to the folder (nerfstudio's default second).
COLMAP_DIRS: tuple[str, ...] = ("sparse/0", "colmap/sparse/0", "sparse")
#: How deep :func:`colmap_models` looks for a model elsewhere in a folder.
COLMAP_SEARCH_DEPTH = 4


def holds_colmap_model(path: Path) -> bool:
    """Whether the folder ``path`` holds a COLMAP model (``cameras.bin`` or ``cameras.txt``)."""
    return any((Path(path) / f"cameras.{ext}").is_file() for ext in ("bin", "txt"))


def colmap_models(folder: Path) -> list[str]:
    """The folders of ``folder`` holding a COLMAP model (:func:`holds_colmap_model`), relative and
    "/"-separated: those of :data:`COLMAP_DIRS` first, then any other up to
    :data:`COLMAP_SEARCH_DEPTH` levels down (hidden folders and links to folders skipped), by name."""
    found = [rel for rel in COLMAP_DIRS if holds_colmap_model(folder / rel)]
    others = []
    for top, dirs, _ in os.walk(folder):
        depth = len(Path(top).relative_to(folder).parts)
        dirs[:] = [] if depth >= COLMAP_SEARCH_DEPTH else sorted(d for d in dirs if not d.startswith("."))
        rel = Path(top).relative_to(folder).as_posix()
        if rel not in found and holds_colmap_model(Path(top)):
            others.append(rel)
    return found + sorted(others)


@dataclass(frozen=True)
class SceneSource:
    """A scene of ``--scenes``: a generated preset, or a dataset folder (used in place, never written)."""

    name: str
    path: Path | None = None
    """The dataset folder (absolute); None for a preset."""
    given: str = ""
    """The folder as given on the command line."""
    format: FolderFormat | None = None
    seed_points: Literal["generated", "ply_file_path", "colmap", "triangulated"] = "generated"
    """Where the seed points come from: a preset's generator, the transforms.json's
    ``ply_file_path``, the COLMAP model's points3D, or
    :func:`stealth_ns.datasets.seed_points.make_seed_points` (a seeded copy in ``OUTPUT/scenes/NAME`` that
    references the folder's images)."""
    colmap_path: str | None = None
    """The COLMAP model folder, relative to ``path``."""
    files: tuple[tuple[str, str], ...] = ()
    """``(relative path, sha256)`` of the files that define the dataset (transforms.json, the COLMAP
    model); their hash :attr:`sha256` identifies it."""
    views: int | None = None
    """Frames, as the dataset check counted them (None: not checked)."""
    sizes: tuple[tuple[int, int], ...] = ()
    """Distinct image sizes (width, height), as the dataset check read them (empty: not checked)."""

    @property
    def is_preset(self) -> bool:
        return self.path is None

    @property
    def triangulated(self) -> bool:
        """The dataset has no seed points: the bench makes them first."""
        return self.seed_points == "triangulated"

    @property
    def sha256(self) -> str:
        """The content hash of the dataset: the sha256 of its transforms.json when that is the only
        file, else of the ``sha256sum``-style listing of :attr:`files`."""
        if len(self.files) == 1:
            return self.files[0][1]
        return hashlib.sha256("".join(f"{h}  {rel}\n" for rel, h in self.files).encode()).hexdigest()

    @property
    def dataparser(self) -> tuple[str, tuple[str, ...]]:
        """The nerfstudio dataparser and its options after ``--data``."""
        if self.format == "colmap":
            # --downscale-factor 1: nerfstudio would otherwise offer (interactively) to write
            # downscaled images_N folders into the dataset for images over 1600 px
            return "colmap", ("--colmap-path", str(self.colmap_path), "--downscale-factor", "1")
        return "nerfstudio-data", ()

    @property
    def train_args(self) -> tuple[str, ...]:
        """Method options the dataset needs: a Blender scene's RGBA images on white, as NeRF-synthetic."""
        return ("--pipeline.model.background-color", "white") if self.format == "blender" else ()

    def describe(self) -> str:
        if self.is_preset:
            return "generated preset"
        where = {
            "ply_file_path": "seed points from its ply_file_path",
            "colmap": f"seed points from the COLMAP model {self.colmap_path}",
            "triangulated": "no seed points",
        }[self.seed_points]
        return f"{self.format}, {where}; used in place, never written"


def _hashes(root: Path, rels: Sequence[str]) -> tuple[tuple[str, str], ...]:
    try:
        return tuple((rel, file_sha256(root / rel)) for rel in rels)
    except OSError as err:
        raise StealthNSError(f"cannot read {root}: {err.strerror or err}") from None


def inspect_folder(name: str, folder: str) -> SceneSource:
    """The :class:`SceneSource` of a dataset folder, by its format (StealthNSError if none fits).

    ``transforms.json`` -> nerfstudio-data (its ``ply_file_path`` gives the seed points, else they
    are triangulated); ``sparse/0`` (or ``colmap/sparse/0``, ``sparse``) with ``images/`` -> COLMAP;
    ``transforms_train.json`` -> Blender (converted with triangulated seed points).
    """
    path = Path(os.path.abspath(Path(folder).expanduser()))  # absolute, ".." folded
    if not path.exists():
        raise StealthNSError(f"scene {name}: {folder} not found")
    if not path.is_dir():
        raise StealthNSError(f"scene {name}: {folder} is not a folder (give the dataset folder)")
    transforms = path / "transforms.json"
    if transforms.is_file():
        try:
            meta = json.loads(transforms.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as err:
            raise StealthNSError(f"scene {name}: cannot read {transforms}: {err}") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
            raise StealthNSError(
                f"scene {name}: {transforms} is not a nerfstudio transforms.json (no frames)"
            )
        ply = meta.get("ply_file_path")
        if ply and not (path / str(ply)).is_file():
            raise StealthNSError(f"scene {name}: the ply_file_path {ply!r} of {transforms} does not exist")
        seed = "ply_file_path" if ply else "triangulated"
        return SceneSource(
            name, path, folder, "nerfstudio-data", seed, files=_hashes(path, ["transforms.json"])
        )
    for rel in COLMAP_DIRS:
        model = path / rel
        if not holds_colmap_model(model):
            continue
        if not (path / "images").is_dir():
            raise StealthNSError(f"scene {name}: {folder} has a COLMAP model in {rel} but no images/ folder")
        if not any((model / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
            raise StealthNSError(f"scene {name}: the COLMAP model {model} has no points3D (the seed points)")
        rels = sorted(f"{rel}/{f.name}" for f in model.iterdir() if f.is_file())
        return SceneSource(name, path, folder, "colmap", "colmap", rel, files=_hashes(path, rels))
    if (path / "transforms_train.json").is_file():
        rels = [
            f"transforms_{s}.json"
            for s in ("train", "val", "test")
            if (path / f"transforms_{s}.json").is_file()
        ]
        return SceneSource(name, path, folder, "blender", "triangulated", files=_hashes(path, rels))
    raise StealthNSError(
        f"scene {name}: unknown dataset format in {folder}: no transforms.json (nerfstudio-data), "
        f"{' / '.join(COLMAP_DIRS)} with images/ (COLMAP) or transforms_train.json (Blender)"
    )
