"""Analytic ray casting of planes, boxes, spheres and vertical cylinders (vectorised numpy).

Conventions
-----------
* Rays are given as ``origins`` (N, 3) and unit ``dirs`` (N, 3) in world units; a hit distance ``t``
  is the Euclidean distance along the ray, ``inf`` for a miss.
* The per-type ``intersect_*`` functions return ``t`` of shape (N, P) for P primitives of that type
  and only count hits with ``t > EPS`` (a ray that starts inside a solid hits its far side, so a
  large cylinder or box can enclose the cameras as a room).
* :func:`cast_rays` combines all primitives of a :class:`Geometry` and returns the nearest hit, its
  unit normal (turned to face the incoming ray) and the global primitive id (-1 for a miss).

Dot products are written as explicit component sums (no BLAS) so results are bit-identical
regardless of thread count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS = 1e-6
"""Smallest hit distance counted as a hit (world units)."""

CHUNK_RAYS = 1 << 16
"""Rays cast per chunk in :func:`cast_rays`; bounds temporary memory to O(CHUNK_RAYS * P)."""


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product over the last axis (length 3), broadcasting; deterministic (no BLAS)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _nearest_positive(*candidates: np.ndarray) -> np.ndarray:
    """Element-wise smallest candidate ``> EPS`` (``inf`` where none is)."""
    best = np.full(np.broadcast_shapes(*(c.shape for c in candidates)), np.inf)
    for c in candidates:
        ok = c > EPS
        best = np.where(ok & (c < best), c, best)
    return best


def intersect_planes(
    origins: np.ndarray, dirs: np.ndarray, normal: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    """Ray/plane hit distances for infinite planes ``dot(normal, x) = offset``.

    Parameters: origins, dirs (N, 3); normal (P, 3) unit; offset (P,) world units.
    Returns: t (N, P), ``inf`` where the ray is parallel or the plane is behind.
    """
    denom = _dot(dirs[:, None, :], normal[None, :, :])
    num = offset[None, :] - _dot(origins[:, None, :], normal[None, :, :])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / denom
    t = np.where(np.abs(denom) > 1e-12, t, np.inf)
    return np.where(t > EPS, t, np.inf)


def intersect_spheres(
    origins: np.ndarray, dirs: np.ndarray, centre: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Ray/sphere hit distances.

    Parameters: origins, dirs (N, 3), dirs unit; centre (P, 3); radius (P,).
    Returns: t (N, P) to the first surface crossing ahead of the origin (``inf`` for a miss).
    """
    oc = origins[:, None, :] - centre[None, :, :]
    b = _dot(oc, dirs[:, None, :])
    c = _dot(oc, oc) - radius[None, :] ** 2
    disc = b * b - c
    hit = disc >= 0
    sq = np.sqrt(np.where(hit, disc, 0.0))
    t = _nearest_positive(-b - sq, -b + sq)
    return np.where(hit, t, np.inf)


def intersect_boxes(
    origins: np.ndarray, dirs: np.ndarray, centre: np.ndarray, half: np.ndarray, rot: np.ndarray
) -> np.ndarray:
    """Ray/oriented-box hit distances (slab method in each box's local frame).

    Parameters: origins (N, 3) or (1, 3) (shared origin); dirs (N, 3); centre (P, 3); half (P, 3)
    half extents; rot (P, 3, 3) local-to-world rotation (columns are the box axes in world
    coordinates). Returns: t (N, P).
    """
    oc = origins[:, None, :] - centre[None, :, :]  # (N or 1, P, 3)
    tmin = np.full((dirs.shape[0], centre.shape[0]), -np.inf)
    tmax = np.full_like(tmin, np.inf)
    for k in range(3):
        axis = rot[None, :, :, k]  # (1, P, 3) box axis k in world coordinates
        o_k = _dot(oc, axis)  # local coordinate k of the origin
        d_k = _dot(dirs[:, None, :], axis)
        d_k = np.where(np.abs(d_k) < 1e-12, 1e-12, d_k)
        inv = 1.0 / d_k
        t1 = (-half[None, :, k] - o_k) * inv
        t2 = (half[None, :, k] - o_k) * inv
        tmin = np.maximum(tmin, np.minimum(t1, t2))
        tmax = np.minimum(tmax, np.maximum(t1, t2))
    hit = tmax >= np.maximum(tmin, EPS)
    t = np.where(tmin > EPS, tmin, tmax)
    return np.where(hit, t, np.inf)


