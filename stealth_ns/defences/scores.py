"""Suspicion scores of the Gaussians of a trained model: one float per Gaussian, higher = more suspicious
= pruned first. Pure numpy/scipy (no torch, no nerfstudio); the glue (:mod:`stealth_ns.defences.posthoc`)
loads the model, renders the per-view weights and applies the pruning rules.

Conventions shared by every score here and by :mod:`stealth_ns.defences.detection`:

* **Non-finite input is maximally suspicious.** A Gaussian with a NaN/inf parameter (a broken row of a
  model) scores ``+inf``; it is left out of the statistics (median, MAD, k-d tree, mean/std) that the
  other rows are scored against, so one broken row does not move anyone else's score. A NaN *score*
  (should one reach the pruning helpers) is read as ``+inf`` too (:func:`nan_as_suspicious`).
* **Ties are broken by index**: the pruning order (:func:`pruning_order`) is scores descending, and
  among equal scores the lower index comes first. Every pruning mask here and in ``detection`` is a
  prefix of that order, so masks are deterministic and nested (a larger budget prunes a superset).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import entr, expit

#: 1 / Phi^-1(3/4): makes the median absolute deviation a consistent estimate of a normal's sigma.
MAD_TO_SIGMA = 1.4826
#: sqrt(pi / 2): the same for the mean absolute deviation (the fallback when MAD = 0).
MEANAD_TO_SIGMA = 1.2533
#: Iglewicz and Hoaglin's cut for the modified z-score (the zscore defence prunes ``score > 3.5``).
ZSCORE_THRESHOLD = 3.5
#: Features of :func:`zscore_features`, in the order their z-scores are stacked.
ZSCORE_FEATURES: tuple[str, ...] = ("centre_distance", "log_max_scale", "log_volume", "opacity")
_ROWS_PER_BLOCK = 1 << 16


def nan_as_suspicious(scores: np.ndarray) -> np.ndarray:
    """``(N,)`` float64 copy of ``scores`` with NaN replaced by ``+inf`` (±inf kept): the most
    suspicious value, so a NaN score is pruned first and ranks deterministically."""
    s = np.asarray(scores, dtype=np.float64)
    if s.ndim != 1:
        raise ValueError(f"scores must be 1-D (N,), got shape {s.shape}")
    return np.where(np.isnan(s), np.inf, s)


def pruning_order(scores: np.ndarray) -> np.ndarray:
    """``(N,)`` int64 indices in pruning order: highest score first (NaN as ``+inf``), ties by
    ascending index (a stable sort). Pruning ``n`` Gaussians prunes ``pruning_order(s)[:n]``."""
    return np.argsort(-nan_as_suspicious(scores), kind="stable")


def prune_mask_top_count(scores: np.ndarray, n_prune: int) -> np.ndarray:
    """``(N,)`` bool: True for the ``n_prune`` first Gaussians of :func:`pruning_order` (the highest
    scores, ties by lower index). ``n_prune`` is clipped to ``[0, N]``."""
    order = pruning_order(scores)
    mask = np.zeros(order.shape[0], dtype=bool)
    mask[order[: max(0, min(int(n_prune), order.shape[0]))]] = True
    return mask


def robust_zscore(x: np.ndarray) -> np.ndarray:
    """Modified z-score (Iglewicz and Hoaglin 1993) of each value of ``x``: ``(N,)`` -> ``(N,)``, >= 0,
    dimensionless (``x``'s units cancel).

    ``|x - median| / (1.4826 * MAD)`` with ``MAD = median(|x - median|)``. When MAD is 0 (more than
    half the values are equal) the scale falls back to ``1.2533 * mean(|x - median|)`` (IBM SPSS's
    fallback); when that is 0 too (all finite values equal) every finite value scores 0. Non-finite
    values (NaN, ±inf) score ``+inf`` and are left out of the median and the scale. Empty in, empty out.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"robust_zscore takes a 1-D array (N,), got shape {x.shape}")
    out = np.full(x.shape, np.inf)
    finite = np.isfinite(x)
    if not finite.any():
        return out
    v = x[finite]
    dev = np.abs(v - np.median(v))
    mad = float(np.median(dev))
    scale = MAD_TO_SIGMA * mad if mad > 0 else MEANAD_TO_SIGMA * float(dev.mean())
    out[finite] = dev / scale if scale > 0 else 0.0
    return out


