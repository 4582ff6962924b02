"""Procedural test scenes rendered by analytic ray casting, in nerfstudio-data or Blender format.

Use :func:`make_scene` (or ``stealth-ns make-scene``). Four presets (layouts: :mod:`.presets`):

* ``orbit``: inward-facing 360-degree capture around a group of textured objects (Mip-NeRF 360
  like), 60 views by default, 128x96;
* ``forward``: a free forward walk down a street (Free dataset like), 48 views by default, 128x96;
* ``facing``: a forward-facing hand-held capture of a cluttered scene (LLFF like: cameras on a
  small planar grid, baseline ~10x smaller than the scene depth, all looking the same way), 24
  views by default, 128x96;
* ``object``: an object-centric capture of 1-3 objects on a transparent background
  (NeRF-synthetic / Blender like: cameras on the upper hemisphere at radius 4 looking at the
  origin), 150 views (100 train / 25 val / 25 test) by default, 128x128.

``orbit``, ``forward`` and ``facing`` are written in nerfstudio-data format (dataparser
``nerfstudio-data``) with SfM-like seed points in ``sparse_pc.ply`` (surface samples of the
training views with depth-proportional noise; ``facing`` adds 2% outliers, points pushed along
their viewing ray, as an SfM reconstruction has); every 8th view (index % 8 == 0) is held out for
testing. ``object`` is written in the Blender format (dataparser ``blender-data``: RGBA PNGs,
``transforms_{train,val,test}.json``) without seed points, as NeRF-synthetic has none.

Depth maps are **z-depth** (distance along the camera's -Z axis, world units; 0 where the pixel sees
sky or background), which is what nerfstudio's depth losses expect. They are float32 ``.npy`` in
world units, so a nerfstudio depth pipeline needs ``depth_unit_scale_factor=1.0`` (its default,
1e-3, assumes millimetres). ``scene.json`` records the preset, seed, resolution, split, field of
view, region of interest and the preset's own parameters.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.file_manifest import listing
from stealth_ns.images.io import save_png
from stealth_ns.scene_generator.presets import (
    BLENDER_PRESETS,
    DEFAULT_RESOLUTION,
    DEFAULT_VIEWS,
    PRESETS,
    ScenePlan,
    scene_plan,
)
from stealth_ns.scene_generator.render import Intrinsics, RenderedView, render_view
from stealth_ns.scene_generator.writer import (
    MANIFEST,
    blender_depth_path,
    blender_frame_path,
    blender_transforms_dict,
    clear_recorded,
    depth_path,
    foreign_files,
    image_path,
    transforms_dict,
    write_json,
    write_manifest,
    write_ply,
)

__all__ = ["PRESETS", "SceneSummary", "make_scene", "parse_resolution", "split_indices"]

SEED_POINTS = 8000
"""Approximate number of seed points written to ``sparse_pc.ply``."""
POINT_NOISE = 0.003
"""Seed point position noise: Gaussian sigma = POINT_NOISE * z-depth (world units)."""
OUTLIER_FRACTION = {"facing": 0.02}
"""Fraction of seed points turned into SfM-like outliers, per preset (none for the others)."""
MAX_SIDE = 8192


@dataclass(frozen=True)
class SceneSummary:
    """What :func:`make_scene` wrote; ``str()`` gives a short human summary."""

    preset: str
    output: Path
    views: int
    n_train: int
    n_test: int
    width: int
    height: int
    n_points: int
    seed: int
    seconds: float
    dataparser: str = "nerfstudio-data"
    n_val: int | None = None
    """Number of val views where they differ from the test views (Blender format), else None."""

    @property
    def train_command(self) -> str:
        return f"ns-train stealth-splat-lite --vis tensorboard {self.dataparser} --data {self.output}"

    def __str__(self) -> str:
        val = "" if self.n_val is None else f"{self.n_val} val / "
        points = f"{self.n_points} seed points" if self.dataparser != "blender-data" else "no seed points"
        return (
            f"Wrote {self.preset} scene ({self.dataparser} format) to {self.output}\n"
            f"  {self.views} views ({self.n_train} train / {val}{self.n_test} test), "
            f"{self.width}x{self.height}, {points}, seed {self.seed}, {self.seconds:.1f} s\n"
            f"Train on it with:\n  {self.train_command}"
        )


def parse_resolution(resolution: str) -> tuple[int, int]:
    """Parse ``"WIDTHxHEIGHT"`` (e.g. ``"128x96"``) into positive ints (width, height)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(resolution))
    if not m:
        raise StealthNSError(f"resolution must look like WIDTHxHEIGHT, e.g. 128x96 (got {resolution!r})")
    w, h = int(m.group(1)), int(m.group(2))
    if w <= 0 or h <= 0:
        raise StealthNSError(f"resolution must have a positive width and height (got {resolution!r})")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise StealthNSError(f"resolution must be at most {MAX_SIDE} pixels a side (got {resolution!r})")
    return w, h


