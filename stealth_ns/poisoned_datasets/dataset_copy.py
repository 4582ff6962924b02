"""A poisoned copy of a dataset: the one place that writes one.

The data-only StealthAttack (:mod:`stealth_ns.poisoned_datasets.data_only`) and IPA-Splat
(:mod:`stealth_ns.poisoned_datasets.ipa_splat`) both end the same way: a copy of the user's nerfstudio-data or
COLMAP dataset in which some training images are replaced and (data-only) the seed points have poison
points added, so that any 3DGS trainer can consume it. This module

* checks the input and the output folder (never the input, nor inside it, nor around it; an existing
  output only when it is an earlier poisoned copy and ``overwrite`` is given, and then only the files
  it recorded writing, unchanged, in ``OUTPUT/.stealth-ns-copy.json``: a file the user added there, or
  changed, stops it before anything is removed);
* copies the whole dataset folder, and files it references outside itself (the images of a seeded copy
  made by ``stealth-ns seed-points --output``) into ``external/``, rewriting those references;
* writes replaced images in the file's own format and at its own path (re-reads them and reports how
  far the written pixels are from the intended ones: 0 for PNG, the encoder's error for JPEG);
* appends points to the seed cloud (the transforms' PLY, or COLMAP's ``points3D``), mapping them from
  nerfstudio's normalised frame back into the dataset's own;
* writes the attack record into ``OUTPUT/attack/`` (the same record a poisoned run has), which
  ``stealth-ns report`` and ``bench`` read for a victim trained on the copy.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch

from stealth_ns.attack.record import RECORD_FILE, AttackRecord
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.file_manifest import (
    files_under,
    foreign_files,
    listing,
    read_manifest,
    remove_owned,
    write_manifest,
)
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.images.io import read_image, save_image

if TYPE_CHECKING:
    from stealth_ns.datasets.source import SceneSource

DatasetFormat = Literal["nerfstudio-data", "colmap"]
#: The attack record of a poisoned copy, relative to the copy (as ``<run>/attack`` of a run).
RECORD_DIR = "attack"
#: Files referenced from outside the dataset folder are copied under this folder of the copy.
EXTERNAL_DIR = "external"
#: The copy's record of the files it wrote (:mod:`stealth_ns.foundation.file_manifest`).
FILES_RECORD = ".stealth-ns-copy.json"
WRITTEN_BY = "stealth_ns.poisoning.dataset_copy"
"""The copies' manifest label: the writer's first module path, kept so that copies written before and
after its package was renamed read the same (a label, not an import path)."""
_FRAME_FILE_KEYS = ("file_path", "depth_file_path", "mask_path")
_SPLIT_KEYS = ("train_filenames", "val_filenames", "test_filenames")


@dataclass(frozen=True)
class SourceDataset:
    """A dataset folder to copy, as the bench inspects dataset folders (``inspect_folder``)."""

    scene: SceneSource

    @property
    def root(self) -> Path:
        """The folder, absolute."""
        assert self.scene.path is not None
        return self.scene.path

    @property
    def format(self) -> DatasetFormat:
        assert self.scene.format in ("nerfstudio-data", "colmap")
        return self.scene.format

    @property
    def colmap_path(self) -> str | None:
        """The COLMAP model folder, relative to :attr:`root`."""
        return self.scene.colmap_path

    @property
    def has_seed_points(self) -> bool:
        return self.scene.seed_points != "triangulated"

    @property
    def dataparser(self) -> tuple[str, tuple[str, ...]]:
        """nerfstudio's dataparser name and its options after ``--data`` for this dataset."""
        return self.scene.dataparser


def open_source(data: Path) -> SourceDataset:
    """The dataset at ``data`` (StealthNSError with one line for a missing folder or another format)."""
    from stealth_ns.datasets.source import inspect_folder

    src = inspect_folder("--data", str(data))
    if src.format == "blender":
        raise StealthNSError(
            f"{data} is a Blender dataset: poisoned copies are written for nerfstudio-data and COLMAP "
            f"datasets; convert it with `stealth-ns seed-points --data {data} --output DIR` and poison DIR"
        )
    return SourceDataset(src)


