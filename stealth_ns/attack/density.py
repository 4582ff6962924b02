"""Voxel density of a Gaussian point cloud and its Gaussian kernel density estimate (KDE).

Paper section 3.3: the axis-aligned bounding box (AABB) of the Gaussian cloud ``G`` is voxelised into a
uniform grid ``S``; each voxel ``s`` holds the density ``rho(s) = sum_{g in s} alpha(g)`` (the opacities of
the Gaussians whose centres fall in it), and the continuous density is the KDE

    f(x) = 1/|S| * sum_s K_h(x - c(s)) * rho(s),   K_h = isotropic Gaussian of bandwidth h,

evaluated at the voxel centres ``c(s)``, which is a Gaussian smoothing of the grid. As in the authors'
code the bandwidth ``h`` is in *voxel* units and the KDE is normalised by its maximum (paper default
``h = 7.5``).

Conventions: world coordinates are in scene units; a grid of shape ``(X, Y, Z)`` covers the box
``[origin, origin + shape * voxel_size]``; voxel ``(i, j, k)`` covers
``origin + [i, i+1) x [j, j+1) x [k, k+1) * voxel_size`` and its centre is
``origin + (i + 0.5, j + 0.5, k + 0.5) * voxel_size``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypeVar

import numpy as np
import torch
from scipy import ndimage

from stealth_ns.foundation.json_io import write_npz_atomic

__all__ = [
    "DensityGrid",
    "voxel_density",
    "gaussian_kde_grid",
    "sample_grid",
    "load_density_npz",
]

ArrayT = TypeVar("ArrayT", np.ndarray, torch.Tensor)

#: Refuse to allocate grids with more voxels than this (float32: 1 GiB).
MAX_VOXELS = 2**28

_NPZ_RESERVED = ("values", "origin", "voxel_size")


@dataclass(frozen=True, eq=False)
class DensityGrid:
    """A scalar field sampled on a regular voxel grid.

    Attributes:
        values: ``[X, Y, Z]`` float32, one value per voxel (density, KDE, ...).
        origin: ``[3]`` float64, world coordinate (scene units) of the outer corner of voxel ``(0, 0, 0)``.
        voxel_size: edge length of a (cubic) voxel, in scene units.
    """

    values: np.ndarray
    origin: np.ndarray
    voxel_size: float

    def __post_init__(self) -> None:
        values = np.asarray(self.values, dtype=np.float32)
        origin = np.asarray(self.origin, dtype=np.float64).reshape(-1)
        if values.ndim != 3:
            raise ValueError(f"DensityGrid.values must be 3-D [X, Y, Z], got shape {values.shape}")
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"DensityGrid.origin must be 3 finite numbers, got {self.origin!r}")
        voxel_size = float(self.voxel_size)
        if not (math.isfinite(voxel_size) and voxel_size > 0):
            raise ValueError(f"DensityGrid.voxel_size must be a positive number, got {self.voxel_size!r}")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "voxel_size", voxel_size)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Number of voxels along x, y, z."""
        return tuple(int(n) for n in self.values.shape)  # type: ignore[return-value]

    @property
    def upper(self) -> np.ndarray:
        """``[3]`` world coordinate of the far corner of the grid (``origin + shape * voxel_size``)."""
        return self.origin + np.asarray(self.shape, dtype=np.float64) * self.voxel_size

    def centers(self) -> np.ndarray:
        """World coordinates of all voxel centres, ``[X, Y, Z, 3]`` float64 (scene units).

        Allocates ``24 * X * Y * Z`` bytes; prefer :meth:`world_to_index` / :func:`sample_grid` on big grids.
        """
        axes = [
            self.origin[a] + (np.arange(n, dtype=np.float64) + 0.5) * self.voxel_size
            for a, n in enumerate(self.shape)
        ]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def world_to_index(self, x: np.ndarray) -> np.ndarray:
        """Integer index of the voxel containing each world point.

        Args:
            x: ``[..., 3]`` world points (scene units).

        Returns:
            ``[..., 3]`` int64 ``floor((x - origin) / voxel_size)``, *not* clipped: points outside the grid
            give indices outside ``[0, shape)``.
        """
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1:] != (3,):
            raise ValueError(f"points must have shape [..., 3], got {x.shape}")
        return np.floor((x - self.origin) / self.voxel_size).astype(np.int64)

    def with_values(self, values: np.ndarray) -> DensityGrid:
        """A grid with the same geometry (origin, voxel size) and new ``[X, Y, Z]`` values."""
        values = np.asarray(values)
        if values.shape != self.values.shape:
            raise ValueError(f"values of shape {values.shape} do not match the grid shape {self.shape}")
        return DensityGrid(values=values, origin=self.origin, voxel_size=self.voxel_size)

    def save_npz(self, path: str | Path, extras: Mapping[str, np.ndarray] | None = None) -> Path:
        """Save the grid (and optional extra arrays, e.g. ``{"kde": kde.values}``) to a compressed ``.npz``.

        Keys written: ``values``, ``origin``, ``voxel_size`` and every key of ``extras`` (which must not use
        those three names). Parent directories are created. Returns the path written.
        """
        path = Path(path)
        extras = dict(extras or {})
        clash = sorted(set(extras) & set(_NPZ_RESERVED))
        if clash:
            raise ValueError(f"extra array names {clash} clash with the grid's own keys {_NPZ_RESERVED}")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {"values": self.values, "origin": self.origin, "voxel_size": np.float64(self.voxel_size)}
        write_npz_atomic(path, {**arrays, **{k: np.asarray(v) for k, v in extras.items()}})
        return path

    @classmethod
    def load_npz(cls, path: str | Path) -> DensityGrid:
        """Load a grid written by :meth:`save_npz` (extras ignored; see :func:`load_density_npz`)."""
        return load_density_npz(path)[0]


