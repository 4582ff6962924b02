"""Seed points for known-pose captures: triangulate SIFT matches with the dataset's own poses.

Real known-pose captures (instant-ngp / nerfstudio ``transforms.json``, NeRF-synthetic / Blender
``transforms_train.json``) carry camera poses but no SfM point cloud. :func:`make_seed_points`
(``stealth-ns seed-points``) runs pycolmap on the images with the poses and intrinsics held
fixed -- SIFT features, exhaustive matching with two-view verification, triangulation with
bundle adjustment of the points only -- and writes the points as ``sparse_pc.ply`` plus a
nerfstudio-data transforms file whose ``ply_file_path`` names it. Conventions and where the files
go: ``docs/design/seed_points.md``.

Conventions: a transforms file's ``transform_matrix`` is OpenGL camera-to-world (camera looks down
-Z, +Y up); COLMAP wants OpenCV world-to-camera (+Z forward, +Y down), so the camera frame's Y and
Z axes are flipped and the matrix inverted. The points are written in the frame of the transforms
file's poses: nerfstudio's parser maps a PLY with the same ``transform_matrix`` (recentring and
scaling) as the poses; ``applied_transform`` concerns the poses' *origin* frame and does not apply.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.datasets.check import read_json_object
from stealth_ns.datasets.triangulation import Camera, Frame, triangulate
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import image_size
from stealth_ns.scene_generator.writer import write_ply

__all__ = ["SeedPointsSummary", "make_seed_points"]

SEEDED_JSON = "transforms_seeded.json"
"""Name of the copy of the transforms file written beside the original (default mode)."""
PLY_NAME = "sparse_pc.ply"
"""Preferred name of the written PLY."""
BLENDER_SPLITS = ("train", "val", "test")
POSE_MISFIT_PX = 3.0
"""Median distance (px) of verified matches to the given poses' epipolar lines above which the poses are
said not to fit the images. Measured on the generated orbit scene (128x96, 14 views): 0.16 px with
its poses, 8.9 px with the same poses shuffled among the frames; the real capture fox (50 views): 0.20 px."""


@dataclass(frozen=True)
class SeedPointsSummary:
    """What :func:`make_seed_points` wrote; ``str()`` gives a short human summary."""

    dataset: Path
    """What to pass to ``nerfstudio-data --data``: a folder or a transforms JSON file."""
    ply: Path
    """The written PLY."""
    n_points: int
    n_images: int
    """Images the points were triangulated from."""
    seconds: float
    mean_error_px: float = float("nan")
    """Mean reprojection error of the kept points, pixels."""
    n_triangulated: int = 0
    """Points COLMAP triangulated before the track-length / error filter and ``max_points``."""
    blender: bool = False
    """The input was a Blender-format folder (RGBA images, transparent background)."""
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def train_command(self) -> str:
        bg = " --pipeline.model.background-color white" if self.blender else ""
        return f"ns-train stealth-splat-lite --vis tensorboard{bg} nerfstudio-data --data {self.dataset}"

    def __str__(self) -> str:
        lines = [
            f"Seed points: {self.n_points} points from {self.n_images} images "
            f"(mean reprojection error {self.mean_error_px:.2f} px), {self.seconds:.1f} s",
            f"  points:  {self.ply}",
            f"  dataset: {self.dataset}",
            *(f"  {note}" for note in self.notes),
            "Train on it with:",
            f"  {self.train_command}",
        ]
        return "\n".join(lines)


@dataclass
class _Dataset:
    """A parsed dataset: ``meta`` is a nerfstudio-data transforms dict (converted for Blender)
    whose relative paths are relative to ``root``; ``frames`` are the views to triangulate from."""

    root: Path
    transforms: Path | None
    meta: dict[str, Any]
    frames: list[Frame]
    n_frames: int
    blender: bool


def make_seed_points(
    data: Path,
    output: Path | None = None,
    overwrite: bool = False,
    max_points: int | None = None,
    seed: int = 0,
    min_views: int = 3,
    max_error: float = 2.0,
) -> SeedPointsSummary:
    """Triangulate seed points for the known-pose dataset ``data`` and write them as a PLY.

    ``data``: a nerfstudio-data folder (``transforms.json``), a transforms JSON file, or a Blender
    folder (``transforms_train.json``). Without ``output`` the PLY and a copy of the transforms
    file with ``ply_file_path`` (``transforms_seeded.json``) go beside the data; with ``overwrite``
    the transforms file itself is updated instead. With ``output`` (another folder),
    ``output/transforms.json`` (image paths pointing back to ``data``) and ``output/sparse_pc.ply``
    are written. Points must be seen in ``min_views`` images with a mean reprojection error of at
    most ``max_error`` pixels; ``max_points`` keeps a random (``seed``) subset. The same input gives
    the same PLY. Raises :class:`StealthNSError` with a one-line message for bad input.
    """
    t0 = time.perf_counter()
    if max_points is not None and (isinstance(max_points, bool) or int(max_points) < 1):
        raise StealthNSError(f"max_points must be a positive integer (got {max_points!r})")
    if isinstance(seed, bool) or int(seed) < 0:
        raise StealthNSError(f"seed must be a non-negative integer (got {seed!r})")
    if int(min_views) < 2:
        raise StealthNSError(f"min_views must be at least 2 (got {min_views!r})")
    if not max_error > 0:
        raise StealthNSError(f"max_error must be positive, in pixels (got {max_error!r})")

    ds = _load_dataset(Path(data).expanduser().absolute())
    plan = _plan_outputs(ds, None if output is None else Path(output).expanduser().absolute(), overwrite)
    print(
        f"seed-points: {len(ds.frames)} of {ds.n_frames} frames used for triangulation"
        + (" (the training split)" if len(ds.frames) < ds.n_frames else "")
    )
    points, stats = triangulate(ds.frames, seed=int(seed))
    _check_poses_fit(ds, stats)

    n_triangulated = int(points.xyz.shape[0])
    keep = (points.track >= int(min_views)) & (points.error <= float(max_error))
    n_kept = int(keep.sum())
    print(
        f"filter: {n_kept} of {n_triangulated} points seen in >= {min_views} images "
        f"with reprojection error <= {max_error:g} px"
    )
    if n_kept == 0:
        if n_triangulated == 0:
            raise StealthNSError(
                f"triangulation gave no points: only {stats['inliers']} verified matches in "
                f"{stats['pairs']} image pairs ({stats['keypoints']} SIFT features in {len(ds.frames)} "
                "images), too few matches; use higher-resolution images or more overlapping views"
            )
        two = int(((points.track >= 2) & (points.error <= float(max_error))).sum())
        raise StealthNSError(
            f"none of the {n_triangulated} triangulated points is seen in >= {min_views} images with "
            f"error <= {max_error:g} px ({two} are with >= 2 images): try --min-views 2, a larger "
            "--max-error, or higher-resolution images"
        )
    xyz, rgb, err = points.xyz[keep], points.rgb[keep], points.error[keep]
    if max_points is not None and xyz.shape[0] > int(max_points):
        idx = np.sort(np.random.default_rng(int(seed)).choice(xyz.shape[0], int(max_points), replace=False))
        xyz, rgb, err = xyz[idx], rgb[idx], err[idx]
        print(f"max_points: kept a random {xyz.shape[0]} of {n_kept} points (seed {seed})")

    _write_outputs(ds, plan, xyz, rgb)
    notes = list(plan.notes)
    if xyz.shape[0] < 100:
        notes.append(f"only {xyz.shape[0]} points: higher-resolution images or --min-views 2 would give more")
    return SeedPointsSummary(
        dataset=plan.dataset,
        ply=plan.ply,
        n_points=int(xyz.shape[0]),
        n_images=len(ds.frames),
        seconds=time.perf_counter() - t0,
        mean_error_px=float(err.mean()),
        n_triangulated=n_triangulated,
        blender=ds.blender,
        notes=tuple(notes),
    )


def _load_dataset(data: Path) -> _Dataset:
    """Parse ``data`` (folder or transforms JSON) into a :class:`_Dataset`."""
    if not data.exists():
        raise StealthNSError(f"dataset {data} does not exist")
    if data.is_file():
        if data.suffix.lower() != ".json":
            raise StealthNSError(f"{data} is neither a folder nor a transforms JSON file")
        return _load_nerfstudio(data)
    if (data / "transforms.json").is_file():
        return _load_nerfstudio(data / "transforms.json")
    if (data / "transforms_train.json").is_file():
        return _load_blender(data)
    raise StealthNSError(
        f"{data} has no transforms.json (nerfstudio-data) nor transforms_train.json (Blender format)"
    )


def _get(meta: dict, frame: dict, key: str, where: str) -> Any:
    """nerfstudio's rule: a top-level value wins over the frame's."""
    if key in meta:
        return meta[key]
    if key in frame:
        return frame[key]
    raise StealthNSError(f"{where}: no {key!r} (neither at the top level nor in the frame)")


def _camera(model: str, w: int, h: int, fx: float, fy: float, cx: float, cy: float, dist, where: str):
    """COLMAP camera for nerfstudio intrinsics; ``dist`` is nerfstudio's [k1, k2, k3, k4, p1, p2]."""
    k1, k2, k3, k4, p1, p2 = (float(v) for v in dist)
    values = [fx, fy, cx, cy, k1, k2, k3, k4, p1, p2]
    if not all(math.isfinite(v) for v in values) or w <= 0 or h <= 0 or fx <= 0 or fy <= 0:
        raise StealthNSError(f"{where}: invalid intrinsics (fl_x {fx}, fl_y {fy}, cx {cx}, cy {cy}, {w}x{h})")
    if model == "OPENCV_FISHEYE":
        return Camera("OPENCV_FISHEYE", w, h, (fx, fy, cx, cy, k1, k2, k3, k4))
    if model not in ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"):
        raise StealthNSError(
            f"{where}: camera_model {model!r} is not supported (PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, "
            "OPENCV_FISHEYE are)"
        )
    # nerfstudio treats all of these as one perspective model: radial k1..k4 (r^2..r^8), tangential p1, p2
    if k4 != 0.0:
        raise StealthNSError(f"{where}: radial distortion k4 (r^8) has no COLMAP equivalent")
    if k1 == k2 == k3 == p1 == p2 == 0.0:
        return Camera("PINHOLE", w, h, (fx, fy, cx, cy))
    if k3 == 0.0:
        return Camera("OPENCV", w, h, (fx, fy, cx, cy, k1, k2, p1, p2))
    return Camera("FULL_OPENCV", w, h, (fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0))


