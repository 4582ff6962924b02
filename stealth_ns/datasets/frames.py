"""The world frames a dataset's models can be in, and how each maps into nerfstudio's normalised frame.

nerfstudio trains in a frame of its own: its dataparser orients and centres the poses and scales them
into a unit box, ``p_ns = s * (T @ [p, 1])`` with ``T`` the ``dataparser_transform`` (3 x 4) and ``s``
the ``dataparser_scale``. Models from other trainers are in a frame of the dataset instead:

=============  ======================================================================================
frame          what is in it
=============  ======================================================================================
nerfstudio     nerfstudio's runs and ``ns-export gaussian-splat`` PLYs (exported as trained)
dataset        the frame of the dataset's own poses and seed points: a Blender or nerfstudio-data
               ``transforms.json``'s, a COLMAP model's. The official 3DGS code trains in it (it
               reads the poses as given), OpenSplat with ``--keep-crs`` and gsplat's
               ``simple_trainer`` with ``--no-normalize-world-space`` (by default both normalise)
colmap         (nerfstudio-data converted from COLMAP by ``ns-process-data``, which records an
               ``applied_transform``) the original COLMAP model's frame, for a model trained on the
               ``colmap/sparse/0`` the conversion kept
=============  ======================================================================================

nerfstudio-data's dataparser composes the ``applied_transform`` A into ``T`` (``T = T' @ A``) while
the poses and the seed PLY are already in the applied frame, so the dataset frame maps by ``T' =
T @ A^-1`` and the COLMAP frame by ``T``.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from stealth_ns.datasets.source import SceneSource

FRAMES: tuple[str, ...] = ("nerfstudio", "dataset", "colmap")

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
    return frame_transforms(outputs, scene)["dataset"]


def frame_transforms(outputs: Any, scene: SceneSource) -> dict[str, np.ndarray]:
    """Each frame of :data:`FRAMES` the dataset has -> the ``[4, 4]`` similarity taking its points into
    nerfstudio's frame (``nerfstudio``: the identity; ``colmap`` only with an ``applied_transform``)."""
    m = np.vstack([np.asarray(outputs.dataparser_transform, dtype=np.float64), [0, 0, 0, 1]])
    scale = np.diag([float(outputs.dataparser_scale)] * 3 + [1.0])
    out = {"nerfstudio": np.eye(4)}
    applied = applied_transform(scene)
    if applied is None:
        out["dataset"] = scale @ m
    else:
        out["dataset"] = scale @ m @ np.linalg.inv(applied)
        out["colmap"] = scale @ m
    return out
