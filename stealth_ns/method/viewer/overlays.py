"""The panel's 3D overlays as point clouds: poison centres and the injection's KDE as coloured voxels.

Everything here is in nerfstudio's scene units; :mod:`stealth_ns.method.viewer.scene` draws it in viser units.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from stealth_ns.attack.density import DensityGrid, load_density_npz
from stealth_ns.attack.record import DENSITY_GRID_FILE
from stealth_ns.images.io import to_uint8
from stealth_ns.method.viewer.source import PanelError


def poison_centres(means: torch.Tensor | np.ndarray, tags: torch.Tensor | np.ndarray) -> np.ndarray:
    """Centres of the poison Gaussians.

    Args:
        means: ``[N, 3]`` Gaussian centres, scene units.
        tags: ``[N]`` poison tag (``> 0.5`` = poison) or bool mask.

    Returns:
        ``[P, 3]`` float32 centres of the poison Gaussians, scene units.
    """
    m = means.detach().cpu().numpy() if isinstance(means, torch.Tensor) else np.asarray(means)
    t = tags.detach().cpu().numpy() if isinstance(tags, torch.Tensor) else np.asarray(tags)
    return m[t.astype(np.float32) > 0.5].astype(np.float32).reshape(-1, 3)


def density_colors(values: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """Colour ``[M]`` densities with matplotlib's ``turbo`` map -> ``[M, 3]`` uint8 (vmin blue, vmax red)."""
    import matplotlib

    span = max(float(vmax) - float(vmin), 1e-12)
    t = np.clip((np.asarray(values, dtype=np.float64) - vmin) / span, 0.0, 1.0)
    rgba = matplotlib.colormaps["turbo"](0.1 + 0.9 * t)  # turbo's first tenth is too dark to read
    return to_uint8(rgba[:, :3])


@dataclass(frozen=True)
class VoxelCloud:
    """Thresholded KDE voxels as a point cloud.

    Attributes:
        points: ``[M, 3]`` float32 voxel centres, scene units.
        colors: ``[M, 3]`` uint8 (turbo colour map from the threshold to the maximum).
        n_above: number of voxels at or above the threshold (``M`` is smaller when subsampled).
        voxel_size: voxel edge, scene units.
    """

    points: np.ndarray
    colors: np.ndarray
    n_above: int
    voxel_size: float


def kde_voxel_cloud(
    grid: DensityGrid,
    kde: np.ndarray | None = None,
    threshold: float = 0.5,
    max_points: int = 50_000,
    seed: int = 0,
) -> VoxelCloud:
    """Voxels whose KDE is at least ``threshold`` times its maximum, coloured by KDE.

    Args:
        grid: the density grid's geometry (origin, voxel size) and, when ``kde`` is None, its values.
        kde: ``[X, Y, Z]`` KDE values on the grid (the ``kde`` extra of ``density_grid.npz``).
        threshold: fraction of the maximum, in ``[0, 1]``.
        max_points: at most this many voxels are returned (a deterministic uniform subsample).
        seed: seed of the subsample.

    Returns:
        The :class:`VoxelCloud` (empty when the KDE is zero everywhere).
    """
    values = grid.values if kde is None else np.asarray(kde, dtype=np.float32)
    if values.shape != grid.shape:
        raise ValueError(f"KDE of shape {values.shape} does not match the grid {grid.shape}")
    vmax = float(values.max()) if values.size else 0.0
    if not vmax > 0.0:
        return VoxelCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), 0, grid.voxel_size)
    cut = float(np.clip(threshold, 0.0, 1.0)) * vmax
    idx = np.argwhere(values >= cut)
    n_above = int(idx.shape[0])
    if n_above > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(n_above, size=max_points, replace=False))
        idx = idx[keep]
    points = grid.origin + (idx + 0.5) * grid.voxel_size
    colors = density_colors(values[tuple(idx.T)], cut, vmax)
    return VoxelCloud(points.astype(np.float32), colors, n_above, grid.voxel_size)


class KdeVoxels:
    """Thresholded KDE voxels of a run's ``<attack>/density_grid.npz``, cached per file and threshold."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, float, float], VoxelCloud] = {}

    def clear(self) -> None:
        """Forget the cached cloud (the file is read again next time)."""
        self._cache.clear()

    def cloud(self, attack_dir: Path | None, threshold: float) -> VoxelCloud:
        """The voxels at or above ``threshold`` times the KDE's maximum (see :func:`kde_voxel_cloud`).

        Raises:
            PanelError: no attack folder, no ``density_grid.npz`` in it (written at the injection step) or
                an unreadable one.
        """
        path = None if attack_dir is None else attack_dir / DENSITY_GRID_FILE
        if path is None or not path.exists():
            raise PanelError(f"no KDE: {path} does not exist (it is written at the injection step)")
        key = (str(path), path.stat().st_mtime, round(threshold, 4))
        if key not in self._cache:
            try:
                grid, extras = load_density_npz(path)
            except (OSError, ValueError) as err:
                raise PanelError(f"cannot read {path}: {err}") from err
            self._cache.clear()
            self._cache[key] = kde_voxel_cloud(grid, extras.get("kde"), threshold)
        return self._cache[key]