def _distortion(src: dict) -> list[float]:
    """nerfstudio's distortion list [k1, k2, k3, k4, p1, p2] from ``distortion_params`` or the keys."""
    if "distortion_params" in src:
        vals = [float(v) for v in src["distortion_params"]]
        return (vals + [0.0] * 6)[:6]
    return [float(src.get(k, 0.0)) for k in ("k1", "k2", "k3", "k4", "p1", "p2")]


def _pose(frame: dict, where: str) -> np.ndarray:
    """The frame's ``transform_matrix`` as a checked 4x4 float64 camera-to-world (OpenGL)."""
    if "transform_matrix" not in frame:
        raise StealthNSError(f"{where}: no transform_matrix")
    try:
        m = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        raise StealthNSError(f"{where}: transform_matrix is not a matrix of numbers") from None
    if m.shape not in ((4, 4), (3, 4)):
        raise StealthNSError(f"{where}: transform_matrix must be 4x4 or 3x4 (got shape {m.shape})")
    if not np.isfinite(m).all():
        raise StealthNSError(f"{where}: transform_matrix contains NaN or infinity")
    c2w = np.eye(4)
    c2w[:3] = m[:3]
    rot = c2w[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-2 or np.linalg.det(rot) <= 0:
        raise StealthNSError(f"{where}: the rotation part of transform_matrix is not a rotation")
    u, _, vt = np.linalg.svd(rot)
    c2w[:3, :3] = u @ vt
    return c2w


def _image_file(root: Path, file_path: str, where: str, blender: bool) -> Path:
    path = root / file_path
    if blender and not path.suffix:
        path = path.with_name(path.name + ".png")
    if not path.is_file():
        raise StealthNSError(f"{where}: image {path} does not exist")
    return path


def _selected(meta: dict, root: Path, frames: list[Frame]) -> list[Frame]:
    """The training split (``train_filenames``) where the file declares one, else all frames."""
    if "train_filenames" not in meta:
        return frames
    names = {os.path.normpath(root / f) for f in meta["train_filenames"]}
    chosen = [f for f in frames if os.path.normpath(root / f.file_path) in names]
    return chosen if chosen else frames


def _load_nerfstudio(path: Path) -> _Dataset:
    meta = read_json_object(path)
    raw = meta.get("frames")
    if not isinstance(raw, list) or not raw:
        raise StealthNSError(f"{path} has no frames")
    root = path.parent
    model = str(meta.get("camera_model", "OPENCV"))
    dist_fixed = any(k in meta for k in ("k1", "k2", "k3", "p1", "p2", "distortion_params"))
    frames = []
    for i, fr in enumerate(raw):
        if not isinstance(fr, dict) or "file_path" not in fr:
            raise StealthNSError(f"{path}: frame {i} has no file_path")
        where = f"frame {fr['file_path']!r}"
        c2w = _pose(fr, where)
        image = _image_file(root, str(fr["file_path"]), where, blender=False)
        try:
            w, h = int(_get(meta, fr, "w", where)), int(_get(meta, fr, "h", where))
            intr = [float(_get(meta, fr, k, where)) for k in ("fl_x", "fl_y", "cx", "cy")]
        except (TypeError, ValueError):
            raise StealthNSError(f"{where}: intrinsics must be numbers") from None
        cam = _camera(model, w, h, *intr, _distortion(meta if dist_fixed else fr), where)
        size = image_size(image, f"{where}: image")
        if size != (w, h):
            raise StealthNSError(f"{where}: image {image} is {size[0]}x{size[1]} but the file says {w}x{h}")
        frames.append(Frame(str(fr["file_path"]), image, c2w, cam))
    return _Dataset(root, path, meta, _selected(meta, root, frames), len(frames), blender=False)


def _load_blender(root: Path) -> _Dataset:
    """Read a Blender folder and convert it to a nerfstudio-data transforms dict (PINHOLE,
    fl = 0.5 * w / tan(camera_angle_x / 2), principal point at the centre, Blender's split kept)."""
    frames: list[Frame] = []
    splits: dict[str, list[str]] = {}
    out_frames = []
    for split in BLENDER_SPLITS:
        path = root / f"transforms_{split}.json"
        if not path.is_file():
            continue
        meta = read_json_object(path)
        raw = meta.get("frames")
        if not isinstance(raw, list) or not raw:
            raise StealthNSError(f"{path} has no frames")
        if "camera_angle_x" not in meta:
            raise StealthNSError(f"{path}: no camera_angle_x")
        angle = float(meta["camera_angle_x"])
        if not 0 < angle < math.pi:
            raise StealthNSError(f"{path}: camera_angle_x must be in (0, pi) radians (got {angle})")
        splits[split] = []
        for i, fr in enumerate(raw):
            if not isinstance(fr, dict) or "file_path" not in fr:
                raise StealthNSError(f"{path}: frame {i} has no file_path")
            where = f"{split} frame {fr['file_path']!r}"
            c2w = _pose(fr, where)
            image = _image_file(root, str(fr["file_path"]), where, blender=True)
            w, h = image_size(image, f"{where}: image")
            fl = 0.5 * w / math.tan(0.5 * angle)
            cam = Camera("PINHOLE", w, h, (fl, fl, w / 2.0, h / 2.0))
            rel = Path(os.path.relpath(image, root)).as_posix()
            frames.append(Frame(rel, image, c2w, cam))
            splits[split].append(rel)
            out_frames.append(
                {
                    "file_path": rel,
                    "fl_x": fl,
                    "fl_y": fl,
                    "cx": w / 2.0,
                    "cy": h / 2.0,
                    "w": w,
                    "h": h,
                    "transform_matrix": c2w.tolist(),
                }
            )
    if not frames:
        raise StealthNSError(f"{root}/transforms_train.json has no frames")
    out: dict[str, Any] = {"camera_model": "PINHOLE"}
    cams = {(f["fl_x"], f["fl_y"], f["cx"], f["cy"], f["w"], f["h"]) for f in out_frames}
    if len(cams) == 1:  # shared intrinsics go to the top level, as nerfstudio writes them
        for f in out_frames:
            for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
                out[k] = f.pop(k)
    out["frames"] = out_frames
    val = splits.get("val") or splits.get("test")
    test = splits.get("test") or splits.get("val")
    if val and test:  # nerfstudio wants all three lists once one is given
        out.update(train_filenames=splits["train"], val_filenames=val, test_filenames=test)
    train = [f for f in frames if f.file_path in set(splits["train"])]
    return _Dataset(root, None, out, train, len(frames), blender=True)


@dataclass
class _Plan:
    """Paths to write: ``json`` (the transforms file), ``ply``, what ``json`` refers to images by
    (``rebase``: a folder the image paths are made relative to), and the dataset to train."""

    json: Path
    ply: Path
    dataset: Path
    rebase: Path | None
    notes: list[str]


def _writable(folder: Path) -> bool:
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=folder)
    except OSError:
        return False
    os.close(fd)
    os.unlink(probe)
    return True


