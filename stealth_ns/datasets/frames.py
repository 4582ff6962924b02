"""The world frames a dataset's models can be in, and how each maps into nerfstudio's normalised frame.

nerfstudio trains in a frame of its own: its dataparser orients and centres the poses and scales them
into a unit box, ``p_ns = s * (T @ [p, 1])`` with ``T`` the ``dataparser_transform`` (3 x 4) and ``s``
the ``dataparser_scale``. Models from other trainers are in a frame of the dataset instead:

=================  ==================================================================================
frame              what is in it
=================  ==================================================================================
nerfstudio         nerfstudio's runs and ``ns-export gaussian-splat`` PLYs (exported as trained)
dataset            the frame of the dataset's own poses and seed points: a Blender or nerfstudio-data
                   ``transforms.json``'s, a COLMAP model's. The official 3DGS code trains in it (it
                   reads the poses as given), OpenSplat without ``--center`` (it writes its PLY back
                   in the input's frame) and gsplat's ``simple_trainer`` with
                   ``--no-normalize-world-space``
colmap             (nerfstudio-data converted from COLMAP by ``ns-process-data``, which records an
                   ``applied_transform``) the original COLMAP model's frame, for a model trained on the
                   ``colmap/sparse/0`` the conversion kept
opensplat-center   OpenSplat's with ``--center``: the dataset frame centred on the cameras' mean
                   position and scaled into [-1, 1]
gsplat-normalized  gsplat ``simple_trainer``'s by default (``normalize_world_space``), computed from the
                   COLMAP model's cameras and points (the ``colmap`` frame's when the dataset has one,
                   else the dataset frame's)
=================  ==================================================================================

The two trainer frames are recomputed from the dataset's files (every camera, the seed points), as
the trainers compute them (:mod:`stealth_ns.datasets.trainer_frames`); neither is offered for a
Blender dataset (neither trainer reads one), gsplat's not without seed points.

nerfstudio-data's dataparser composes the ``applied_transform`` A into ``T`` (``T = T' @ A``) while
the poses and the seed PLY are already in the applied frame, so the dataset frame maps by ``T' =
T @ A^-1`` and the COLMAP frame by ``T``.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from stealth_ns.datasets.source import SceneSource
from stealth_ns.datasets.trainer_frames import (
    dataset_views,
    gsplat_normalization,
    opensplat_center,
    transform_points,
)

FRAMES: tuple[str, ...] = ("nerfstudio", "dataset", "colmap", "opensplat-center", "gsplat-normalized")

#: The axis change ``ns-process-data`` applies to a COLMAP model (implied by a ``colmap/sparse/0`` folder
#: next to a transforms.json that records none).
COLMAP_APPLIED = [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0]]


def applied_transform(scene: SceneSource) -> np.ndarray | None:
    """``[4, 4]`` the ``applied_transform`` of a nerfstudio-data folder (recorded in transforms.json, or
    implied by a ``colmap/sparse/0`` folder); None for other formats or when there is none."""
    if scene.format != "nerfstudio-data" or scene.path is None:
        return None
    meta = json.loads((scene.path / "transforms.json").read_text(encoding="utf-8"))
    applied = meta.get("applied_transform")
    if applied is None and (scene.path / "colmap" / "sparse" / "0").exists():
        applied = COLMAP_APPLIED
    return None if applied is None else np.vstack([np.asarray(applied, dtype=np.float64), [0, 0, 0, 1]])


def dataset_to_nerfstudio(outputs: Any, scene: SceneSource) -> np.ndarray:
    """``[4, 4]`` similarity taking a point of the dataset frame (its poses' and seed points') into
    nerfstudio's, for the dataparser ``outputs`` of ``scene``."""
    return _dataset_frames(outputs, applied_transform(scene))["dataset"]


def frame_transforms(outputs: Any, scene: SceneSource) -> dict[str, np.ndarray]:
    """Each frame of :data:`FRAMES` the dataset has -> the ``[4, 4]`` similarity taking its points into
    nerfstudio's frame (``nerfstudio``: the identity; ``colmap`` only with an ``applied_transform``;
    the trainer frames as :func:`trainer_frame_transforms` finds them)."""
    applied = applied_transform(scene)
    out = _dataset_frames(outputs, applied)
    out.update(trainer_frame_transforms(scene, out, applied))
    return out


def _dataset_frames(outputs: Any, applied: np.ndarray | None) -> dict[str, np.ndarray]:
    """``nerfstudio``, ``dataset`` and (with an ``applied_transform``) ``colmap`` -> their ``[4, 4]``
    similarity into nerfstudio's frame."""
    m = np.vstack([np.asarray(outputs.dataparser_transform, dtype=np.float64), [0, 0, 0, 1]])
    scale = np.diag([float(outputs.dataparser_scale)] * 3 + [1.0])
    out = {"nerfstudio": np.eye(4)}
    if applied is None:
        out["dataset"] = scale @ m
    else:
        out["dataset"] = scale @ m @ np.linalg.inv(applied)
        out["colmap"] = scale @ m
    return out


def trainer_frame_transforms(
    scene: SceneSource, to_nerfstudio: dict[str, np.ndarray], applied: np.ndarray | None
) -> dict[str, np.ndarray]:
    """``opensplat-center`` and ``gsplat-normalized`` -> the ``[4, 4]`` similarity taking their points
    into nerfstudio's frame, composed with ``to_nerfstudio``'s ``dataset`` (gsplat: ``colmap`` when
    ``applied``, the dataset's ``applied_transform``, is given) transform. Only those the dataset's files
    define: none for a Blender dataset or unreadable files, gsplat's not without seed points, and
    neither when the trainer's transform is no similarity (cameras all in one place, for instance)."""
    try:
        views = dataset_views(scene)
    except (OSError, ValueError, KeyError, IndexError, TypeError, RuntimeError):
        return {}  # nerfstudio read the dataset: these frames are not worth a failed load
    if views is None or len(views.c2w) == 0:
        return {}
    with np.errstate(all="ignore"):
        trainer = {"opensplat-center": ("dataset", opensplat_center(views.c2w))}
        if views.points is not None and len(views.points) >= 3:
            c2w, points, base = views.c2w, views.points, "dataset"
            if applied is not None:  # gsplat reads COLMAP models only: the one the conversion came from
                back = np.linalg.inv(applied)
                c2w = back @ c2w
                points = transform_points(back, points.astype(np.float64)).astype(np.float32)
                base = "colmap"
            trainer["gsplat-normalized"] = (base, gsplat_normalization(c2w, points))
    return {
        name: to_nerfstudio[base] @ np.linalg.inv(m) for name, (base, m) in trainer.items() if _similarity(m)
    }


def _similarity(matrix: np.ndarray) -> bool:
    """Whether ``matrix`` ``[4, 4]`` is finite with a linear part of positive determinant (a similarity
    for the trainers' transforms, which are rotations and uniform scales when not degenerate)."""
    return bool(np.isfinite(matrix).all() and np.linalg.det(matrix[:3, :3]) > 0)
