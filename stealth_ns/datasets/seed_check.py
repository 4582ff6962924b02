"""A dataset's seed points checked before training: one line naming the file and the point.

Split out of :mod:`stealth_ns.datasets.check` (which re-exports these names), so that every dataset
format's check -- nerfstudio-data's ``ply_file_path``, COLMAP's ``points3D``, blender-data's
``--ply-path`` -- measures its cloud against its cameras the same way. The density-guided
injection's own start-up check (:func:`check_injection_seed_points`: the model starts from seed
points at all) is here too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.attack.options import option_words
from stealth_ns.datasets.references import read_json_object
from stealth_ns.foundation.errors import StealthNSError

__all__ = [
    "MAX_POINT_DISTANCE", "MIN_SEED_POINTS", "camera_spread", "check_injection_seed_points", "check_ply",
    "check_seed_points", "ply_vertex_count", "xyz_text",
]  # fmt: skip

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


def xyz_text(p: np.ndarray) -> str:
    """A position as ``x, y, z`` for a message."""
    return ", ".join(f"{float(v):.6g}" for v in p)


def camera_spread(positions: np.ndarray, what: str) -> tuple[np.ndarray, float]:
    """The cameras' mean position and spread (largest distance from it) for ``positions`` [C, 3];
    StealthNSError if they all are at one position (nerfstudio divides by the spread)."""
    centre = positions.mean(axis=0)
    spread = float(np.linalg.norm(positions - centre, axis=1).max())
    if spread <= 1e-6 * max(1.0, float(np.abs(centre).max())):
        raise StealthNSError(
            f"{what}: every frame's camera is at the same position ({xyz_text(positions[0])}): nerfstudio "
            "scales the scene by how far apart the cameras are"
        )
    return centre, spread


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
            f"{what}: {point(bad[0])} is ({xyz_text(xyz[bad[0]])}), not a finite position "
            f"({bad.size} such point{'s' * (bad.size != 1)})"
        )
    if n < MIN_SEED_POINTS:
        raise StealthNSError(
            f"{what} has {n} point{'s' * (n != 1)}: at least {MIN_SEED_POINTS} are needed (a Gaussian's "
            f"first size is its distance to its 3 nearest neighbours){hint}"
        )
    if float(np.ptp(xyz, axis=0).max()) == 0.0:
        raise StealthNSError(
            f"{what}: all {n} points coincide at ({xyz_text(xyz[0])}); they span no volume{hint}"
        )
    distance = np.linalg.norm(xyz - centre, axis=1) / spread
    k = int(np.argmax(distance))
    if distance[k] > MAX_POINT_DISTANCE:
        raise StealthNSError(
            f"{what}: {point(k)} at ({xyz_text(xyz[k])}) is {distance[k]:.3g} times the cameras' spread "
            f"from their centre (more than {MAX_POINT_DISTANCE:g}): an absurd position"
        )


def check_ply(ply: Path, where: str, key: str, hint: str, centre: np.ndarray, spread: float) -> int:
    """The number of points of the seed-point file ``ply`` named by ``where``'s ``key``
    (``ply_file_path``, ``--ply-path``), read as nerfstudio reads it (open3d) and checked with
    :func:`check_seed_points`; ``hint`` (from "; ") says how to do without or make them."""
    if not ply.is_file():
        raise StealthNSError(f"{where}: {key} {ply} (seed points) does not exist{hint}")
    try:
        n = ply_vertex_count(ply)
    except StealthNSError as err:
        raise StealthNSError(f"{where}: {err}") from None
    xyz = np.zeros((0, 3))
    if n > 0:
        import open3d as o3d

        xyz = np.asarray(o3d.io.read_point_cloud(str(ply)).points, dtype=np.float64)
        if len(xyz) != n:
            raise StealthNSError(f"{where}: open3d reads {len(xyz)} of the {n} points of {ply}")
    check_seed_points(xyz, f"{where}: seed-point file {ply}", centre, spread, hint)
    return len(xyz)


def check_injection_seed_points(points: Any, random_init: bool, transforms: Path | None, data: Any) -> None:
    """StealthNSError unless the model starts from seed points: the density-guided placement reads the
    density of the point cloud, and that of a random initialisation is noise.

    Args:
        points: the model's seed points ([N, 3]), None when the dataset has none.
        random_init: ``--pipeline.model.random-init``.
        transforms: the dataset's nerfstudio-data transforms file (None: no dataset folder given).
        data: the dataset as ``--data`` names it, for the message.
    """
    if random_init:
        why = "--pipeline.model.random-init is on"
    elif points is None and (named := _named_seed_point_file(transforms)) is not None:
        why = named
    elif points is None:
        why = (
            "the dataset has no seed points (no ply_file_path in transforms.json, no COLMAP points, "
            "or a Blender dataset)"
        )
    elif points.shape[0] == 0:
        why = "the seed-point file is empty"
    else:
        return
    raise StealthNSError(
        f"the density-guided injection places poison by the density of the seed points, but {why}. "
        f"Triangulate them from the known poses with `stealth-ns seed-points --data {data}` and train "
        f"on the dataset it prints, or turn the component off with {option_words('density_guided', False)}"
    )


def _named_seed_point_file(path: Path | None) -> str | None:
    """Why the seed-point file named by a nerfstudio-data transforms file ``path`` gave no points, if it
    names one."""
    if path is None:
        return None
    try:
        ply = read_json_object(path).get("ply_file_path")
    except StealthNSError:  # not nerfstudio-data (colmap, blender): no named file
        return None
    if not isinstance(ply, str):
        return None
    ply_path = path.parent / ply  # its existence is checked at start-up (dataset_check)
    try:
        n = ply_vertex_count(ply_path)
    except StealthNSError as err:
        return str(err)
    return f"the seed-point file {ply_path} has no points" if n == 0 else None