def _ours(ply: Path) -> bool:
    """Whether ``ply`` was written by stealth-ns (:func:`~stealth_ns.scene_generator.writer.write_ply`'s
    header)."""
    try:
        with ply.open("rb") as fh:
            return b"\ncomment stealth-ns " in fh.read(200)
    except OSError:
        return False


def _ply_names(folder: Path) -> Iterator[Path]:
    """``sparse_pc.ply``, ``sparse_pc_seeded.ply``, ``sparse_pc_seeded_2.ply``, ... in ``folder``."""
    yield folder / PLY_NAME
    yield folder / "sparse_pc_seeded.ply"
    for k in itertools.count(2):
        yield folder / f"sparse_pc_seeded_{k}.ply"


def _replaceable_ply(folder: Path) -> Path:
    """``sparse_pc.ply`` unless it is a point cloud of the user's (not written by stealth-ns), else the
    first ``sparse_pc_seeded*.ply`` that is free or ours: --overwrite never replaces the user's points."""
    for path in itertools.islice(_ply_names(folder), 1000):
        if not path.exists() or _ours(path):
            return path
    raise StealthNSError(f"{folder} holds 1000 seed point files: remove some")


def _free_ply_name(folder: Path) -> Path:
    """The first of :func:`_ply_names` that does not exist."""
    return next(path for path in _ply_names(folder) if not path.exists())