def _rows(a: np.ndarray, name: str, columns: int | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or (columns is not None and a.shape[1] != columns):
        raise ValueError(f"{name} must have shape (N, {columns or 'D'}), got {a.shape}")
    return a


def zscore_features(
    means: np.ndarray, log_scales: np.ndarray, opacity_logits: np.ndarray
) -> dict[str, np.ndarray]:
    """statCull-style per-feature robust z-scores (:func:`robust_zscore`), name -> ``(N,)``.

    Args:
        means: ``(N, 3)`` Gaussian centres (scene units).
        log_scales: ``(N, D)`` natural log of the per-axis scales (splatfacto's ``scales`` parameter).
        opacity_logits: ``(N,)`` opacity before the sigmoid (splatfacto's ``opacities``).

    Features (:data:`ZSCORE_FEATURES`): ``centre_distance``, Euclidean distance of the centre from
    the per-axis median centre (scene units); ``log_max_scale``, the largest log scale;
    ``log_volume``, the sum of the log scales (log volume up to a constant); ``opacity``,
    ``sigmoid(logit)`` in [0, 1]. A row with any non-finite parameter scores ``+inf`` in every feature
    and is left out of the median centre and of every feature's median/MAD.
    """
    means = _rows(means, "means", 3)
    log_scales = _rows(log_scales, "log_scales")
    logits = np.asarray(opacity_logits, dtype=np.float64)
    if logits.ndim != 1 or not (means.shape[0] == log_scales.shape[0] == logits.shape[0]):
        raise ValueError(
            f"means {means.shape}, log_scales {log_scales.shape}, opacity_logits {logits.shape}"
            " must have the same number of rows N (opacity_logits as (N,))"
        )
    bad = ~(np.isfinite(means).all(1) & np.isfinite(log_scales).all(1) & np.isfinite(logits))
    centre = np.median(means[~bad], axis=0) if (~bad).any() else np.zeros(3)
    raw = {
        "centre_distance": np.linalg.norm(means - centre, axis=1),
        "log_max_scale": log_scales.max(axis=1) if log_scales.shape[1] else np.zeros(len(logits)),
        "log_volume": log_scales.sum(axis=1),
        "opacity": expit(logits),
    }
    out = {}
    for name in ZSCORE_FEATURES:
        feature = raw[name]
        feature[bad] = np.nan
        out[name] = robust_zscore(feature)
    return out


def zscore_scores(means: np.ndarray, log_scales: np.ndarray, opacity_logits: np.ndarray) -> np.ndarray:
    """``(N,)`` statCull-style score: each Gaussian's largest robust z-score over the features of
    :func:`zscore_features` (dimensionless, >= 0; ``+inf`` for a row with a non-finite parameter).
    The defence prunes ``score > ZSCORE_THRESHOLD`` (3.5). Which feature was the largest:
    ``ZSCORE_FEATURES[np.argmax(np.stack(list(zscore_features(...).values())), axis=0)]``."""
    features = zscore_features(means, log_scales, opacity_logits)
    return np.max(np.stack([features[name] for name in ZSCORE_FEATURES]), axis=0)


def sor_scores(means: np.ndarray, k: int = 20) -> np.ndarray:
    """Statistical-outlier-removal score of each centre, as open3d's
    ``PointCloud.remove_statistical_outlier(nb_neighbors=k, std_ratio)`` computes it: ``(N, 3)`` ->
    ``(N,)`` dimensionless, so that open3d removes a point exactly when ``score >= std_ratio``
    (the defence's ``score > std_ratio`` differs only on the measure-zero boundary).

    Per point, ``d`` = the mean Euclidean distance to its ``k`` nearest neighbours, **the point itself
    included** (open3d's k-d tree returns the query point at distance 0 among its ``k``); then
    ``score = (d - mean(d)) / std(d)`` with the **sample** std (ddof = 1, open3d's Bessel correction)
    over the cloud. Both facts were checked against open3d 0.20 (tests/defences/test_defence_scores.py). With
    ``N <= k`` every point uses all ``N`` points (open3d does the same).

    Degenerate cases where open3d differs (documented, not copied): open3d removes every point whose
    ``d`` is exactly 0 (k coincident centres) and leaves those points' ``d`` out of the mean's and
    std's sums but not out of their counts; here they get their ordinary (low) score and the plain
    mean/std. When fewer than 2 finite points remain or ``std(d) = 0`` every finite point scores 0
    (open3d would then remove all of them). Non-finite centres score ``+inf`` and are not in the tree.
    """
    means = _rows(means, "means", 3)
    if int(k) < 1:
        raise ValueError(f"k (neighbours) must be at least 1, got {k}")
    out = np.full(means.shape[0], np.inf)
    finite = np.isfinite(means).all(axis=1)
    points = means[finite]
    n = points.shape[0]
    if n < 2:
        out[finite] = 0.0
        return out
    kk = min(int(k), n)
    dist, _ = cKDTree(points).query(points, k=kk, workers=-1)
    d = dist.reshape(n, kk).mean(axis=1)
    std = float(d.std(ddof=1))
    out[finite] = (d - d.mean()) / std if std > 0 else 0.0
    return out


def concentration_scores(weights: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """How concentrated each Gaussian's per-view support is: ``(N, V)`` -> ``(N,)`` in ``[1/V, 1]``.

    ``weights[i, v] >= 0`` is Gaussian i's support in training view v (its accumulated
    alpha-blending weight over the view's pixels, or its gradient energy in that view; any
    non-negative unit). With the shares ``p_v = w_v / sum_v w_v``, the effective number of views is
    ``n_eff = exp(H(p))`` (Shannon entropy in nats, ``0 log 0 = 0``) and ``score = 1 / n_eff``:
    1 for a Gaussian seen by one view only, ``1/m`` for one seen equally by ``m`` views, ``1/V``
    for one seen equally by all. Rows whose total ``sum_v w_v <= eps`` (never seen; ``eps`` in the
    weights' unit) score 0: harmless to prune, not suspicious. A row with a NaN or +inf weight scores
    ``+inf``. Negative weights (-inf included) raise ValueError.
    """
    w = np.asarray(weights)
    if w.ndim != 2:
        raise ValueError(f"weights must have shape (N, V), got {w.shape}")
    if np.any(w < 0):
        rows = np.unique(np.nonzero(w < 0)[0])
        raise ValueError(
            f"weights must be non-negative; {rows.size} row(s) have a negative weight, e.g. row {rows[0]}"
        )
    out = np.zeros(w.shape[0])
    for start in range(0, w.shape[0], _ROWS_PER_BLOCK):
        block = np.asarray(w[start : start + _ROWS_PER_BLOCK], dtype=np.float64)
        finite = np.isfinite(block).all(axis=1)
        total = np.where(finite, block.sum(axis=1), 0.0)
        seen = finite & (total > eps)
        p = block[seen] / total[seen, None]
        scores = np.zeros(block.shape[0])
        scores[seen] = np.exp(-entr(p).sum(axis=1))
        scores[~finite] = np.inf
        out[start : start + block.shape[0]] = scores
    return out


def count_cap_scores(importance: np.ndarray) -> np.ndarray:
    """Poison-splat's naive count cap as a score: ``(N,)`` -> ``(N,)`` ``= -importance`` (the least
    important is pruned first). ``importance`` >= 0 is e.g. the blending weight summed over all training
    views (LightGaussian's global significance). A non-finite importance (NaN, ±inf) scores ``+inf``."""
    imp = np.asarray(importance, dtype=np.float64)
    if imp.ndim != 1:
        raise ValueError(f"importance must be 1-D (N,), got shape {imp.shape}")
    return np.where(np.isfinite(imp), -imp, np.inf)


def count_cap_mask(importance: np.ndarray, keep: int) -> np.ndarray:
    """``(N,)`` bool, True = pruned, when only the ``keep`` most important Gaussians are kept.

    Exactly ``prune_mask_top_count(count_cap_scores(importance), N - keep)``: among equal importances
    the lower index is pruned first (so the higher index is kept); non-finite importances are pruned
    first. ``keep >= N`` prunes nothing; ``keep < 0`` raises ValueError.
    """
    if int(keep) < 0:
        raise ValueError(f"keep must be >= 0, got {keep}")
    s = count_cap_scores(importance)
    return prune_mask_top_count(s, s.shape[0] - int(keep))


def frustum_depth_ratios(
    means: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray, sizes: np.ndarray, scene_depths: np.ndarray
) -> np.ndarray:
    """How close each centre comes to a training camera that has it in view: ``(N,)`` >= 0,
    dimensionless, ``+inf`` for a centre no camera has in view.

    Per camera v, a centre in front of it (camera-space ``z > 0``) whose projection falls inside its
    image has the ratio ``z / scene_depths[v]``; the result is the smallest ratio over the cameras.
    Occlusion is ignored: the question is where the Gaussian sits, not who sees it.

    Args:
        means: ``(N, 3)`` centres (scene units).
        viewmats: ``(V, 4, 4)`` world-to-camera, OpenCV convention (camera looks down ``+z``).
        Ks: ``(V, 3, 3)`` intrinsics in pixels; sizes: ``(V, 2)`` image ``(width, height)``.
        scene_depths: ``(V,)`` > 0, each camera's typical distance to what it shows (e.g. the median
            rendered z-depth), in scene units.

    A row with a non-finite centre scores ``0`` (the most suspicious ratio, so
    :func:`camera_proximity_scores` gives it ``+inf``).

    This is the readable reference; :func:`stealth_ns.defences.signals.frustum_depth_ratios` runs the
    compiled kernel of the same contract (``raster/csrc/frustum_cpu.cpp``).
    """
    means, viewmats, Ks, sizes, depths = check_frustum_arguments(means, viewmats, Ks, sizes, scene_depths)
    finite = np.isfinite(means).all(axis=1)
    points = np.where(finite[:, None], means, 0.0)
    out = np.full(means.shape[0], np.inf)
    for cam in range(viewmats.shape[0]):
        p = points @ viewmats[cam, :3, :3].T + viewmats[cam, :3, 3]
        z = p[:, 2]
        front = z > 0
        zs = np.where(front, z, 1.0)
        u = Ks[cam, 0, 0] * p[:, 0] / zs + Ks[cam, 0, 2]
        w = Ks[cam, 1, 1] * p[:, 1] / zs + Ks[cam, 1, 2]
        inside = front & (u >= 0) & (u < sizes[cam, 0]) & (w >= 0) & (w < sizes[cam, 1])
        out = np.where(inside, np.minimum(out, z / depths[cam]), out)
    out[~finite] = 0.0
    return out


def check_frustum_arguments(
    means: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray, sizes: np.ndarray, scene_depths: np.ndarray
) -> tuple[np.ndarray, ...]:
    """:func:`frustum_depth_ratios`'s arguments as float64 arrays; ValueError naming the shapes when one
    is wrong, or when the scene depths are not finite and > 0."""
    means = _rows(means, "means", 3)
    viewmats = np.asarray(viewmats, dtype=np.float64)
    Ks, sizes = np.asarray(Ks, dtype=np.float64), np.asarray(sizes, dtype=np.float64)
    depths = np.asarray(scene_depths, dtype=np.float64)
    v = viewmats.shape[0]
    if viewmats.shape != (v, 4, 4) or Ks.shape != (v, 3, 3) or sizes.shape != (v, 2) or depths.shape != (v,):
        raise ValueError(
            f"viewmats {viewmats.shape}, Ks {Ks.shape}, sizes {sizes.shape}, scene_depths {depths.shape}: "
            "need (V, 4, 4), (V, 3, 3), (V, 2) and (V,)"
        )
    if not np.all(np.isfinite(depths) & (depths > 0)):
        raise ValueError("scene_depths must be finite and > 0")
    return means, viewmats, Ks, sizes, depths


def camera_proximity_scores(ratios: np.ndarray) -> np.ndarray:
    """camera-proximity's score: ``(N,)`` ratios of :func:`frustum_depth_ratios` -> ``-ratio``, so the
    Gaussian nearest a camera that has it in view is pruned first; one no camera has in view
    (``+inf``) scores ``-inf``, the least suspicious. A NaN ratio scores ``+inf``."""
    r = np.asarray(ratios, dtype=np.float64)
    if r.ndim != 1:
        raise ValueError(f"ratios must be 1-D (N,), got shape {r.shape}")
    return np.where(np.isnan(r), np.inf, -r)
