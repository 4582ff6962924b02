"""Choice of the poisoned view(s) from the training cameras.

* Single-view attack: the paper poisons "the median-indexed frame" of the training set
  (:func:`median_view`).
* Multi-view attack (paper section 4): poisoned views at 0, 90, 180 and 270 degrees from the median view,
  measured as azimuth around the scene's vertical axis (:func:`multi_view_indices`).
* User choice by index or image name (:func:`resolve_views`).
* Support views of the consistent illusion (``--pipeline.attack.support-views``): a poisoned view's
  nearest training views (:func:`nearest_views`).

Camera poses are camera-to-world matrices in the nerfstudio / OpenGL convention (camera looks down its
local ``-Z``, ``+Y`` up), ``[N, 3, 4]`` or ``[N, 4, 4]``, numpy or torch.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from pathlib import PurePath

import numpy as np
import torch

from stealth_ns.attack.options import option_name
from stealth_ns.foundation.errors import StealthNSError

__all__ = [
    "median_view",
    "multi_view_indices",
    "nearest_views",
    "scene_center",
    "scene_up",
    "resolve_views",
    "rotate_pose",
]

#: Target azimuths (degrees) of the multi-view attack, in the order they are used.
MULTI_VIEW_ANGLES: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)


def median_view(n_train: int) -> int:
    """Index of the median training frame, ``n_train // 2``.

    For odd ``n_train`` this is the exact median index; for even ``n_train`` the upper of the two middle
    indices (e.g. 26 of 0..51).
    """
    if isinstance(n_train, bool) or int(n_train) != n_train or n_train < 1:
        raise StealthNSError(f"need at least one training view to pick the median one, got {n_train!r}")
    return int(n_train) // 2


def _poses(camera_to_worlds) -> np.ndarray:
    c2w = (
        camera_to_worlds.detach().cpu().double().numpy()
        if isinstance(camera_to_worlds, torch.Tensor)
        else np.asarray(camera_to_worlds, dtype=np.float64)
    )
    if c2w.ndim != 3 or c2w.shape[1:] not in ((3, 4), (4, 4)):
        raise ValueError(f"camera_to_worlds must be [N, 3, 4] or [N, 4, 4], got {c2w.shape}")
    if not np.all(np.isfinite(c2w[:, :3, :4])):
        raise ValueError("camera_to_worlds contain non-finite values")
    return c2w[:, :3, :4]


def scene_up(camera_to_worlds) -> np.ndarray:
    """World "up" estimated as the normalised mean of the cameras' ``+Y`` (up) axes, ``[3]``.

    nerfstudio's dataparsers orient poses so that world ``+Z`` is up (``orientation_method="up"``), but
    averaging the cameras' own up vectors also works for datasets oriented differently, as long as the
    cameras are held roughly upright. Falls back to ``+Z`` if the mean vanishes.
    """
    c2w = _poses(camera_to_worlds)
    up = c2w[:, :3, 1].mean(axis=0)
    n = np.linalg.norm(up)
    return up / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def scene_center(camera_to_worlds) -> np.ndarray:
    """The point closest to all optical axes in the least-squares sense, ``[3]`` (scene units).

    Minimises ``sum_i || (I - d_i d_i^T) (x - o_i) ||^2`` over ``x`` (``o_i`` camera centres, ``d_i`` unit
    viewing directions ``-Z_cam``), i.e. the point the cameras look at for an inward-facing capture. If the
    system is ill-conditioned (all axes nearly parallel, e.g. a forward-facing capture, or a single camera),
    the mean of the camera centres is returned instead.
    """
    c2w = _poses(camera_to_worlds)
    o = c2w[:, :3, 3]
    d = -c2w[:, :3, 2]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # [N, 3, 3]
    a = proj.sum(axis=0)
    b = np.einsum("nij,nj->i", proj, o)
    if np.linalg.cond(a) > 1e6:
        return o.mean(axis=0)
    return np.linalg.solve(a, b)


def rotate_pose(c2w, center, axis, degrees: float) -> np.ndarray:
    """A camera orbited about the line through ``center`` along ``axis`` by ``degrees``, ``[3, 4]``.

    Position and orientation turn together (right-handed about ``axis``), so a camera looking at
    ``center`` keeps looking at it: the neighbour views of the paper's Fig. 8.

    Args:
        c2w: ``[3, 4]`` or ``[4, 4]`` camera-to-world (scene units).
        center: ``[3]`` a point on the rotation axis; axis: ``[3]`` its direction (any length > 0).
        degrees: rotation angle.
    """
    pose = _poses(np.asarray(c2w, dtype=np.float64)[None])[0]
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    t = np.deg2rad(degrees)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rot = np.eye(3) + np.sin(t) * cross + (1.0 - np.cos(t)) * cross @ cross  # Rodrigues
    c = np.asarray(center, dtype=np.float64)
    out = np.empty((3, 4))
    out[:, :3] = rot @ pose[:, :3]
    out[:, 3] = rot @ (pose[:, 3] - c) + c
    return out


def multi_view_indices(
    camera_to_worlds,
    k: int,
    base: int | None = None,
    center: Sequence[float] | np.ndarray | None = None,
) -> list[int]:
    """Poisoned views of the multi-view attack: the training views nearest to 0, 90, 180, 270 degrees.

    Azimuths are measured around the vertical axis (:func:`scene_up`) through ``center``, counter-clockwise
    seen from above (right-handed about up), with 0 degrees at the ``base`` camera. For each of the first
    ``k`` target angles the view whose azimuth is closest (circular distance) is chosen, never repeating a
    view; the first is always ``base`` itself. Cameras on the vertical axis through the centre (no defined
    azimuth) are never chosen except as ``base``.

    Args:
        camera_to_worlds: ``[N, 3, 4]`` or ``[N, 4, 4]`` training camera-to-world poses (OpenGL convention).
        k: number of poisoned views, 1..4.
        base: index of the 0-degree view; default :func:`median_view` ``(N)``.
        center: ``[3]`` scene centre; default :func:`scene_center` (the point closest to all optical axes).

    Returns:
        ``k`` distinct training-view indices, in the order 0, 90, 180, 270 degrees.

    Raises:
        StealthNSError: ``k`` not in 1..4, ``base`` out of range, or fewer than ``k`` usable cameras.
    """
    c2w = _poses(camera_to_worlds)
    n = c2w.shape[0]
    if isinstance(k, bool) or int(k) != k or not 1 <= k <= len(MULTI_VIEW_ANGLES):
        raise StealthNSError(f"the multi-view attack poisons 1 to 4 views, got {k!r}")
    k = int(k)
    if n < k:
        raise StealthNSError(f"cannot poison {k} views: only {n} training views")
    if base is None:
        base = median_view(n)
    if isinstance(base, bool) or int(base) != base or not 0 <= base < n:
        raise StealthNSError(f"base view index {base} is out of range: {n} training views (0..{n - 1})")
    base = int(base)
    c = scene_center(c2w) if center is None else np.asarray(center, dtype=np.float64).reshape(3)
    up = scene_up(c2w)

    offsets = c2w[:, :3, 3] - c
    flat = offsets - (offsets @ up)[:, None] * up[None, :]
    radius = np.linalg.norm(flat, axis=1)
    scale = max(float(radius.max()), 1e-12)
    e1 = flat[base]
    if radius[base] <= 1e-6 * scale:  # base camera on the axis: use its horizontal viewing direction
        view = -c2w[base, :3, 2]
        e1 = -(view - (view @ up) * up)
    if np.linalg.norm(e1) < 1e-12:
        raise StealthNSError(
            "cannot define azimuths: the base camera is on the vertical axis and looks straight down/up"
        )
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    azimuth = np.degrees(np.arctan2(flat @ e2, flat @ e1)) % 360.0
    usable = radius > 1e-6 * scale
    usable[base] = True
    if int(usable.sum()) < k:
        raise StealthNSError(
            f"cannot poison {k} views: only {int(usable.sum())} cameras have a defined azimuth"
        )

    chosen = [base]
    for target in MULTI_VIEW_ANGLES[1:k]:
        diff = np.abs((azimuth - target + 180.0) % 360.0 - 180.0)
        diff[~usable] = np.inf
        diff[chosen] = np.inf
        chosen.append(int(np.argmin(diff)))
    return chosen


def nearest_views(camera_to_worlds, index: int, k: int, exclude: Sequence[int] = ()) -> list[int]:
    """The ``k`` training views nearest to view ``index``: ``[N, 3|4, 4]`` poses -> ``k`` indices.

    Nearest by the distance between camera centres (scene units), among the views that look the
    same way (viewing directions less than 90 degrees apart); ties by the lower index. ``index``
    itself and ``exclude`` (e.g. the other poisoned views) are never chosen. Fewer than ``k`` such
    views: StealthNSError.
    """
    c2w = _poses(camera_to_worlds)
    n = c2w.shape[0]
    if not 0 <= int(index) < n:
        raise StealthNSError(f"view index {index} is out of range: {n} training views (0..{n - 1})")
    centres, looks = c2w[:, :3, 3], -c2w[:, :3, 2]
    distance = np.linalg.norm(centres - centres[index], axis=1)
    usable = (looks @ looks[index]) > 0.0
    usable[[int(index), *map(int, exclude)]] = False
    candidates = np.flatnonzero(usable)
    if candidates.size < k:
        raise StealthNSError(
            f"{option_name('support_views')} {k}: view {index} has only {candidates.size} other training "
            "views looking the same way"
        )
    order = np.lexsort((candidates, distance[candidates]))  # by distance, then index
    return [int(i) for i in candidates[order[:k]]]


def _name_matches(spec: str, names: Sequence[str]) -> list[int]:
    """Indices of ``names`` matching ``spec``: exact string, else path suffix (e.g. basename), else stem."""
    exact = [i for i, nm in enumerate(names) if nm == spec]
    if exact:
        return exact
    sparts = PurePath(spec).parts
    if sparts:
        suffix = [i for i, nm in enumerate(names) if PurePath(nm).parts[-len(sparts) :] == sparts]
        if suffix:
            return suffix
    return [i for i, nm in enumerate(names) if PurePath(nm).stem == spec]


def resolve_views(spec: Sequence[int | str], image_names: Sequence[str]) -> list[int]:
    """Turn view specifications (indices or image names) into training-view indices.

    Each item is either an integer index into ``image_names`` (0-based, no negative indexing) or a string.
    A string is matched, in this order, against the full name, a trailing part of the path (so
    ``"frame_00012.png"`` or ``"images/frame_00012.png"`` match ``"/data/scene/images/frame_00012.png"``),
    and the file stem (``"frame_00012"``). A string of digits that matches no name is an index; one that
    both names an image and is a valid index for a *different* view is rejected as ambiguous.

    Args:
        spec: indices and/or names, e.g. ``[3, "frame_00012.png"]``.
        image_names: file names (or paths) of the training views, in training-index order.

    Returns:
        The indices, in the order given.

    Raises:
        StealthNSError: index out of range, unknown name (with close matches), a name matching several
            images, an ambiguous digit string, or the same view given twice.
    """
    names = [str(nm) for nm in image_names]
    n = len(names)
    out: list[int] = []
    given: dict[int, str] = {}
    for item in spec:
        if isinstance(item, bool):
            raise StealthNSError(f"invalid view {item!r}: give an index or an image name")
        if isinstance(item, (int, np.integer)):
            idx = int(item)
            label = f"view index {idx}"
            if not 0 <= idx < n:
                raise StealthNSError(f"view index {idx} is out of range: {n} training views (0..{n - 1})")
        elif isinstance(item, str):
            text = item.strip()
            hits = _name_matches(text, names)
            as_index = int(text) if text.isdigit() else None
            if len(hits) > 1:
                shown = ", ".join(names[i] for i in hits[:4])
                raise StealthNSError(
                    f"view name {text!r} matches {len(hits)} images ({shown}): give a longer path"
                )
            if hits:
                idx = hits[0]
                if as_index is not None and as_index < n and as_index != idx:
                    raise StealthNSError(
                        f"view {text!r} is ambiguous: image {names[idx]!r} is view {idx} but {text} is also "
                        "a view index; pass the full image name or an integer"
                    )
            elif as_index is not None:
                idx = as_index
                if idx >= n:
                    raise StealthNSError(f"view index {idx} is out of range: {n} training views (0..{n - 1})")
            else:
                pool = sorted(set(names) | {PurePath(nm).name for nm in names})
                close = difflib.get_close_matches(text, pool, n=3, cutoff=0.5)
                hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
                raise StealthNSError(f"unknown view name {text!r} (not among the {n} training images){hint}")
            label = f"view {text!r}"
        else:
            raise StealthNSError(f"invalid view {item!r}: give an index or an image name")
        if idx in given:
            raise StealthNSError(f"{label} selects view {idx} ({names[idx]}), already given as {given[idx]}")
        given[idx] = label
        out.append(idx)
    return out