def _check_poses_fit(ds: _Dataset, stats: dict[str, float]) -> None:
    """StealthNSError when the images' verified matches lie far from the epipolar lines of the given
    poses (:data:`POSE_MISFIT_PX`, or 0.4 % of the image diagonal if more): the poses do not fit the images
    (another capture's, shuffled frames, another convention), which no resolution or threshold mends."""
    c = ds.frames[0].camera
    bound = max(POSE_MISFIT_PX, 0.004 * float(np.hypot(c.width, c.height)))
    error = stats.get("pose_error_px", float("nan"))
    if np.isfinite(error) and error > bound:
        raise StealthNSError(
            f"the camera poses do not fit the images: their {int(stats['inliers'])} verified matches lie "
            f"{error:.1f} px (median) from the epipolar lines the poses draw (under 1 px when they fit, "
            f"the bound is {bound:.1f} px); check that each frame's transform_matrix belongs to its image "
            "and the camera convention (OpenGL camera-to-world)"
        )


def _plan_outputs(ds: _Dataset, output: Path | None, overwrite: bool) -> _Plan:
    """Decide (and check, before the slow part) which files will be written."""
    root = ds.root
    if output is not None and output.exists() and not output.is_dir():
        raise StealthNSError(f"output {output} exists and is not a folder")
    same = output is not None and output.exists() and output.resolve() == root.resolve()
    if same and not overwrite:
        raise StealthNSError(
            f"output {output} is the dataset folder: pass --overwrite to update its transforms file in "
            "place, or leave --output out to write transforms_seeded.json beside it"
        )
    if output is None or same:
        if not _writable(root):
            raise StealthNSError(
                f"cannot write to the dataset folder {root}: pass --output OUT (another folder)"
            )
        if overwrite and ds.transforms is not None:  # update the user's transforms file in place
            dataset = root if ds.transforms.name == "transforms.json" else ds.transforms
            ply = _replaceable_ply(root)
            notes = [f"updated {ds.transforms} in place"]
            if ply.name != PLY_NAME:
                notes.append(f"{root / PLY_NAME} is not stealth-ns' (kept): wrote {ply.name}")
            return _Plan(ds.transforms, ply, dataset, None, notes)
        seeded = root / SEEDED_JSON
        if ds.transforms is not None and seeded.resolve() == ds.transforms.resolve():
            raise StealthNSError(
                f"{seeded} is the input: pass --overwrite to update it in place, or --output OUT"
            )
        if overwrite:  # Blender: no nerfstudio file of the user's to update
            return _Plan(seeded, _replaceable_ply(root), seeded, None, [])
        if seeded.exists():
            raise StealthNSError(
                f"{seeded} already exists (an earlier run?): delete it, or pass --overwrite or --output OUT"
            )
        ply = _free_ply_name(root)
        notes = [] if ply.name == PLY_NAME else [f"{root / PLY_NAME} exists: wrote {ply.name} instead"]
        if ds.transforms is not None:
            notes.append(f"{ds.transforms.name} left unchanged; {SEEDED_JSON} is a copy naming the points")
        else:
            notes.append(f"{SEEDED_JSON}: the Blender dataset as nerfstudio-data (all splits kept)")
        return _Plan(seeded, ply, seeded, None, notes)
    # a separate output folder
    targets = (output / "transforms.json", output / PLY_NAME)
    if output.exists() and any(output.iterdir()) and not overwrite:
        raise StealthNSError(f"output folder {output} exists and is not empty; pass --overwrite")
    existing = output  # created only when writing, so a failed run leaves nothing behind
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir() or not _writable(existing):
        raise StealthNSError(f"cannot write to output folder {output} ({existing} is not a writable folder)")
    for t in targets:
        if t.is_dir():
            raise StealthNSError(f"{t} is a folder")
    if targets[0].is_file() and not _names_our_ply(targets[0]):
        raise StealthNSError(
            f"--output {output} holds a transforms.json that seed-points did not write (its ply_file_path "
            "names no point cloud of stealth-ns'): --overwrite replaces only its own; give another folder"
        )
    notes = [f"image paths in {targets[0].name} point to {root}"]
    return _Plan(targets[0], _replaceable_ply(output), output, output, notes)


