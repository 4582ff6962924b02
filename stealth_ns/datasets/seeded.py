"""Seed points triangulated for a dataset folder that has none
(:func:`stealth_ns.datasets.seed_points.make_seed_points`), made once into a seeded copy ``ROOT/scenes/NAME``
and recorded in ``ROOT/scenes/NAME.seed-points.json``, so that later uses reuse them while the
folder's content is the same.
"""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path
from typing import Any

from stealth_ns.datasets.source import SceneSource
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.fingerprint import file_sha256
from stealth_ns.foundation.json_io import write_json_atomic

#: ``OUTPUT/scenes/NAME`` + this: the record of a dataset folder's triangulated seed points.
SEED_POINTS_MARKER = ".seed-points.json"


def seeded_dir(output: Path, name: str) -> Path:
    """``OUTPUT/scenes/NAME``: the seeded copy of a dataset folder without seed points."""
    return output / "scenes" / name


def seed_points_marker(output: Path, name: str) -> Path:
    return output / "scenes" / f"{name}{SEED_POINTS_MARKER}"


def read_seed_points(output: Path, source: SceneSource) -> dict[str, Any] | None:
    """The record of ``source``'s triangulated seed points when it is still valid: made from the
    same folder with the same content, and the dataset and point cloud it names exist."""
    try:
        data = json.loads(seed_points_marker(output, source.name).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or (data.get("source"), data.get("source_sha256")) != (
        str(source.path),
        source.sha256,
    ):
        return None
    try:
        if not (Path(data["dataset"]).exists() and Path(data["ply"]).is_file()):
            return None
    except (KeyError, TypeError):
        return None
    return data


def ensure_seed_points(output: Path, source: SceneSource) -> dict[str, Any]:
    """Triangulate the seed points of a dataset folder into ``OUTPUT/scenes/NAME`` unless a valid
    record of them is there (:func:`read_seed_points`); returns the record."""
    record = read_seed_points(output, source)
    if record is not None:
        return record
    try:
        from stealth_ns.datasets.seed_points import make_seed_points
    except ImportError as err:
        raise StealthNSError(
            f"cannot make seed points: stealth_ns.datasets.seed_points is not available ({err})"
        ) from None
    folder = seeded_dir(output, source.name)
    print(f"triangulating the seed points of {source.name} ({source.path}) into {folder}", flush=True)
    assert source.path is not None
    summary = make_seed_points(source.path, output=folder, overwrite=True, seed=0)
    ply = Path(summary.ply).absolute()
    record = {
        "source": str(source.path),
        "source_sha256": source.sha256,
        "format": source.format,
        "dataset": str(Path(summary.dataset).absolute()),
        "ply": str(ply),
        "ply_sha256": file_sha256(ply),
        "n_points": int(summary.n_points),
        "seconds": round(float(summary.seconds), 2),
        "seed": 0,
        "made_at": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
    }
    write_json_atomic(seed_points_marker(output, source.name), record)
    print(f"  {record['n_points']} seed points in {record['seconds']:.0f} s: {ply}", flush=True)
    return record
