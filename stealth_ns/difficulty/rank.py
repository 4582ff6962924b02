"""``stealth-ns rank-views``: rank a dataset's training views by the KDE difficulty protocol."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stealth_ns.foundation.errors import StealthNSError

if TYPE_CHECKING:
    pass
from stealth_ns.difficulty.dataset import load_train_split
from stealth_ns.difficulty.protocol import (
    DEFAULT_BANDWIDTH,
    DEFAULT_GRID_RESOLUTION,
    DEFAULT_N_DEPTHS,
    DEFAULT_N_DIRS,
    DEFAULT_RADIUS_FRACTION,
    bbox_diagonal,
    scene_kde,
    view_densities,
)
from stealth_ns.difficulty.ranking import ViewRanking


def rank_scene_views(
    data: Path,
    radius_fraction: float = DEFAULT_RADIUS_FRACTION,
    grid_resolution: int = DEFAULT_GRID_RESOLUTION,
    voxel_size: float | None = None,
    bandwidth: float = DEFAULT_BANDWIDTH,
    outlier_removal: bool = True,
    n_dirs: int = DEFAULT_N_DIRS,
    n_depths: int = DEFAULT_N_DEPTHS,
) -> ViewRanking:
    """Rank a dataset's training views by the KDE difficulty protocol (see the module docstring).

    Args:
        data: a nerfstudio-data folder (``transforms.json`` with ``ply_file_path``; or the json itself) or a
            COLMAP folder (``sparse/0``, ``colmap/sparse/0`` or ``sparse`` with points3D).
        radius_fraction: sampling radius as a fraction of the seed points' bounding-box diagonal.
        grid_resolution: KDE voxels along the longest side of the bounding box (if ``voxel_size`` is None).
        voxel_size: KDE voxel edge in scene units (overrides ``grid_resolution``).
        bandwidth: KDE bandwidth in voxels.
        outlier_removal: drop statistical outliers (20 neighbours, 2 std) before the KDE, as the attack does.
        n_dirs, n_depths: frustum quadrature size (:func:`frustum_samples`).

    Returns:
        The :class:`ViewRanking`; ``.easy``, ``.median``, ``.hard`` are image names.

    Raises:
        StealthNSError: missing or unrecognised dataset, no seed points, bad parameters.
    """
    if not (math.isfinite(radius_fraction) and radius_fraction > 0):
        raise StealthNSError(f"radius fraction must be a positive number, got {radius_fraction!r}")
    if isinstance(grid_resolution, bool) or int(grid_resolution) != grid_resolution or grid_resolution < 1:
        raise StealthNSError(f"grid resolution must be a positive integer, got {grid_resolution!r}")
    if voxel_size is not None and not (math.isfinite(voxel_size) and voxel_size > 0):
        raise StealthNSError(f"voxel size must be a positive number, got {voxel_size!r}")
    if not (math.isfinite(bandwidth) and bandwidth >= 0):
        raise StealthNSError(f"bandwidth must be a non-negative number (voxels), got {bandwidth!r}")
    if min(n_dirs, n_depths) < 1:
        raise StealthNSError(f"n_dirs and n_depths must be at least 1, got {n_dirs} and {n_depths}")

    data = Path(data).expanduser()
    outputs, points, fmt = load_train_split(data)
    points = points[np.all(np.isfinite(points), axis=1)]
    if outlier_removal:
        from stealth_ns.attack.injection import remove_outliers

        points = points[remove_outliers(points)]
    diagonal = bbox_diagonal(points) if len(points) else 0.0
    if not diagonal > 0:
        raise StealthNSError(f"the seed points of {data} all coincide: no scene extent to measure")
    try:
        kde = scene_kde(points, grid_resolution=grid_resolution, voxel_size=voxel_size, bandwidth=bandwidth)
    except ValueError as err:
        raise StealthNSError(f"cannot build the scene KDE: {err}") from None

    from nerfstudio.cameras.cameras import CameraType

    cams = outputs.cameras
    kinds = {int(k) for k in cams.camera_type.reshape(-1).tolist()}
    if kinds != {CameraType.PERSPECTIVE.value}:
        raise StealthNSError(f"{data}: only perspective (pinhole) cameras are supported by this protocol")
    radius = radius_fraction * diagonal
    intr = [
        getattr(cams, k).reshape(-1).double().numpy() for k in ("fx", "fy", "cx", "cy", "width", "height")
    ]
    densities = view_densities(
        kde, cams.camera_to_worlds.double().numpy(), *intr, radius=radius, n_dirs=n_dirs, n_depths=n_depths
    )
    names = [Path(p).name for p in outputs.image_filenames]
    settings = {
        "radius_fraction": radius_fraction,
        "grid_resolution": grid_resolution,
        "voxel_size": voxel_size,
        "kde_voxel_size": kde.voxel_size,
        "kde_shape": list(kde.shape),
        "bandwidth": bandwidth,
        "outlier_removal": outlier_removal,
        "seed_points": len(points),
        "n_dirs": n_dirs,
        "n_depths": n_depths,
    }
    return ViewRanking(
        names=names,
        indices=list(range(len(names))),
        densities=densities,
        radius=radius,
        diagonal=diagonal,
        data=data,
        dataparser=fmt,
        settings=settings,
    )


@dataclass
class RankViews:
    """Rank training views by scene density in their frustum (the paper's Easy/Median/Hard protocol)."""

    data: Path
    """Dataset folder: nerfstudio-data (transforms.json with ply_file_path) or COLMAP (sparse/0, points3D)."""
    output: Path | None = None
    """Folder for view_ranking.json and view_ranking.png (created); default: print the table only."""
    radius_fraction: float = DEFAULT_RADIUS_FRACTION
    """Sampling radius as a fraction of the seed point cloud's bounding-box diagonal (paper: 10%)."""
    grid_resolution: int = DEFAULT_GRID_RESOLUTION
    """KDE voxels along the longest side of the point cloud's bounding box (the attack's default)."""
    voxel_size: float | None = None
    """KDE voxel edge in scene units; overrides --grid-resolution."""
    bandwidth: float = DEFAULT_BANDWIDTH
    """KDE bandwidth h in voxels (the attack's default)."""
    outlier_removal: bool = True
    """Drop statistical outliers (20 neighbours, 2 std) from the seed points first, as the attack does."""
    n_dirs: int = DEFAULT_N_DIRS
    """Frustum samples: directions across the image width (rows follow the aspect ratio)."""
    n_depths: int = DEFAULT_N_DEPTHS
    """Frustum samples: depths per direction, in (0, radius]."""

    def main(self) -> None:
        if self.output is not None and self.output.exists() and not self.output.is_dir():
            raise StealthNSError(f"--output {self.output} exists and is not a folder")
        ranking = rank_scene_views(
            self.data,
            radius_fraction=self.radius_fraction,
            grid_resolution=self.grid_resolution,
            voxel_size=self.voxel_size,
            bandwidth=self.bandwidth,
            outlier_removal=self.outlier_removal,
            n_dirs=self.n_dirs,
            n_depths=self.n_depths,
        )
        print(ranking.table())
        if self.output is not None:
            try:
                json_path, png_path = ranking.save(self.output)
            except OSError as err:
                raise StealthNSError(f"cannot write to {self.output}: {err}") from None
            print(f"Wrote {json_path} and {png_path}")