def is_poisoned_copy(folder: Path) -> bool:
    """Whether ``folder`` is a poisoned copy written by stealth-ns (its record says so)."""
    try:
        data = json.loads((folder / RECORD_DIR / RECORD_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and isinstance(data.get("poisoned_dataset"), dict)


def check_output(source: SourceDataset, output: Path, overwrite: bool) -> Path:
    """The absolute output folder, after refusing one that would write into the input or lose data."""
    out = Path(os.path.abspath(Path(output).expanduser()))
    root = source.root
    # compared as written and with symbolic links resolved: a link must not lead --overwrite to the input
    for o, r in ((out, root), (out.resolve(), root.resolve())):
        if o == r or o.is_relative_to(r):
            raise StealthNSError(
                f"--output {output} is inside the input dataset {root}: the input is never written"
            )
        if r.is_relative_to(o):
            raise StealthNSError(f"--output {output} contains the input dataset {root}: give another folder")
    if out.exists() and not out.is_dir():
        raise StealthNSError(f"--output {output} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise StealthNSError(
                f"--output {output} is not empty; give a new folder (or --overwrite to replace an earlier "
                "poisoned copy)"
            )
        if not is_poisoned_copy(out):
            raise StealthNSError(
                f"--output {output} is not empty and is not a poisoned copy written by stealth-ns: "
                "--overwrite replaces only those"
            )
        foreign = foreign_files(out, read_manifest(out / FILES_RECORD), _present(out))
        if foreign:
            raise StealthNSError(
                f"--output {output} holds files stealth-ns did not write there, or changed since (not in "
                f"{FILES_RECORD}): {listing(foreign)}; --overwrite replaces only its own "
                "files: move these away or give another folder"
            )
    return out


def _present(out: Path) -> list[str]:
    """The files of an earlier copy at ``out`` (relative), its file record left out."""
    return [f for f in files_under(out) if f != FILES_RECORD]


@dataclass
class PoisonedCopy:
    """A poisoned copy being written: where each source file went, what was changed."""

    source: SourceDataset
    root: Path
    moved: dict[Path, Path] = field(default_factory=dict)  # absolute source file outside root -> copy
    images: dict[str, dict[str, Any]] = field(default_factory=dict)  # view name -> what was written
    seed_points_added: int = 0

    def path_of(self, source_file: Path) -> Path:
        """The copy of a file of the source dataset (as nerfstudio's dataparser named it)."""
        path = Path(os.path.abspath(source_file))
        if path in self.moved:
            return self.moved[path]
        if path.is_relative_to(self.source.root):
            return self.root / path.relative_to(self.source.root)
        raise StealthNSError(f"{source_file} is not a file of the dataset {self.source.root}")

    def write_image(self, name: str, source_file: Path, image: np.ndarray, change: str) -> None:
        """Replace a training image of the copy by ``image`` (uint8 ``[H, W, C]``, C as the file had),
        in the file's own format; records the largest difference (0-255) between the pixels written
        and those intended (0 for PNG)."""
        path = self.path_of(source_file)
        save_image(path, image)
        error = max_abs_difference(read_image(path, f"written image {path}"), image)
        self.images[name] = {
            "file": str(path.relative_to(self.root)),
            "change": change,
            "encode_error_255": error,
        }

    def write_training_image(
        self, name: str, outputs: Any, index: int, image: np.ndarray, clean: np.ndarray, change: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """Replace training view ``index`` of the source's dataparser ``outputs``, whose poisoned and
        clean versions in nerfstudio's training frame are ``image`` and ``clean`` (uint8 ``[h, w, C]``).
        With lens distortion the file gets its own pixels plus the change mapped back onto them
        (:mod:`stealth_ns.poisoned_datasets.distortion`). Returns (pixels written, the source's pixels), both
        in the file's frame."""
        from stealth_ns.poisoned_datasets.distortion import camera_distortion, change_in_source_frame

        source_file = outputs.image_filenames[index]
        lens = camera_distortion(outputs.cameras, index)
        if lens is None:
            self.write_image(name, source_file, image, change)
            return image, clean

        original = read_image(source_file, f"training image {source_file}")
        delta = change_in_source_frame(image.astype(np.float32) - clean.astype(np.float32), *lens)
        written = original.astype(np.float32).reshape(*original.shape[:2], -1)
        channels = min(written.shape[-1], delta.shape[-1])  # an RGB change on an RGBA file: colour only
        written[..., :channels] += delta[..., :channels]
        written = np.clip(np.rint(written), 0, 255).astype(np.uint8).reshape(original.shape)
        self.write_image(name, source_file, written, change + " (mapped back through the lens distortion)")
        return written, original


def max_abs_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest absolute difference between two uint8 images of one shape, on the 0-255 scale."""
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).max())


def copy_dataset(source: SourceDataset, output: Path, overwrite: bool = False) -> PoisonedCopy:
    """Copy ``source`` into ``output`` (checked by :func:`check_output`); files the dataset references
    outside its folder are copied into ``output/external`` and the references rewritten."""
    out = check_output(source, output, overwrite)
    _check_source(source)  # a file named outside the dataset is refused before anything is written
    if out.exists():  # an earlier copy, holding nothing but what stealth-ns wrote (check_output)
        remove_owned(out, read_manifest(out / FILES_RECORD), _present(out))
    try:
        out.mkdir(parents=True, exist_ok=True)
        # recorded first: a copy cut short is still a copy --overwrite may replace, and nothing else
        planned = [f for f in files_under(source.root) if f != FILES_RECORD] + [f"{RECORD_DIR}/{RECORD_FILE}"]
        write_manifest(out / FILES_RECORD, out, planned, WRITTEN_BY, False, (RECORD_DIR, EXTERNAL_DIR))
        left_out = _LinksOut(source)
        shutil.copytree(source.root, out, symlinks=False, dirs_exist_ok=True, ignore=left_out)
    except OSError as err:
        raise StealthNSError(f"cannot copy {source.root} to {out}: {err.strerror or err}") from None
    # marks the folder as a poisoned copy from now on (so --overwrite may replace an unfinished one);
    # write_record replaces it with the full record at the end
    (out / RECORD_DIR).mkdir(exist_ok=True)
    write_json_atomic(out / RECORD_DIR / RECORD_FILE, {"poisoned_dataset": {"complete": False}})
    copy = PoisonedCopy(source, out)
    if left_out.links:
        print(f"left out of the copy: {len(left_out.links)} symbolic link(s) to files outside the dataset "
              f"that it does not use ({', '.join(left_out.links[:3])})", flush=True)  # fmt: skip
    if source.format == "nerfstudio-data":
        _internalise_references(copy)
    return copy


class _LinksOut:
    """``copytree``'s ``ignore``: leaves out the record of an earlier copy (the source may be one) and
    symbolic links that lead out of the dataset to files it does not name (a copy made to be shared
    must not carry ``secret -> ~/.ssh/id_rsa``); the names it left out are kept in :attr:`links`."""

    def __init__(self, source: SourceDataset) -> None:
        self.root, self.real_root = source.root, Path(os.path.realpath(source.root))
        self.used = _named_files(source)
        self.links: list[str] = []

    def __call__(self, folder: str, names: list[str]) -> list[str]:
        skip = [FILES_RECORD] if Path(folder) == self.root and FILES_RECORD in names else []
        for name in names:
            path = Path(folder) / name
            if not path.is_symlink() or Path(os.path.realpath(path)).is_relative_to(self.real_root):
                continue
            if not any(used == path or used.is_relative_to(path) for used in self.used):
                skip.append(name)
                self.links.append(path.relative_to(self.root).as_posix())
        return skip


def _named_files(source: SourceDataset) -> set[Path]:
    """The files a nerfstudio-data source's transforms.json names (absolute, links not resolved); a
    COLMAP model's images are checked to lie inside its folder with links resolved (empty set)."""
    if source.format != "nerfstudio-data":
        return set()
    meta = json.loads((source.root / "transforms.json").read_text(encoding="utf-8"))
    values = [meta.get(k) for k in ("ply_file_path", "mask_path")]
    for frame in meta.get("frames", []):
        values += [frame.get(k) for k in _FRAME_FILE_KEYS] if isinstance(frame, dict) else []
    return {Path(os.path.abspath(source.root / v)) for v in values if isinstance(v, str)}


def _check_source(source: SourceDataset) -> None:
    """check-data's path rules (:mod:`stealth_ns.datasets.check`): no file the dataset names leaves its
    folder, except the images and depths of the dataset a seeded copy was made from (a COLMAP model's
    image names are read by its whole check, images not decoded)."""
    from stealth_ns.datasets.check import check_colmap, check_references, read_json_object, transforms_path

    if source.format == "colmap":
        check_colmap(source.root, str(source.colmap_path), decode=False)
    else:
        path = transforms_path(source.root)
        check_references(path, read_json_object(path))


def _internalise_references(copy: PoisonedCopy) -> None:
    """Make a nerfstudio-data copy self-contained: files its transforms.json names outside the dataset
    folder are copied into ``external/`` and the paths rewritten (relative to the copy), as are absolute
    paths into the folder (they named the input's files, not the copy's).

    Every reference was checked before the copy was written (:func:`_check_source`): a file outside the
    folder is one another dataset declares as its own -- the images of a seeded copy made by
    ``stealth-ns seed-points --output`` -- never ``../../etc/passwd`` nor a ``ply_file_path`` elsewhere.
    """
    path = copy.root / "transforms.json"
    text = path.read_text(encoding="utf-8")
    meta = json.loads(text)
    renamed: dict[Path, str] = {}  # a frame's path as nerfstudio matches it -> its path in the copy
    for frame in meta.get("frames", []):
        for key in _FRAME_FILE_KEYS:
            if isinstance(frame.get(key), str):
                new = _internal_reference(copy, frame[key])
                renamed[Path(frame[key])] = new
                frame[key] = new
    for key in ("ply_file_path", "mask_path"):
        if isinstance(meta.get(key), str):
            meta[key] = _internal_reference(copy, meta[key])
    for key in _SPLIT_KEYS:  # nerfstudio matches these against the frames' paths
        if isinstance(meta.get(key), list):
            meta[key] = [renamed.get(Path(v), v) if isinstance(v, str) else v for v in meta[key]]
    if meta != json.loads(text):  # an unchanged file stays byte for byte the input's
        write_json_atomic(path, meta)


def _internal_reference(copy: PoisonedCopy, value: str) -> str:
    """``value`` (a path in the source's transforms.json, checked) as a path relative to the copy: a file
    of the folder by its relative path, one outside it (links resolved) copied under ``external/``."""
    root = copy.source.root
    source = Path(os.path.abspath(root / value))
    if source.is_relative_to(root):
        return value if not os.path.isabs(value) else source.relative_to(root).as_posix()
    real, real_root = Path(os.path.realpath(source)), Path(os.path.realpath(root))
    if real.is_relative_to(real_root):  # reached from outside, through a link to the folder
        copy.moved[source] = copy.root / real.relative_to(real_root)
    elif source not in copy.moved:
        taken = set(copy.moved.values())
        folder, k = source.parent.name, 1
        while (target := copy.root / EXTERNAL_DIR / folder / source.name) in taken:
            k += 1  # another folder of that name: never overwrite a file copied before
            folder = f"{source.parent.name}_{k}"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target)
        copy.moved[source] = target
    return copy.moved[source].relative_to(copy.root).as_posix()


# ---------------------------------------------------------------------------------- seed points
def to_dataset_frame(points: torch.Tensor | np.ndarray, outputs: Any, source: SourceDataset) -> np.ndarray:
    """[M, 3] points in nerfstudio's normalised frame -> the frame of the dataset's seed points (the
    inverse of :func:`stealth_ns.datasets.frames.dataset_to_nerfstudio`)."""
    from stealth_ns.datasets.frames import dataset_to_nerfstudio

    m = dataset_to_nerfstudio(outputs, source.scene)
    p = np.asarray(points, dtype=np.float64)
    homo = np.concatenate([p, np.ones((len(p), 1))], axis=1)
    return (homo @ np.linalg.inv(m).T)[:, :3]


def append_seed_points(copy: PoisonedCopy, xyz: np.ndarray, rgb: np.ndarray) -> Path:
    """Add points (``xyz`` [M, 3] in the dataset's frame, ``rgb`` [M, 3] uint8) to the copy's seed cloud;
    returns the file written."""
    if copy.source.format == "colmap":
        path = _append_colmap_points(copy.root / str(copy.source.colmap_path), xyz, rgb)
    else:
        path = _append_ply_points(copy.root, xyz, rgb)
    copy.seed_points_added += len(xyz)
    return path


def _append_ply_points(root: Path, xyz: np.ndarray, rgb: np.ndarray) -> Path:
    import open3d as o3d

    from stealth_ns.scene_generator.writer import write_ply

    meta = json.loads((root / "transforms.json").read_text(encoding="utf-8"))
    ply = meta.get("ply_file_path")
    if not isinstance(ply, str):
        raise StealthNSError(f"{root / 'transforms.json'} names no seed points (ply_file_path)")
    path = root / ply
    cloud = o3d.io.read_point_cloud(str(path))
    old_xyz = np.asarray(cloud.points, dtype=np.float64)
    old_rgb = (np.asarray(cloud.colors) * 255).round().astype(np.uint8) if cloud.has_colors() else None
    if old_rgb is None:
        old_rgb = np.full((len(old_xyz), 3), 128, dtype=np.uint8)
    write_ply(path, np.concatenate([old_xyz, xyz]), np.concatenate([old_rgb, rgb.astype(np.uint8)]))
    return path


def _append_colmap_points(model: Path, xyz: np.ndarray, rgb: np.ndarray) -> Path:
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    for p, c in zip(np.asarray(xyz, dtype=np.float64), np.asarray(rgb, dtype=np.uint8), strict=True):
        rec.add_point3D(p, pycolmap.Track(), c)
    if (model / "points3D.bin").is_file():
        rec.write_binary(str(model))
        return model / "points3D.bin"
    rec.write_text(str(model))
    return model / "points3D.txt"


# ---------------------------------------------------------------------------------- the record
def write_record(copy: PoisonedCopy, record: AttackRecord, details: dict[str, Any]) -> Path:
    """Write the copy's attack record (``OUTPUT/attack``), with ``details`` and the images written
    under its ``poisoned_dataset`` key; returns the record folder."""
    record.poisoned_dataset = {
        **details,
        "source": str(copy.source.root),
        "format": copy.source.format,
        "images_written": copy.images,
        "seed_points_added": copy.seed_points_added,
        "complete": True,
    }
    folder = copy.root / RECORD_DIR
    record.write(folder, views=True)
    # the copy is complete: every file of it recorded with its hash (--overwrite removes only those)
    write_manifest(copy.root / FILES_RECORD, copy.root, _present(copy.root), WRITTEN_BY, True)
    return folder