def split_indices(views: int) -> tuple[list[int], list[int]]:
    """Train and test view indices: every 8th view (index % 8 == 0) is a test view."""
    test = [i for i in range(views) if i % 8 == 0]
    train = [i for i in range(views) if i % 8 != 0]
    return train, test


def _check_output(output: Path, overwrite: bool) -> None:
    """Fail early (before rendering) if ``output`` cannot be used; creates it if missing."""
    try:
        if output.exists() and not output.is_dir():
            raise StealthNSError(f"output {output} exists and is not a folder")
        if output.is_dir() and any(output.iterdir()) and not overwrite:
            raise StealthNSError(f"output folder {output} exists and is not empty; pass --overwrite")
        foreign = foreign_files(output) if output.is_dir() else []
        if foreign:
            raise StealthNSError(
                f"output folder {output} holds files stealth-ns did not write (or that changed since; not "
                f"recorded in {MANIFEST}): {listing(foreign)}; --overwrite replaces only the "
                "generator's own files: move these away or choose another folder"
            )
        output.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=output)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise StealthNSError(f"output folder {output} is not writable: {reason}") from None


def _seed_points(rng: np.random.Generator, view: RenderedView, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``k`` random surface samples (xyz (k, 3) with depth-proportional noise, rgb (k, 3))
    from the pixel-centre hits of one rendered view."""
    depth = view.depth.reshape(-1)
    valid = np.flatnonzero(depth > 0)
    k = min(k, valid.size)
    pick = np.sort(rng.choice(valid, size=k, replace=False))
    xyz = view.centre_points.reshape(-1, 3)[pick]
    xyz = xyz + rng.normal(size=xyz.shape) * (POINT_NOISE * depth[pick])[:, None]
    return xyz, view.centre_colour.reshape(-1, 3)[pick]


def _add_outliers(
    rng: np.random.Generator, xyz: np.ndarray, origins: np.ndarray, fraction: float
) -> tuple[np.ndarray, int]:
    """Turn a ``fraction`` of the points ``xyz`` (N, 3) into SfM-like outliers (mis-triangulated
    matches): moved along the ray from their source camera ``origins`` (N, 3) to a distance scaled
    by a log-normal factor (sigma 0.4, at least 15% off) plus lateral noise of 3% of the distance.
    Colours stay. Returns the new points and the number of outliers."""
    n = int(round(fraction * len(xyz)))
    if n == 0:
        return xyz, 0
    pick = np.sort(rng.choice(len(xyz), size=n, replace=False))
    factor = np.exp(rng.normal(size=n) * 0.4)
    factor = np.where(np.abs(factor - 1.0) < 0.15, 1.0 + np.sign(factor - 1.0 + 1e-12) * 0.15, factor)
    ray = xyz[pick] - origins[pick]
    dist = np.linalg.norm(ray, axis=1, keepdims=True)
    out = xyz.copy()
    out[pick] = origins[pick] + ray * factor[:, None] + rng.normal(size=(n, 3)) * 0.03 * dist
    return out, n


def make_scene(
    preset: str,
    output: Path,
    resolution: str | None = None,
    views: int | None = None,
    seed: int = 0,
    overwrite: bool = False,
) -> SceneSummary:
    """Render a procedural scene and write it to ``output`` (nerfstudio-data or Blender format,
    by preset; see the module doc). ``resolution`` "WIDTHxHEIGHT" defaults to the preset's
    (128x96, 128x128 for ``object``); ``views`` to the preset's (:data:`DEFAULT_VIEWS`).

    Raises :class:`~stealth_ns.foundation.errors.StealthNSError` (one-line message) for an unknown preset, a
    malformed resolution, fewer than 8 views, a negative seed, an output that cannot be written, or
    a non-empty output folder without ``overwrite``. With it, the files an earlier run recorded in
    its manifest (:data:`~stealth_ns.scene_generator.writer.MANIFEST`) are removed first, unrelated files
    beside them are left alone, and a folder holding files the generator did not write where it
    writes (``images/``, ``transforms.json``, ...) is refused before anything is touched.
    """
    t0 = time.perf_counter()
    if preset not in PRESETS:
        raise StealthNSError(f"unknown preset {preset!r}; choose one of: {', '.join(PRESETS)}")
    width, height = parse_resolution(DEFAULT_RESOLUTION[preset] if resolution is None else resolution)
    if views is None:
        views = DEFAULT_VIEWS[preset]
    if isinstance(views, bool) or not isinstance(views, (int, np.integer)) or views < 8:
        raise StealthNSError(f"views must be an integer of at least 8 (got {views!r})")
    views = int(views)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise StealthNSError(f"seed must be a non-negative integer (got {seed!r})")
    output = Path(output).expanduser().absolute()
    _check_output(output, overwrite)

    plan: ScenePlan = scene_plan(preset, int(seed), views)
    intr = Intrinsics.from_fov(width, height, plan.hfov_deg)
    common = {
        # a label, not an import path: it keeps the package's first name, so that a scene generated
        # before and after the package's rename is the same bytes
        "generator": "stealth_ns.scenes",
        "preset": preset,
        "seed": int(seed),
        "resolution": [width, height],
        "views": views,
        "hfov_deg": plan.hfov_deg,
        "centre": plan.centre,
        "radius": plan.radius,
        **plan.info,
    }
    try:
        clear_recorded(output)
        planned = _planned_files(preset, plan)
        write_manifest(output, planned, hashes=False)  # first: a run cut short can still be replaced
        if preset in BLENDER_PRESETS:
            counts = _write_blender(output, plan, intr, common)
        else:
            counts = _write_nerfstudio(output, plan, intr, common, int(seed))
        write_manifest(output, planned, hashes=True)
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise StealthNSError(f"could not write scene to {output}: {reason}") from None
    return SceneSummary(
        preset=preset,
        output=output,
        views=views,
        width=width,
        height=height,
        seed=int(seed),
        seconds=time.perf_counter() - t0,
        **counts,
    )


def _planned_files(preset: str, plan: ScenePlan) -> list[str]:
    """Relative paths of every file :func:`make_scene` writes for ``plan`` (its manifest)."""
    if preset in BLENDER_PRESETS:
        files = ["scene.json"]
        for split, (start, stop) in plan.splits.items():
            files.append(f"transforms_{split}.json")
            for k in range(stop - start):
                files += [blender_frame_path(split, k)[2:] + ".png", blender_depth_path(split, k)]
        return files
    views = range(len(plan.c2w))
    return [
        "transforms.json",
        "sparse_pc.ply",
        "scene.json",
        *(image_path(i) for i in views),
        *(depth_path(i) for i in views),
    ]


def _write_nerfstudio(output: Path, plan: ScenePlan, intr: Intrinsics, common: dict, seed: int) -> dict:
    """Render and write ``plan`` in nerfstudio-data format; returns SceneSummary's counts."""
    views = len(plan.c2w)
    train, test = split_indices(views)
    train_set = set(train)
    (output / "images").mkdir()
    (output / "depths").mkdir()
    rng = np.random.default_rng([seed, 303])
    per_view = math.ceil(SEED_POINTS / len(train))
    pts, cols, origins = [], [], []
    for i, c2w in enumerate(plan.c2w):
        view = render_view(plan, intr, c2w)
        save_png(output / image_path(i), view.image)
        np.save(output / depth_path(i), view.depth)
        if i in train_set:
            xyz, rgb = _seed_points(rng, view, per_view)
            pts.append(xyz)
            cols.append(rgb)
            origins.append(np.broadcast_to(c2w[:3, 3], xyz.shape))
    xyz, rgb = np.concatenate(pts), np.concatenate(cols)
    fraction = OUTLIER_FRACTION.get(plan.preset, 0.0)
    n_outliers = 0
    if fraction > 0:
        xyz, n_outliers = _add_outliers(
            np.random.default_rng([seed, 606]), xyz, np.concatenate(origins), fraction
        )
    c2w_out = plan.exported_c2w()
    write_ply(output / "sparse_pc.ply", xyz, rgb)
    write_json(output / "transforms.json", transforms_dict(intr, c2w_out, train, test))
    info = {
        **common,
        "format": "nerfstudio-data",
        "n_train": len(train),
        "n_test": len(test),
        "depth": "z-depth along camera -Z, world units, float32 .npy, 0 = sky (no surface)",
        "n_points": int(xyz.shape[0]),
    }
    if fraction > 0:
        info["n_outliers"] = n_outliers
    write_json(output / "scene.json", info)  # last: its presence means the scene is complete
    return {"n_train": len(train), "n_test": len(test), "n_points": int(xyz.shape[0])}


def _write_blender(output: Path, plan: ScenePlan, intr: Intrinsics, common: dict) -> dict:
    """Render and write ``plan`` in the Blender (NeRF-synthetic) format; returns SceneSummary's counts."""
    c2w_out = plan.exported_c2w()
    camera_angle_x = float(np.deg2rad(plan.hfov_deg))
    scale = np.float32(plan.export_scale)  # depth in export-frame units
    counts = {}
    for split, (start, stop) in plan.splits.items():
        (output / split).mkdir()
        (output / "depths" / split).mkdir(parents=True)
        for k, i in enumerate(range(start, stop)):
            view = render_view(plan, intr, plan.c2w[i])
            save_png(output / split / f"r_{k}.png", view.rgba())
            np.save(output / blender_depth_path(split, k), (view.depth * scale).astype(np.float32))
        write_json(
            output / f"transforms_{split}.json",
            blender_transforms_dict(camera_angle_x, c2w_out[start:stop], split),
        )
        counts[split] = stop - start
    write_json(
        output / "scene.json",
        {
            **common,
            "format": "blender",
            "n_train": counts["train"],
            "n_val": counts["val"],
            "n_test": counts["test"],
            "splits": {k: list(v) for k, v in plan.splits.items()},
            "depth": "z-depth along camera -Z, world units, float32 .npy, 0 = background (no surface)",
            "n_points": 0,
        },
    )
    return {
        "n_train": counts["train"],
        "n_test": counts["test"],
        "n_points": 0,
        "dataparser": "blender-data",
        "n_val": counts["val"],
    }
