"""``make_scene``: check the inputs, plan the scene (:mod:`.presets`), render and write it in its format
(:mod:`.formats`), and say what was written (:class:`SceneSummary`)."""

from __future__ import annotations

import os
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.file_manifest import listing
from stealth_ns.scene_generator.formats import planned_files, write_blender, write_nerfstudio
from stealth_ns.scene_generator.presets import (
    BLENDER_PRESETS,
    DEFAULT_RESOLUTION,
    DEFAULT_VIEWS,
    PRESETS,
    ScenePlan,
    scene_plan,
)
from stealth_ns.scene_generator.render import Intrinsics
from stealth_ns.scene_generator.writer import MANIFEST, clear_recorded, foreign_files, write_manifest

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


def make_scene(
    preset: str,
    output: Path,
    resolution: str | None = None,
    views: int | None = None,
    seed: int = 0,
    overwrite: bool = False,
) -> SceneSummary:
    """Render a procedural scene and write it to ``output`` (nerfstudio-data or Blender format,
    by preset; see the package doc). ``resolution`` "WIDTHxHEIGHT" defaults to the preset's
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
        planned = planned_files(preset, plan)
        write_manifest(output, planned, hashes=False)  # first: a run cut short can still be replaced
        if preset in BLENDER_PRESETS:
            counts = write_blender(output, plan, intr, common)
        else:
            counts = write_nerfstudio(output, plan, intr, common, int(seed))
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
