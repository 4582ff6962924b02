"""Procedural test scenes in nerfstudio-data format, rendered by analytic ray casting.

Use :func:`make_scene` (or ``stealth-ns make-scene``). Two presets:

* ``orbit``: inward-facing 360-degree capture around a group of textured objects (Mip-NeRF 360
  like), 60 views by default;
* ``forward``: a free forward walk down a street (Free dataset like), 48 views by default.

Every 8th view (index % 8 == 0) is held out for testing. Depth maps are **z-depth** (distance along
the camera's -Z axis, world units; 0 where the pixel sees sky), which is what nerfstudio's depth
losses expect. They are float32 ``.npy`` in world units, so a nerfstudio depth pipeline needs
``depth_unit_scale_factor=1.0`` (its default, 1e-3, assumes millimetres).
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

from stealth_ns.errors import StealthNSError
from stealth_ns.scenes.presets import DEFAULT_VIEWS, HFOV_DEG, PRESETS, ScenePlan, make_plan
from stealth_ns.scenes.render import Intrinsics, RenderedView, render_view
from stealth_ns.scenes.writer import (
    clear_generated,
    depth_path,
    image_path,
    transforms_dict,
    write_json,
    write_ply,
    write_png,
)

__all__ = ["PRESETS", "SceneSummary", "make_scene", "parse_resolution", "split_indices"]

SEED_POINTS = 8000
"""Approximate number of seed points written to ``sparse_pc.ply``."""
POINT_NOISE = 0.003
"""Seed point position noise: Gaussian sigma = POINT_NOISE * z-depth (world units)."""
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

    @property
    def train_command(self) -> str:
        return f"ns-train stealth-splat-lite --vis tensorboard nerfstudio-data --data {self.output}"

    def __str__(self) -> str:
        return (
            f"Wrote {self.preset} scene to {self.output}\n"
            f"  {self.views} views ({self.n_train} train / {self.n_test} test), {self.width}x{self.height}, "
            f"{self.n_points} seed points, seed {self.seed}, {self.seconds:.1f} s\n"
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


def make_scene(
    preset: str,
    output: Path,
    resolution: str = "128x96",
    views: int | None = None,
    seed: int = 0,
    overwrite: bool = False,
) -> SceneSummary:
    """Render a procedural scene and write it to ``output`` in nerfstudio-data format.

    Raises :class:`~stealth_ns.errors.StealthNSError` (one-line message) for an unknown preset, a
    malformed resolution, fewer than 8 views, a negative seed, an output that cannot be written, or
    a non-empty output folder without ``overwrite`` (with it, the previously generated entries are
    removed first; unrelated files are left alone).
    """
    t0 = time.perf_counter()
    if preset not in PRESETS:
        raise StealthNSError(f"unknown preset {preset!r}; choose one of: {', '.join(PRESETS)}")
    width, height = parse_resolution(resolution)
    if views is None:
        views = DEFAULT_VIEWS[preset]
    if isinstance(views, bool) or not isinstance(views, (int, np.integer)) or views < 8:
        raise StealthNSError(f"views must be an integer of at least 8 (got {views!r})")
    views = int(views)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise StealthNSError(f"seed must be a non-negative integer (got {seed!r})")
    output = Path(output).expanduser().absolute()
    _check_output(output, overwrite)

    plan: ScenePlan = make_plan(preset, int(seed), views)
    intr = Intrinsics.from_fov(width, height)
    train, test = split_indices(views)
    train_set = set(train)
    try:
        clear_generated(output)
        (output / "images").mkdir()
        (output / "depths").mkdir()
        rng = np.random.default_rng([int(seed), 303])
        per_view = math.ceil(SEED_POINTS / len(train))
        pts, cols = [], []
        for i, c2w in enumerate(plan.c2w):
            view = render_view(plan, intr, c2w)
            write_png(output / image_path(i), view.image)
            np.save(output / depth_path(i), view.depth)
            if i in train_set:
                xyz, rgb = _seed_points(rng, view, per_view)
                pts.append(xyz)
                cols.append(rgb)
        xyz, rgb = np.concatenate(pts), np.concatenate(cols)
        write_ply(output / "sparse_pc.ply", xyz, rgb)
        write_json(output / "transforms.json", transforms_dict(intr, plan.c2w, train, test))
        write_json(
            output / "scene.json",
            {
                "generator": "stealth_ns.scenes",
                "preset": preset,
                "seed": int(seed),
                "resolution": [width, height],
                "views": views,
                "n_train": len(train),
                "n_test": len(test),
                "hfov_deg": HFOV_DEG,
                "centre": plan.centre,
                "radius": plan.radius,
                "depth": "z-depth along camera -Z, world units, float32 .npy, 0 = sky (no surface)",
                "n_points": int(xyz.shape[0]),
                **plan.info,
            },
        )
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise StealthNSError(f"could not write scene to {output}: {reason}") from None
    return SceneSummary(
        preset=preset,
        output=output,
        views=views,
        n_train=len(train),
        n_test=len(test),
        width=width,
        height=height,
        n_points=int(xyz.shape[0]),
        seed=int(seed),
        seconds=time.perf_counter() - t0,
    )
