"""The protocol's math (see :mod:`stealth_ns.difficulty`): the scene KDE, frustum quadrature, per-view
densities and the Easy / Median / Hard picks. Pure numpy on the attack's density grid.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import TYPE_CHECKING, Literal, NamedTuple

import numpy as np

from stealth_ns.attack.config import AttackConfig

if TYPE_CHECKING:
    from stealth_ns.attack.density import DensityGrid


_ATTACK_DEFAULTS = {f.name: f.default for f in fields(AttackConfig)}
DEFAULT_GRID_RESOLUTION: int = _ATTACK_DEFAULTS["grid_resolution"]
"""The attack's KDE grid (voxels along the longest side): the protocol ranks views by the density the
attack itself would use."""
DEFAULT_BANDWIDTH: float = _ATTACK_DEFAULTS["bandwidth"]
"""The attack's KDE bandwidth h in voxels."""
DEFAULT_RADIUS_FRACTION = 0.1
DEFAULT_N_DIRS = 32
DEFAULT_N_DEPTHS = 32


class FrustumSamples(NamedTuple):
    """Quadrature points of a camera's view frustum within a radius.

    Attributes:
        points: ``[M, 3]`` world points (scene units).
        weights: ``[M]`` non-negative weights summing to 1 (the share of the frustum volume each stands for).
    """

    points: np.ndarray
    weights: np.ndarray


def frustum_samples(
    c2w: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: float,
    height: float,
    radius: float,
    n_dirs: int = DEFAULT_N_DIRS,
    n_depths: int = DEFAULT_N_DEPTHS,
) -> FrustumSamples:
    """Deterministic volume samples of a pinhole camera's frustum, up to distance ``radius`` from its centre.

    Directions go through the centres of an ``n_rows x n_dirs`` grid of cells tiling the image
    (``n_rows = max(1, round(n_dirs * height / width))``); a direction at angle ``theta`` to the optical
    axis is weighted by its cell's solid angle, ``cos(theta)^3``. Along each direction, the distances
    ``t_k = radius * ((k + 0.5) / n_depths)^(1/3)``, ``k = 0..n_depths-1``, are the mid-volume points of
    ``n_depths`` equal-volume spherical shells, so all samples on a direction weigh the same.

    Args:
        c2w: ``[3, 4]`` or ``[4, 4]`` camera-to-world matrix (OpenGL axes, see the module docstring).
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels.
        width, height: image size in pixels.
        radius: sampling radius in scene units (> 0).
        n_dirs: directions across the image width (>= 1).
        n_depths: samples along each direction (>= 1).

    Returns:
        :class:`FrustumSamples` with ``M = n_rows * n_dirs * n_depths`` points, every one inside the image's
        field of view and at a distance in ``(0, radius]`` from the camera centre.
    """
    m = np.asarray(c2w, dtype=np.float64)
    if m.shape not in ((3, 4), (4, 4)):
        raise ValueError(f"c2w must be [3, 4] or [4, 4], got {m.shape}")
    intr = (fx, fy, cx, cy, width, height)
    if not all(math.isfinite(float(v)) for v in intr) or fx == 0 or fy == 0 or width <= 0 or height <= 0:
        raise ValueError(f"bad intrinsics fx={fx}, fy={fy}, cx={cx}, cy={cy}, width={width}, height={height}")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a positive number, got {radius!r}")
    if int(n_dirs) != n_dirs or n_dirs < 1 or int(n_depths) != n_depths or n_depths < 1:
        raise ValueError(f"n_dirs and n_depths must be positive integers, got {n_dirs!r}, {n_depths!r}")
    n_cols, n_rows = int(n_dirs), max(1, round(n_dirs * height / width))
    u = (np.arange(n_cols) + 0.5) * (width / n_cols)
    v = (np.arange(n_rows) + 0.5) * (height / n_rows)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    d_cam = np.stack([(uu - cx) / fx, -(vv - cy) / fy, -np.ones_like(uu)], axis=-1).reshape(-1, 3)
    norm = np.linalg.norm(d_cam, axis=-1)
    d_cam /= norm[:, None]
    dirs = d_cam @ m[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)  # c2w may carry a slight scale
    t = radius * ((np.arange(n_depths) + 0.5) / n_depths) ** (1.0 / 3.0)
    points = m[:3, 3] + dirs[:, None, :] * t[None, :, None]
    w_dir = norm**-3.0  # cos(theta)^3: solid angle of an image cell at angle theta off-axis
    weights = np.repeat(w_dir / (w_dir.sum() * n_depths), n_depths)
    return FrustumSamples(points.reshape(-1, 3), weights)


