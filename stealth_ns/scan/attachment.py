"""Whether a group of flagged Gaussians floats free near its camera or is attached to the scene (pure).

StealthAttack's illusion is drawn by Gaussians placed in the empty space in front of one camera, where
no view has seen anything: nothing of the scene lies near them, and the nearest surface is far behind.
A real object close to a camera (a box beside a walk-through's path) is flagged for the same nearness,
but it stands on the floor or reaches back into the scene: its far part and what it stands on lie
beyond the near line, unflagged, right beside its flagged part.

The *detachment* of a group measures that: for each of its opaque Gaussians that draw its region (their
centres in front of the view's camera and inside the region: a group may also hold flagged Gaussians
of the scene, near surfaces elsewhere in the view), the distance from its centre to the nearest opaque
Gaussian that no signal flagged (the scene, as the scan sees it), over its distance to the camera; the
median over them. A Gaussian in front of the near
line with nothing unflagged between it and the surface behind has a detachment of at least
(1 - f) / f, f its depth over the surface's; poison in front of a line at 0.3-0.55 of the median depth
(docs/scan.md) is at least ~0.8 from the surface straight behind it, and more where the nearest surface
is farther. An attacker can plant unflagged Gaussians closer only outside the view's frustum or beyond
the line: inside the frustum and nearer, camera-proximity flags them.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

#: A Gaussian at least this opaque hides most of what lies behind it: only such Gaussians are members
#: measured or anchors of the scene (a near-transparent Gaussian draws nothing and holds nothing up).
OPAQUE_GAUSSIAN = 0.3


def scene_anchors(means: np.ndarray, opacity: np.ndarray, flagged: np.ndarray) -> cKDTree | None:
    """A search tree over the centres (``means`` ``[N, 3]``, scene units) of the opaque (``opacity``
    ``[N]`` in [0, 1]) Gaussians that no signal flagged (``flagged`` ``[N]`` bool); None when there are
    none."""
    anchors = np.asarray(means, dtype=np.float64)[(np.asarray(opacity) >= OPAQUE_GAUSSIAN) & ~flagged]
    return cKDTree(anchors) if len(anchors) else None


def drawing_region(means: np.ndarray, members: np.ndarray, viewmat: np.ndarray, K: np.ndarray,
                   region: np.ndarray) -> np.ndarray:  # fmt: skip
    """``[N]`` bool: the ``members`` (``[N]`` bool) whose centre (``means`` ``[N, 3]``) lies in front of the
    camera (``viewmat`` ``[4, 4]`` world-to-camera, OpenCV: looking down +z; ``K`` ``[3, 3]`` pixels) and
    falls in a pixel of ``region`` (``[H, W]`` bool; pixel (x, y) spans [x, x + 1) x [y, y + 1))."""
    out = np.zeros(len(members), dtype=bool)
    rows = np.nonzero(members)[0]
    p = np.asarray(means, dtype=np.float64)[rows] @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = p[:, 2]
    front = z > 1e-9
    x = np.full(len(rows), -1.0)
    y = np.full(len(rows), -1.0)
    x[front] = K[0, 0] * p[front, 0] / z[front] + K[0, 2]
    y[front] = K[1, 1] * p[front, 1] / z[front] + K[1, 2]
    h, w = region.shape
    inside = front & (x >= 0) & (x < w) & (y >= 0) & (y < h)
    out[rows[inside]] = region[y[inside].astype(int), x[inside].astype(int)]
    return out


def detachment(
    means: np.ndarray, opacity: np.ndarray, members: np.ndarray, camera: np.ndarray, anchors: cKDTree | None
) -> float:
    """The median, over the opaque Gaussians among ``members`` (``[N]`` bool; the scan passes those that
    draw the group's region, :func:`drawing_region`), of the distance from each
    centre to the nearest of ``anchors`` (:func:`scene_anchors`) over its distance to ``camera`` (the
    view's centre, ``[3]``, the same units): 0 inside the scene, about 1 when the nearest piece of scene
    is as far as the camera. Infinite when the group has no opaque Gaussian or there is no anchor (no
    evidence that it is attached)."""
    centres = np.asarray(means, dtype=np.float64)[members & (np.asarray(opacity) >= OPAQUE_GAUSSIAN)]
    if anchors is None or len(centres) == 0:
        return math.inf
    to_scene, _ = anchors.query(centres)
    to_camera = np.linalg.norm(centres - np.asarray(camera, dtype=np.float64), axis=1)
    return float(np.median(to_scene / np.maximum(to_camera, 1e-12)))


def is_detached(value: float, ratio: float) -> bool:
    """Whether a group of detachment ``value`` floats free (the scan's ``--detached-ratio``: 0 calls every
    group free, the rule off)."""
    return value >= ratio