def intersect_cylinders(
    origins: np.ndarray, dirs: np.ndarray, centre_xz: np.ndarray, radius: np.ndarray, y_range: np.ndarray
) -> np.ndarray:
    """Ray/capped vertical (y-axis) cylinder hit distances.

    Parameters: origins, dirs (N, 3); centre_xz (P, 2) axis position; radius (P,);
    y_range (P, 2) bottom and top heights.
    Returns: t (N, P) (side or caps, whichever is first).
    """
    ox = origins[:, None, 0] - centre_xz[None, :, 0]
    oz = origins[:, None, 2] - centre_xz[None, :, 1]
    oy = origins[:, None, 1]
    dx, dy, dz = dirs[:, None, 0], dirs[:, None, 1], dirs[:, None, 2]
    r2 = radius[None, :] ** 2
    y0, y1 = y_range[None, :, 0], y_range[None, :, 1]
    a = dx * dx + dz * dz
    b = ox * dx + oz * dz
    c = ox * ox + oz * oz - r2
    disc = b * b - a * c
    ok = (disc >= 0) & (a > 1e-12)
    sq = np.sqrt(np.where(ok, disc, 0.0))
    safe_a = np.where(a > 1e-12, a, 1.0)
    cands = []
    for s in (-sq, sq):
        ts = (-b + s) / safe_a
        ys = oy + ts * dy
        cands.append(np.where(ok & (ys >= y0) & (ys <= y1), ts, np.inf))
    safe_dy = np.where(np.abs(dy) > 1e-12, dy, 1e-12)
    for yc in (y0, y1):
        tc = (yc - oy) / safe_dy
        px = ox + tc * dx
        pz = oz + tc * dz
        cands.append(np.where((np.abs(dy) > 1e-12) & (px * px + pz * pz <= r2), tc, np.inf))
    return _nearest_positive(*cands)


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation about +Y by ``yaw`` radians, shape (3, 3)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class Geometry:
    """A set of primitives, each with a global id (its insertion order) used to look up materials.

    Add primitives with :meth:`add_plane`, :meth:`add_box`, :meth:`add_sphere`,
    :meth:`add_cylinder`; each returns the new primitive's id. ``count`` is the number added.
    """

    KINDS = ("plane", "box", "sphere", "cylinder")

    def __init__(self) -> None:
        self._params: dict[str, list[tuple]] = {k: [] for k in self.KINDS}
        self._ids: dict[str, list[int]] = {k: [] for k in self.KINDS}
        self.count = 0
        self._arrays: dict | None = None

    def _add(self, kind: str, params: tuple) -> int:
        self._params[kind].append(params)
        self._ids[kind].append(self.count)
        self.count += 1
        self._arrays = None
        return self.count - 1

    def add_plane(self, normal, offset: float) -> int:
        """Infinite plane ``dot(normal, x) = offset`` (normal is normalised)."""
        n = np.asarray(normal, dtype=np.float64)
        return self._add("plane", (n / np.linalg.norm(n), float(offset)))

    def add_box(self, centre, half, yaw: float = 0.0) -> int:
        """Box with half extents ``half`` (3,), rotated by ``yaw`` radians about the vertical axis."""
        return self._add("box", (np.asarray(centre, float), np.asarray(half, float), yaw_matrix(yaw)))

    def add_sphere(self, centre, radius: float) -> int:
        """Sphere of ``radius`` around ``centre`` (3,)."""
        return self._add("sphere", (np.asarray(centre, float), float(radius)))

    def add_cylinder(self, centre_xz, radius: float, y0: float, y1: float) -> int:
        """Capped vertical cylinder with axis at ``centre_xz`` (x, z), from height y0 to y1."""
        return self._add("cylinder", (np.asarray(centre_xz, float), float(radius), (float(y0), float(y1))))

    def arrays(self) -> dict:
        """Packed per-type parameter arrays plus ``ids`` (P,) mapping local index to global id."""
        if self._arrays is None:
            p, ids = self._params, self._ids
            out: dict = {}
            if p["plane"]:
                out["plane"] = dict(
                    normal=np.stack([q[0] for q in p["plane"]]), offset=np.array([q[1] for q in p["plane"]])
                )
            if p["box"]:
                out["box"] = dict(
                    centre=np.stack([q[0] for q in p["box"]]),
                    half=np.stack([q[1] for q in p["box"]]),
                    rot=np.stack([q[2] for q in p["box"]]),
                )
            if p["sphere"]:
                out["sphere"] = dict(
                    centre=np.stack([q[0] for q in p["sphere"]]), radius=np.array([q[1] for q in p["sphere"]])
                )
            if p["cylinder"]:
                out["cylinder"] = dict(
                    centre_xz=np.stack([q[0] for q in p["cylinder"]]),
                    radius=np.array([q[1] for q in p["cylinder"]]),
                    y_range=np.array([q[2] for q in p["cylinder"]]),
                )
            for kind in out:
                out[kind]["ids"] = np.array(ids[kind], dtype=np.int64)
            self._arrays = out
        return self._arrays


