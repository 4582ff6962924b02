"""The world frames two popular 3DGS trainers train in by default, recomputed from a dataset's own
cameras and seed points, as each trainer computes them (docs/design/scan.md, "Frames"):

* **OpenSplat** with ``--center`` (``autoScaleAndCenterPoses``): every camera origin ``o_i`` moved by
  their mean ``c`` and scaled by ``f = 1 / max_ij |o_ij - c_j|`` (the largest coordinate, not the
  largest distance), ``p' = f (p - c)``; no rotation. Computed in float32, as OpenSplat does. Without
  ``--center`` OpenSplat writes its PLY back in the input's frame (the ``dataset`` frame).
* **gsplat**'s ``simple_trainer`` (``normalize_world_space=True``, its default; COLMAP input): the
  camera similarity ``T1`` (:func:`gsplat_similarity_from_cameras`), then the rotation ``T2`` onto the
  principal axes of the seed points moved by ``T1`` (:func:`gsplat_align_principal_axes`), then ``T3``,
  a half turn about x when the points' median height is above their mean (:func:`gsplat_normalization`).
  Its PLY is written in that frame.

Cameras are camera-to-world matrices ``[N, 4, 4]`` in OpenCV's convention (x right, y down, z forward:
COLMAP's), as gsplat reads them; OpenSplat uses their origins only.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stealth_ns.datasets.source import SceneSource

#: OpenGL camera axes (nerfstudio-data, Blender: y up, z backward) -> OpenCV's (y down, z forward).
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class DatasetViews:
    """A dataset's cameras and seed points in its own frame, as a trainer reads them from the files."""

    c2w: np.ndarray
    """``[N, 4, 4]`` float64 camera-to-world matrices (OpenCV axes) of every image of the dataset."""
    points: np.ndarray | None
    """``[M, 3]`` float32 seed points (None when the dataset has none)."""


def opensplat_center(c2w: np.ndarray) -> np.ndarray:
    """``[4, 4]`` OpenSplat's ``--center`` similarity ``p' = f (p - c)`` from the cameras ``c2w``
    ``[N, 4, 4]`` (their origins only): ``c`` the mean origin, ``f`` one over the largest absolute
    coordinate of the centred origins, both in float32."""
    origins = np.asarray(c2w)[:, :3, 3].astype(np.float32)
    centre = origins.mean(axis=0, dtype=np.float32)
    f = np.float32(1.0) / np.abs(origins - centre).max()
    out = np.eye(4)
    out[:3, :3] *= float(f)
    out[:3, 3] = -float(f) * centre.astype(np.float64)
    return out


def gsplat_similarity_from_cameras(c2w: np.ndarray) -> np.ndarray:
    """``[4, 4]`` gsplat's ``similarity_from_cameras`` (defaults: median scaling, ``focus`` centre) for
    cameras ``c2w`` ``[N, 4, 4]`` (OpenCV axes): the rotation taking the mean camera up (``-y``) onto
    ``-y``, the translation putting the median of each optical axis's point nearest the origin there,
    and the scale making the cameras' median distance from it 1."""
    t = c2w[:, :3, 3]
    rot = c2w[:, :3, :3]
    world_up = np.mean(np.sum(rot * np.array([0, -1.0, 0]), axis=-1), axis=0)
    world_up /= np.linalg.norm(world_up)
    up_camspace = np.array([0.0, -1.0, 0.0])
    c = (up_camspace * world_up).sum()
    cross = np.cross(world_up, up_camspace)
    skew = np.array([[0.0, -cross[2], cross[1]], [cross[2], 0.0, -cross[0]], [-cross[1], cross[0], 0.0]])
    if c > -1:
        r_align = np.eye(3) + skew + (skew @ skew) * 1 / (1 + c)
    else:  # gsplat's fallback (a reflection: such a frame is no similarity and is not offered)
        r_align = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    rot = r_align @ rot
    fwds = np.sum(rot * np.array([0, 0.0, 1.0]), axis=-1)
    t = (r_align @ t[..., None])[..., 0]
    nearest = t + (fwds * -t).sum(-1)[:, None] * fwds
    translate = -np.median(nearest, axis=0)
    transform = np.eye(4)
    transform[:3, 3] = translate
    transform[:3, :3] = r_align
    transform[:3, :] *= 1.0 / np.median(np.linalg.norm(t + translate, axis=-1))
    return transform


