"""The open3d calls of a training run, for the offline GPU machine only (see README.md beside this).

open3d's wheel (400 MB; 105 MB CPU-only) cannot travel to that machine, which takes 64 MiB. These are
the calls a training, its attack and a scan make (nerfstudio's seed-point reader, our injection's
outlier removal and poison PLY): PLY I/O through plyfile, the statistical outlier removal after
open3d's definition (the k nearest neighbours including the point itself, their mean distance, a
point kept when that is at most the cloud's mean plus ``std_ratio`` sample deviations). Its result
may differ from open3d's in ties, so poison placement on that machine is not bitwise a CPU run's.
``prepare.sh`` copies it to ``.gpu/shim/open3d/__init__.py``; it is never installed or imported here.
"""

from __future__ import annotations

import types

import numpy as np
from plyfile import PlyData, PlyElement
from scipy.spatial import cKDTree


def _vector3d(a):
    return np.asarray(a, dtype=np.float64).reshape(-1, 3)


class PointCloud:
    def __init__(self, points=None):
        self.points = _vector3d(points if points is not None else np.zeros((0, 3)))
        self.colors = np.zeros((0, 3))

    def remove_statistical_outlier(self, nb_neighbors: int, std_ratio: float):
        k = min(nb_neighbors, len(self.points))
        dist, _ = cKDTree(self.points).query(self.points, k=k)
        mean = dist.reshape(len(self.points), -1).mean(1)
        keep = np.flatnonzero(mean <= mean.mean() + std_ratio * mean.std(ddof=1))
        out = PointCloud(self.points[keep])
        return out, list(keep)


def read_point_cloud(path: str) -> PointCloud:
    v = PlyData.read(path)["vertex"].data
    cloud = PointCloud(np.stack([v["x"], v["y"], v["z"]], 1))
    if "red" in v.dtype.names:
        rgb = np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float64)
        cloud.colors = rgb / 255.0 if v["red"].dtype == np.uint8 else rgb
    return cloud


def write_point_cloud(path: str, cloud: PointCloud) -> bool:
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    has_rgb = len(cloud.colors) == len(cloud.points) and len(cloud.points) > 0
    if has_rgb:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rows = np.empty(len(cloud.points), dtype=fields)
    for i, c in enumerate("xyz"):
        rows[c] = cloud.points[:, i]
    if has_rgb:
        rgb = np.clip(np.round(np.asarray(cloud.colors) * 255), 0, 255).astype(np.uint8)
        for i, c in enumerate(("red", "green", "blue")):
            rows[c] = rgb[:, i]
    PlyData([PlyElement.describe(rows, "vertex")]).write(path)
    return True


geometry = types.SimpleNamespace(PointCloud=PointCloud)
utility = types.SimpleNamespace(Vector3dVector=_vector3d)
io = types.SimpleNamespace(read_point_cloud=read_point_cloud, write_point_cloud=write_point_cloud)