def load_density_npz(path: str | Path) -> tuple[DensityGrid, dict[str, np.ndarray]]:
    """Load a grid written by :meth:`DensityGrid.save_npz` together with its extra arrays (by key)."""
    with np.load(Path(path), allow_pickle=False) as data:
        missing = [k for k in _NPZ_RESERVED if k not in data.files]
        if missing:
            raise ValueError(f"{path}: not a density grid file (missing {missing})")
        grid = DensityGrid(values=data["values"], origin=data["origin"], voxel_size=float(data["voxel_size"]))
        extras = {k: data[k] for k in data.files if k not in _NPZ_RESERVED}
    return grid, extras


def voxel_density(
    points: np.ndarray,
    weights: np.ndarray,
    voxel_size: float | None = None,
    resolution: int | None = None,
    padding_voxels: int = 0,
) -> DensityGrid:
    """Per-voxel density ``rho(s) = sum of the weights (opacities) of the points in voxel s``.

    The grid covers the AABB ``[min(points), max(points)]`` of the points, grown by ``padding_voxels`` empty
    voxels on every side. Exactly one of ``voxel_size`` and ``resolution`` must be given:

    * ``voxel_size`` (scene units): the grid has ``max(1, ceil(extent / voxel_size))`` voxels per axis
      (plus padding), so it may overhang the AABB by less than one voxel at the far end;
    * ``resolution``: the *unpadded* longest AABB side is split into exactly ``resolution`` voxels
      (``voxel_size = longest_extent / resolution``); the other axes get ``ceil(extent / voxel_size)``.

    Voxels are half-open ``[lo, hi)``; points lying exactly on the far face of the grid (the AABB maximum,
    up to rounding) are counted in the last voxel.

    Args:
        points: ``[N, 3]`` float Gaussian centres (scene units), ``N >= 1``, all finite.
        weights: ``[N]`` non-negative finite weights, the opacity ``alpha(g)`` of each Gaussian
            (e.g. ``sigmoid(opacity_logit)``, optionally times its visibility).
        voxel_size: voxel edge length in scene units (the authors used 0.1 in their scenes).
        resolution: voxels along the longest side of the AABB.
        padding_voxels: empty voxels added on every side (>= 0).

    Returns:
        A :class:`DensityGrid` with float32 ``values`` (sums accumulated in float64).

    Raises:
        ValueError: both or neither of ``voxel_size``/``resolution``, non-positive values, empty input,
            non-finite points/weights, negative weights, mismatched shapes, a degenerate AABB (all points
            equal) with ``resolution``, or a grid of more than :data:`MAX_VOXELS` voxels.
    """
    pts = np.asarray(points, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape [N, 3], got {pts.shape}")
    if pts.shape[0] == 0:
        raise ValueError("cannot voxelise an empty point cloud (0 points)")
    if w.shape != (pts.shape[0],):
        raise ValueError(f"weights must have shape [N] = [{pts.shape[0]}], got {w.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(
            f"points contain {int((~np.isfinite(pts)).any(axis=1).sum())} non-finite (NaN/inf) rows"
        )
    if not np.all(np.isfinite(w)):
        raise ValueError("weights contain non-finite (NaN/inf) values")
    if np.any(w < 0):
        raise ValueError("weights (opacities) must be non-negative")
    if (voxel_size is None) == (resolution is None):
        raise ValueError(
            "give exactly one of voxel_size (scene units) or resolution (voxels along the longest side)"
        )
    if int(padding_voxels) != padding_voxels or padding_voxels < 0:
        raise ValueError(f"padding_voxels must be a non-negative integer, got {padding_voxels!r}")
    pad = int(padding_voxels)

    lo = pts.min(axis=0)
    extent = pts.max(axis=0) - lo
    if voxel_size is not None:
        vs = float(voxel_size)
        if not (math.isfinite(vs) and vs > 0):
            raise ValueError(f"voxel_size must be a positive number, got {voxel_size!r}")
    else:
        if isinstance(resolution, bool) or int(resolution) != resolution or resolution < 1:  # type: ignore[arg-type]
            raise ValueError(f"resolution must be a positive integer, got {resolution!r}")
        longest = float(extent.max())
        if longest <= 0:
            raise ValueError("all points coincide (zero-size AABB): give voxel_size instead of resolution")
        vs = longest / int(resolution)  # type: ignore[arg-type]

    # ceil with a relative tolerance so that extent == k * voxel_size gives k voxels, not k + 1.
    core = np.maximum(1, np.ceil(extent / vs - 1e-9).astype(np.int64))
    shape = core + 2 * pad
    n_vox = int(np.prod(shape))
    if n_vox > MAX_VOXELS:
        raise ValueError(
            f"a grid of {shape[0]}x{shape[1]}x{shape[2]} voxels is too large (> {MAX_VOXELS}): "
            "increase voxel_size or lower resolution"
        )
    origin = lo - pad * vs
    idx = np.floor((pts - lo) / vs).astype(np.int64)
    idx = np.clip(idx, 0, core - 1) + pad
    flat = np.ravel_multi_index((idx[:, 0], idx[:, 1], idx[:, 2]), tuple(shape))
    values = np.bincount(flat, weights=w, minlength=n_vox).reshape(tuple(shape))
    return DensityGrid(values=values.astype(np.float32), origin=origin, voxel_size=vs)


def gaussian_kde_grid(
    grid: DensityGrid, bandwidth_voxels: float, normalize: bool = True, truncate: float = 4.0
) -> DensityGrid:
    """Gaussian KDE of a density grid evaluated at the voxel centres (paper eq. 2-3).

    ``f(c(s)) = 1/|S| sum_s' K_h(c(s) - c(s')) rho(s')`` is a discrete convolution of the grid with a
    Gaussian of standard deviation ``h = bandwidth_voxels`` voxels, computed as
    ``scipy.ndimage.gaussian_filter(rho, sigma=h, mode="constant", cval=0, truncate=truncate)`` in float64:

    * ``mode="constant"``: density is zero outside the grid (nothing is reflected back in at the faces);
    * ``truncate``: the kernel is cut at ``truncate * h`` voxels (scipy's default 4.0; radius
      ``int(truncate * h + 0.5)``) and renormalised to sum to 1, so values further than that from every
      occupied voxel are exactly 0;
    * the constant factors ``1/|S|`` and ``(2 pi h^2)^(-3/2)`` are dropped: unnormalised values are the
      mass-preserving smoothing (``f ~= result / (|S| * voxel_size^3)`` with ``h`` in voxels); with
      ``normalize=True`` (the authors' choice) the result is divided by its maximum, so it lies in ``[0, 1]``
      and any constant factor is irrelevant. An all-zero grid stays all zero.

    Args:
        grid: the per-voxel density from :func:`voxel_density`.
        bandwidth_voxels: kernel standard deviation ``h`` in voxels (>= 0; 0 = no smoothing; paper 7.5).
        normalize: divide by the maximum.
        truncate: kernel radius in standard deviations.

    Returns:
        A :class:`DensityGrid` with the same geometry and float32 KDE values.
    """
    h = float(bandwidth_voxels)
    if not (math.isfinite(h) and h >= 0):
        raise ValueError(f"bandwidth_voxels must be a non-negative number, got {bandwidth_voxels!r}")
    if not (math.isfinite(truncate) and truncate > 0):
        raise ValueError(f"truncate must be a positive number, got {truncate!r}")
    values = grid.values.astype(np.float64)
    if h > 0:
        values = ndimage.gaussian_filter(values, sigma=h, mode="constant", cval=0.0, truncate=truncate)
    if normalize:
        peak = float(values.max()) if values.size else 0.0
        if peak > 0:
            values = values / peak
    return grid.with_values(values.astype(np.float32))


def _sample_torch(
    values: torch.Tensor,
    origin: torch.Tensor,
    voxel_size: float,
    points: torch.Tensor,
    mode: str,
    outside: float,
) -> torch.Tensor:
    """Core of :func:`sample_grid` on torch tensors (``values`` [X,Y,Z], ``points`` [..., 3])."""
    shape = torch.tensor(values.shape, device=points.device)
    u = (points - origin) / voxel_size  # continuous voxel coordinates; voxel i spans [i, i+1)
    inside = ((u >= 0) & (u <= shape.to(u.dtype))).all(dim=-1)
    if mode == "nearest":
        idx = torch.minimum(torch.floor(u).clamp_min(0).long(), shape - 1)
        out = values[idx[..., 0], idx[..., 1], idx[..., 2]].to(points.dtype)
    else:  # trilinear between voxel centres (at u = i + 0.5), neighbours clamped into the grid
        c = u - 0.5
        i0 = torch.floor(c)
        frac = c - i0
        i0 = i0.long()
        out = torch.zeros(points.shape[:-1], dtype=points.dtype, device=points.device)
        for dx in (0, 1):
            wx = frac[..., 0] if dx else 1 - frac[..., 0]
            ix = torch.clamp(i0[..., 0] + dx, 0, values.shape[0] - 1)
            for dy in (0, 1):
                wy = frac[..., 1] if dy else 1 - frac[..., 1]
                iy = torch.clamp(i0[..., 1] + dy, 0, values.shape[1] - 1)
                for dz in (0, 1):
                    wz = frac[..., 2] if dz else 1 - frac[..., 2]
                    iz = torch.clamp(i0[..., 2] + dz, 0, values.shape[2] - 1)
                    out = out + wx * wy * wz * values[ix, iy, iz].to(points.dtype)
    return torch.where(inside, out, torch.full_like(out, outside))


def sample_grid(
    grid: DensityGrid,
    points: ArrayT,
    mode: Literal["nearest", "trilinear"] = "nearest",
    outside: float = 0.0,
) -> ArrayT:
    """Look up a grid at world points.

    Args:
        grid: the grid (typically the normalised KDE).
        points: ``[..., 3]`` world points (scene units), numpy array or torch tensor (any device).
        mode: ``"nearest"``: the value of the voxel containing the point (the authors' lookup);
            ``"trilinear"``: trilinear interpolation between voxel centres, with neighbour indices clamped
            into the grid (so between the outermost centres and the grid faces the value is extrapolated
            flat, and matches ``"nearest"`` on the faces).
        outside: value of points outside the closed box ``[origin, upper]`` (default 0: empty space is the
            least dense, as in the authors' code).

    Returns:
        ``[...]`` values, same array type (and torch device) as ``points``: float64 for numpy input,
        the points' floating dtype for torch input.
    """
    if mode not in ("nearest", "trilinear"):
        raise ValueError(f"mode must be 'nearest' or 'trilinear', got {mode!r}")
    is_numpy = not isinstance(points, torch.Tensor)
    pts = torch.from_numpy(np.asarray(points, dtype=np.float64)) if is_numpy else points
    if pts.shape[-1:] != (3,):
        raise ValueError(f"points must have shape [..., 3], got {tuple(pts.shape)}")
    if not torch.is_floating_point(pts):
        pts = pts.double()
    values = torch.from_numpy(grid.values).to(pts.device)
    origin = torch.as_tensor(grid.origin, dtype=pts.dtype, device=pts.device)
    out = _sample_torch(values, origin, grid.voxel_size, pts, mode, float(outside))
    return out.numpy() if is_numpy else out  # type: ignore[return-value]