def gsplat_align_principal_axes(points: np.ndarray) -> np.ndarray:
    """``[4, 4]`` gsplat's ``align_principal_axes`` of ``points`` ``[M, 3]``: the rigid motion putting
    their median at the origin and their principal axes (largest variance first) on x, y, z."""
    centroid = np.median(points, axis=0)
    eigenvalues, eigenvectors = np.linalg.eigh(np.cov(points - centroid, rowvar=False))
    eigenvectors = eigenvectors[:, eigenvalues.argsort()[::-1]]
    if np.linalg.det(eigenvectors) < 0:
        eigenvectors[:, 0] *= -1
    transform = np.eye(4)
    transform[:3, :3] = eigenvectors.T
    transform[:3, 3] = -eigenvectors.T @ centroid
    return transform


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``[M, 3]`` ``points`` moved by the ``[4, 4]`` ``matrix`` (gsplat's ``transform_points``)."""
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def gsplat_normalization(c2w: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``[4, 4]`` the similarity gsplat's COLMAP ``Parser(normalize=True)`` applies to cameras ``c2w``
    ``[N, 4, 4]`` (OpenCV axes) and seed points ``[M, 3]`` (float32, as it loads them): ``T3 T2 T1``."""
    t1 = gsplat_similarity_from_cameras(c2w)
    points = transform_points(t1, points)
    t2 = gsplat_align_principal_axes(points)
    points = transform_points(t2, points)
    transform = t2 @ t1
    if np.median(points[:, 2]) > np.mean(points[:, 2]):  # upside down: a half turn about x
        transform = np.diag([1.0, -1.0, -1.0, 1.0]) @ transform
    return transform


def _nerfstudio_views(root: Path) -> DatasetViews:
    meta = json.loads((root / "transforms.json").read_text(encoding="utf-8"))
    c2w = np.stack([_pose(frame["transform_matrix"]) @ OPENGL_TO_OPENCV for frame in meta["frames"]])
    ply = meta.get("ply_file_path")
    points = None
    if ply and (root / str(ply)).is_file():
        from plyfile import PlyData

        vertex = PlyData.read(str(root / str(ply)))["vertex"]
        points = np.stack([vertex[k] for k in ("x", "y", "z")], axis=1).astype(np.float32)
    return DatasetViews(c2w, points)


def _pose(matrix: list) -> np.ndarray:
    out = np.eye(4)
    out[:3] = np.asarray(matrix, dtype=np.float64)[:3, :4]
    return out


def _colmap_views(model: Path) -> DatasetViews:
    import pycolmap  # a dependency of stealth-ns (seed-points, COLMAP copies)

    rec = pycolmap.Reconstruction(str(model))
    c2w = []
    for image in rec.images.values():
        if not getattr(image, "has_pose", True):
            continue
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        c2w.append(np.linalg.inv(_pose(pose.matrix())))
    points = np.array([p.xyz for p in rec.points3D.values()], dtype=np.float32).reshape(-1, 3)
    return DatasetViews(np.stack(c2w), points if len(points) else None)


def dataset_views(scene: SceneSource) -> DatasetViews | None:
    """The cameras and seed points of ``scene`` in its own frame, read from its files: a nerfstudio-data
    transforms.json's frames and ``ply_file_path``, a COLMAP model's images and points3D; None for a
    Blender dataset (neither trainer reads one)."""
    if scene.path is None or scene.format == "blender":
        return None
    if scene.format == "colmap":
        return _colmap_views(scene.path / str(scene.colmap_path))
    return _nerfstudio_views(scene.path)
