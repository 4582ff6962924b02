"""The GPU check's open3d stand-in (``scripts/gpu_check/open3d_standin.py``, used only on the
offline device machine) gives what open3d gives for the calls a training makes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

STANDIN = Path(__file__).resolve().parents[1] / "scripts" / "gpu_check" / "open3d_standin.py"


@pytest.fixture(scope="module")
def standin():
    spec = importlib.util.spec_from_file_location("open3d_standin", STANDIN)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _points(n: int, seed: int = 0) -> np.ndarray:
    """[n + n/20, 3] a unit blob with a sparse wide halo (the outliers)."""
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.normal(size=(n, 3)), rng.normal(size=(n // 20, 3)) * 8])


@pytest.mark.parametrize("n", [40, 3000])
def test_outlier_removal_keeps_the_points_open3d_keeps(standin, n):
    points = _points(n)
    _, expected = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).remove_statistical_outlier(
        nb_neighbors=20, std_ratio=2.0
    )
    _, got = standin.geometry.PointCloud(standin.utility.Vector3dVector(points)).remove_statistical_outlier(
        nb_neighbors=20, std_ratio=2.0
    )
    assert len(expected) < len(points)  # the halo lost points
    assert sorted(got) == sorted(expected)


def test_ply_files_read_and_written_as_open3d_does(standin, tmp_path):
    points = _points(200)
    colors = np.random.default_rng(1).uniform(size=points.shape)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.colors = o3d.utility.Vector3dVector(colors)
    o3d.io.write_point_cloud(str(tmp_path / "open3d.ply"), cloud)
    read = standin.io.read_point_cloud(str(tmp_path / "open3d.ply"))
    np.testing.assert_array_equal(read.points, points)
    np.testing.assert_allclose(read.colors, colors, atol=0.5 / 255 + 1e-9)  # 8-bit colours

    ours = standin.geometry.PointCloud(standin.utility.Vector3dVector(points))
    ours.colors = standin.utility.Vector3dVector(colors)
    standin.io.write_point_cloud(str(tmp_path / "standin.ply"), ours)
    back = o3d.io.read_point_cloud(str(tmp_path / "standin.ply"))
    np.testing.assert_array_equal(np.asarray(back.points), points)
    np.testing.assert_array_equal(np.asarray(back.colors), np.asarray(read.colors))