def view_densities(
    kde: DensityGrid,
    c2ws: np.ndarray,
    fx: float | np.ndarray,
    fy: float | np.ndarray,
    cx: float | np.ndarray,
    cy: float | np.ndarray,
    width: float | np.ndarray,
    height: float | np.ndarray,
    radius: float,
    n_dirs: int = DEFAULT_N_DIRS,
    n_depths: int = DEFAULT_N_DEPTHS,
    mode: Literal["nearest", "trilinear"] = "nearest",
) -> np.ndarray:
    """Mean scene density inside each camera's frustum, within ``radius`` of its centre.

    Args:
        kde: the scene's KDE grid (e.g. from :func:`scene_kde`, normalised to a maximum of 1).
        c2ws: ``[N, 3, 4]`` (or ``[N, 4, 4]``) camera-to-world matrices (OpenGL axes).
        fx, fy, cx, cy, width, height: intrinsics in pixels, scalars or ``[N]`` (any shape with N elements).
        radius: sampling radius in scene units.
        n_dirs, n_depths: quadrature size, see :func:`frustum_samples`.
        mode: grid lookup, see :func:`stealth_ns.attack.density.sample_grid` (the attack uses ``"nearest"``).

    Returns:
        ``[N]`` float64 volume-weighted mean KDE value per camera (in the KDE's units; ``[0, 1]`` for a
        normalised KDE).
    """
    from stealth_ns.attack.density import sample_grid

    c2ws = np.asarray(c2ws, dtype=np.float64)
    if c2ws.ndim != 3 or c2ws.shape[1:] not in ((3, 4), (4, 4)):
        raise ValueError(f"c2ws must be [N, 3, 4] or [N, 4, 4], got {c2ws.shape}")
    n = c2ws.shape[0]
    intr = []
    for name, value in zip(
        ("fx", "fy", "cx", "cy", "width", "height"), (fx, fy, cx, cy, width, height), strict=True
    ):
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
        if arr.size not in (1, n):
            raise ValueError(f"{name} must be a scalar or have {n} values, got {arr.size}")
        intr.append(np.broadcast_to(arr, (n,)))
    out = np.empty(n, dtype=np.float64)
    for i in range(n):
        params = [float(a[i]) for a in intr]
        samples = frustum_samples(c2ws[i], *params, radius=radius, n_dirs=n_dirs, n_depths=n_depths)
        out[i] = float(np.dot(sample_grid(kde, samples.points, mode=mode), samples.weights))
    return out


def rank(densities: np.ndarray) -> tuple[int, int, int]:
    """The Easy, Median and Hard views of a list of view densities.

    Views are sorted ascending by ``(density, position)``, so ties go to the earlier view in the ascending
    order (a stable sort). Easy is the first (minimum density), Hard the last (maximum), Median the one at
    position ``(N - 1) // 2`` of the sorted list (the lower median for even ``N``).

    Args:
        densities: ``[N]`` finite view densities, ``N >= 1``.

    Returns:
        ``(easy, median, hard)`` positions into ``densities``.
    """
    d = np.asarray(densities, dtype=np.float64)
    if d.ndim != 1 or d.size == 0:
        raise ValueError(f"densities must be a non-empty 1-D array, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError("densities contain non-finite values")
    order = np.argsort(d, kind="stable")
    return int(order[0]), int(order[(d.size - 1) // 2]), int(order[-1])


def bbox_diagonal(points: np.ndarray) -> float:
    """Length of the diagonal of the axis-aligned bounding box of ``[N, 3]`` points (scene units)."""
    pts = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def scene_kde(
    points: np.ndarray,
    grid_resolution: int = DEFAULT_GRID_RESOLUTION,
    voxel_size: float | None = None,
    bandwidth: float = DEFAULT_BANDWIDTH,
) -> DensityGrid:
    """Normalised KDE of a point cloud, every point weighing 1 (the attack's density, §3.3).

    Args:
        points: ``[N, 3]`` scene points (scene units).
        grid_resolution: voxels along the longest side of the points' bounding box (used when
            ``voxel_size`` is None).
        voxel_size: voxel edge in scene units, or None.
        bandwidth: Gaussian kernel standard deviation in voxels.

    Returns:
        The KDE as a :class:`~stealth_ns.attack.density.DensityGrid` with values in ``[0, 1]``.
    """
    from stealth_ns.attack.density import gaussian_kde_grid, voxel_density

    pts = np.asarray(points, dtype=np.float64)
    ones = np.ones(len(pts), dtype=np.float64)
    if voxel_size is not None:
        grid = voxel_density(pts, ones, voxel_size=voxel_size)
    else:
        grid = voxel_density(pts, ones, resolution=grid_resolution)
    return gaussian_kde_grid(grid, bandwidth, normalize=True)