_INTERSECT = {
    "plane": lambda o, d, a: intersect_planes(o, d, a["normal"], a["offset"]),
    "box": lambda o, d, a: intersect_boxes(o, d, a["centre"], a["half"], a["rot"]),
    "sphere": lambda o, d, a: intersect_spheres(o, d, a["centre"], a["radius"]),
    "cylinder": lambda o, d, a: intersect_cylinders(o, d, a["centre_xz"], a["radius"], a["y_range"]),
}


def _normals(kind: str, a: dict, local: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Outward unit normals (M, 3) at hit ``points`` (M, 3) on primitives ``local`` (M,) of one type."""
    if kind == "plane":
        return a["normal"][local]
    if kind == "sphere":
        n = points - a["centre"][local]
        return n / np.linalg.norm(n, axis=1, keepdims=True)
    if kind == "box":
        rot = a["rot"][local]  # (M, 3, 3)
        rel = points - a["centre"][local]
        p_l = np.stack([_dot(rel, rot[:, :, k]) for k in range(3)], axis=-1) / a["half"][local]
        axis = np.argmax(np.abs(p_l), axis=1)
        sign = np.sign(p_l[np.arange(len(local)), axis])
        return rot[np.arange(len(local)), :, axis] * sign[:, None]
    # cylinder: side or cap, whichever surface the point is closest to
    cxz = a["centre_xz"][local]
    r = a["radius"][local]
    y0, y1 = a["y_range"][local, 0], a["y_range"][local, 1]
    rx, rz = points[:, 0] - cxz[:, 0], points[:, 2] - cxz[:, 1]
    rho = np.sqrt(rx * rx + rz * rz)
    d_side, d_top, d_bot = np.abs(rho - r), np.abs(points[:, 1] - y1), np.abs(points[:, 1] - y0)
    safe = np.where(rho > 1e-12, rho, 1.0)
    n = np.stack([rx / safe, np.zeros_like(rho), rz / safe], axis=1)
    n = np.where(((d_top < d_side) & (d_top <= d_bot))[:, None], [0.0, 1.0, 0.0], n)
    n = np.where(((d_bot < d_side) & (d_bot < d_top))[:, None], [0.0, -1.0, 0.0], n)
    return n


@dataclass
class RayHits:
    """Nearest hits of N rays: ``t`` (N,) distance (inf on miss), ``normal`` (N, 3) unit normal facing
    the ray (zero on miss), ``prim`` (N,) global primitive id (-1 on miss), ``points`` (N, 3)."""

    t: np.ndarray
    normal: np.ndarray
    prim: np.ndarray
    points: np.ndarray


def _bounds(kind: str, a: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """Bounding spheres (centres (P, 3), radii (P,)) of one primitive type; None for planes."""
    if kind == "box":
        return a["centre"], np.linalg.norm(a["half"], axis=1)
    if kind == "sphere":
        return a["centre"], a["radius"]
    if kind == "cylinder":
        y0, y1 = a["y_range"][:, 0], a["y_range"][:, 1]
        c = np.stack([a["centre_xz"][:, 0], 0.5 * (y0 + y1), a["centre_xz"][:, 1]], axis=1)
        return c, np.sqrt(a["radius"] ** 2 + (0.5 * (y1 - y0)) ** 2)
    return None


def _cone_cull(origin: np.ndarray, dirs: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Conservative visibility (P,) bool of bounding spheres from one ``origin`` (3,) for the cone
    of unit rays ``dirs`` (N, 3): False only where a sphere lies wholly outside the cone."""
    mean = dirs.mean(axis=0)
    norm = np.linalg.norm(mean)
    if norm < 0.5:  # rays spread too widely for a useful cone
        return np.ones(len(radii), dtype=bool)
    axis = mean / norm
    half_angle = np.arccos(np.clip(_dot(dirs, axis).min(), -1.0, 1.0))
    v = centres - origin
    dist = np.linalg.norm(v, axis=1)
    inside = dist <= radii * 1.001
    safe = np.where(inside, 1.0, dist)
    beta = np.arccos(np.clip(_dot(v, axis) / safe, -1.0, 1.0))
    gamma = np.arcsin(np.clip(radii / safe, 0.0, 1.0))
    return inside | (beta - gamma <= half_angle + 1e-3)


def cast_rays(geometry: Geometry, origins: np.ndarray, dirs: np.ndarray) -> RayHits:
    """Nearest hit of each ray against all primitives of ``geometry``.

    Parameters: origins (N, 3), or (3,) for rays that share one origin (faster: primitives
    outside the rays' cone are skipped); dirs (N, 3) unit vectors. World units.
    Returns: :class:`RayHits` with arrays of length N.
    """
    dirs = np.asarray(dirs, dtype=np.float64)
    origins = np.asarray(origins, dtype=np.float64)
    shared = origins.ndim == 1
    n_rays = dirs.shape[0]
    arrs = geometry.arrays()
    t_out = np.full(n_rays, np.inf)
    prim_out = np.full(n_rays, -1, dtype=np.int64)
    for start in range(0, n_rays, CHUNK_RAYS):
        sl = slice(start, min(start + CHUNK_RAYS, n_rays))
        d = dirs[sl]
        o = origins[None, :] if shared else origins[sl]
        best_t = np.full(d.shape[0], np.inf)
        best_id = np.full(d.shape[0], -1, dtype=np.int64)
        for kind, a in arrs.items():
            bounds = _bounds(kind, a)
            if shared and bounds is not None:
                keep = _cone_cull(origins, d, *bounds)
                if not keep.any():
                    continue
                a = {key: val[keep] for key, val in a.items()}
            t = _INTERSECT[kind](o, d, a)
            j = np.argmin(t, axis=1)
            tj = t[np.arange(t.shape[0]), j]
            better = tj < best_t
            best_t = np.where(better, tj, best_t)
            best_id = np.where(better, a["ids"][j], best_id)
        t_out[sl], prim_out[sl] = best_t, best_id
    hit = prim_out >= 0
    points = origins + dirs * np.where(hit, t_out, 0.0)[:, None]
    normal = np.zeros_like(dirs)
    for kind, a in arrs.items():
        lookup = np.full(geometry.count, -1, dtype=np.int64)
        lookup[a["ids"]] = np.arange(len(a["ids"]))
        local = np.where(hit, lookup[np.where(hit, prim_out, 0)], -1)
        m = local >= 0
        if np.any(m):
            normal[m] = _normals(kind, a, local[m], points[m])
    facing = _dot(normal, dirs)
    normal = np.where((facing > 0)[:, None], -normal, normal)
    return RayHits(t=t_out, normal=normal, prim=prim_out, points=points)