def _names_our_ply(transforms: Path) -> bool:
    """Whether the transforms file names, as its ``ply_file_path``, a point cloud stealth-ns wrote."""
    try:
        ply = json.loads(transforms.read_text(encoding="utf-8")).get("ply_file_path")
    except (OSError, ValueError, AttributeError):
        return False
    return isinstance(ply, str) and _ours(transforms.parent / ply)


def _rebased(meta: dict, root: Path, target: Path) -> dict:
    """``meta`` with every relative file path (images, masks, depths, split lists) made relative
    to ``target`` instead of ``root``."""

    def move(p: str) -> str:
        src = Path(p) if os.path.isabs(p) else root / p
        return Path(os.path.relpath(os.path.normpath(src), target)).as_posix()

    out = dict(meta)
    frames = []
    for fr in meta["frames"]:
        fr = dict(fr)
        for key in ("file_path", "mask_path", "depth_file_path"):
            if isinstance(fr.get(key), str):
                fr[key] = move(fr[key])
        frames.append(fr)
    out["frames"] = frames
    for key in ("train_filenames", "val_filenames", "test_filenames"):
        if isinstance(meta.get(key), list):
            out[key] = [move(str(p)) for p in meta[key]]
    if isinstance(meta.get("mask_path"), str):
        out["mask_path"] = move(meta["mask_path"])
    return out


def _write_outputs(ds: _Dataset, plan: _Plan, xyz: np.ndarray, rgb: np.ndarray) -> None:
    meta = ds.meta if plan.rebase is None else _rebased(ds.meta, ds.root, plan.rebase)
    meta = dict(meta)
    meta["ply_file_path"] = Path(os.path.relpath(plan.ply, plan.json.parent)).as_posix()
    try:
        plan.json.parent.mkdir(parents=True, exist_ok=True)
        write_ply(plan.ply, xyz.astype(np.float32), rgb)
        tmp = plan.json.with_name(plan.json.name + ".tmp")
        tmp.write_text(json.dumps(meta, indent=4) + "\n", encoding="utf-8")
        os.replace(tmp, plan.json)
    except OSError as err:
        raise StealthNSError(f"cannot write {plan.json.parent}: {err.strerror or err}") from None
