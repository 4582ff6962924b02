"""The scan's model-level verdict, as pure functions: which flagged Gaussians form a group that draws
something of its own into one training view.

Every clean model has Gaussians that one view sees alone (the edge of a forward-facing capture, a
floater behind the cameras), so a flagged Gaussian is no evidence by itself. What poison does and
clean single-view Gaussians do not: it *covers*, in its view, a region of the scene that the rest of
the model shows (other views constrain what lies behind it) and paints something else there. So for
each training view v:

* the group ``G_v``: flagged Gaussians whose blending weight is largest in v, or there at least a
  share of their largest (:func:`groups_by_view`; the scan's ``group_share``: poison that several views
  see nearly alike belongs to each of them);
* its effect (:func:`effect_mask`): the pixels where ``G_v`` alone is opaque, the model without
  ``G_v`` is opaque too (something lies behind), ``G_v`` floats near the camera well in front of it,
  and removing ``G_v`` changes the colour;
* its region: the largest 8-connected part of the effect (:func:`largest_region`), as a share of the
  image. A view whose region reaches the threshold, drawn by enough Gaussians to hold a picture
  (:func:`is_targeted`), is named a targeted view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


def groups_by_view(
    flagged: np.ndarray, weights: np.ndarray, min_size: int = 1, share: float = 1.0
) -> dict[int, np.ndarray]:
    """View index -> ``[N]`` bool: the flagged Gaussians (``flagged`` ``[N]`` bool) whose blending weight
    (``weights`` ``[N, V]`` >= 0) is largest in that view and, with ``share`` < 1, those whose weight
    there is at least ``share`` of their largest (a Gaussian is then in the group of every view that
    sees it nearly as much as its first). Gaussians no view sees are in no group. Groups smaller than
    ``min_size`` are left out. Views in ascending order."""
    weights = np.asarray(weights)
    if weights.ndim != 2 or weights.shape[0] != flagged.shape[0]:
        raise ValueError(f"weights {weights.shape} must be (N, V) with N = {flagged.shape[0]}")
    # only the flagged rows are read: at 1M Gaussians x 100 views the full matrix is 400 MB
    flagged_rows = np.nonzero(flagged)[0]
    seen_by = weights[flagged_rows]
    first = np.argmax(seen_by, axis=1)
    largest = seen_by[np.arange(len(flagged_rows)), first]
    seen = largest > 0
    rows, seen_by, first, largest = flagged_rows[seen], seen_by[seen], first[seen], largest[seen]
    member = np.zeros(seen_by.shape, dtype=bool)
    member[np.arange(len(rows)), first] = True
    if share < 1.0:
        member |= seen_by >= share * largest[:, None]
    out = {}
    for v in np.nonzero(member.sum(axis=0) >= max(min_size, 1))[0]:
        group = np.zeros(flagged.shape[0], dtype=bool)
        group[rows[member[:, v]]] = True
        out[int(v)] = group
    return out


@dataclass(frozen=True)
class EffectRule:
    """The thresholds of :func:`effect_mask` (``ScanConfig.effect_rule()``: the defaults, with their
    reasons, are the scan's options)."""

    opaque: float
    depth_ratio: float
    near_ratio: float
    colour_change: float


@dataclass(frozen=True)
class RenderedView:
    """One render of a view: ``rgb`` ``[H, W, 3]`` in [0, 1], ``alpha`` ``[H, W]`` accumulated opacity,
    ``depth`` ``[H, W]`` expected z-depth (scene units; where nothing is drawn, any value)."""

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


def effect_mask(
    full: RenderedView,
    rest: RenderedView,
    group: RenderedView,
    scene_depth: float,
    cfg: EffectRule,
) -> np.ndarray:
    """``[H, W]`` bool: where a group floats close in front of the scene and changes what the view shows.

    ``full``, ``rest`` and ``group`` are the view rendered with every Gaussian, without the group and
    with the group alone; ``scene_depth`` is the view's median rendered depth (scene units). A pixel
    counts when (the thresholds are ``cfg``'s):

    * the group alone and the model without it are both more opaque than ``opaque`` (the group covers
      something the rest of the model shows);
    * the group's expected depth is below ``depth_ratio`` times the rest's there and below
      ``near_ratio`` times ``scene_depth`` (it floats near the camera, well in front of that surface:
      the edge of a capture that one view sees alone lies at the scene's depth);
    * removing the group changes a colour channel by more than ``colour_change``.
    """
    change = np.abs(full.rgb.astype(np.float32) - rest.rgb.astype(np.float32)).max(axis=-1)
    covered = (group.alpha > cfg.opaque) & (rest.alpha > cfg.opaque)
    near = (group.depth < cfg.depth_ratio * rest.depth) & (group.depth < cfg.near_ratio * scene_depth)
    return covered & near & (change > cfg.colour_change)


@dataclass(frozen=True)
class Region:
    """The largest connected part of a mask."""

    share: float
    """Its pixels over the image's."""
    pixels: int
    box: tuple[int, int, int, int]
    """``(x0, y0, x1, y1)`` inclusive pixel bounds; all -1 when empty."""
    mask: np.ndarray
    """``[H, W]`` bool, the region alone."""


def largest_region(mask: np.ndarray) -> Region:
    """The largest 8-connected component of ``mask`` (``[H, W]`` bool)."""
    mask = np.asarray(mask, dtype=bool)
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=int))
    if n == 0:
        return Region(0.0, 0, (-1, -1, -1, -1), np.zeros_like(mask))
    sizes = np.bincount(labels.ravel())[1:]
    biggest = labels == (int(np.argmax(sizes)) + 1)
    ys, xs = np.nonzero(biggest)
    box = (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))
    return Region(float(biggest.sum()) / mask.size, int(biggest.sum()), box, biggest)


def is_detailed(pixels: int, gaussians: int, max_pixels_per_gaussian: float) -> bool:
    """Whether a group of ``gaussians`` Gaussians has at least one per ``max_pixels_per_gaussian`` of the
    ``pixels`` of its region: an illusion is a picture, and a picture needs Gaussians of a few pixels
    each; a handful of large Gaussians over a wide region paints a smooth blob (a clean capture's
    floater)."""
    return pixels <= max_pixels_per_gaussian * gaussians


def is_targeted(region: Region, gaussians: int, threshold: float, max_pixels_per_gaussian: float) -> bool:
    """Whether a group of ``gaussians`` Gaussians whose largest region is ``region`` names its view: the
    region covers at least ``threshold`` of the image and the group is :func:`is_detailed`."""
    return region.share >= threshold and is_detailed(region.pixels, gaussians, max_pixels_per_gaussian)
