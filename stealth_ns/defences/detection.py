"""How well a suspicion score finds the poison, and the pruning rules applied to it.

Scores follow :mod:`stealth_ns.defences.scores`' conventions: higher = more suspicious, NaN read as
``+inf`` (most suspicious), ties in a pruning order broken by ascending index. ``is_poison`` is the
ground-truth tag of each Gaussian (the model's poison tag), which only the evaluation knows.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from scipy.stats import rankdata

from stealth_ns.defences.scores import nan_as_suspicious, prune_mask_top_count

#: The pruned fractions of :func:`sweep_fractions`'s default: 0, then a 1-3 series from 0.1% to 50%.
DEFAULT_SWEEP: tuple[float, ...] = (0.0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.2, 0.3, 0.5)


def _labels(is_poison: np.ndarray, n: int | None = None) -> np.ndarray:
    y = np.asarray(is_poison)
    if y.ndim != 1 or (n is not None and y.shape[0] != n):
        size = n if n is not None else "N"
        raise ValueError(f"is_poison must be a 1-D bool array of {size} values, got shape {y.shape}")
    if y.dtype != bool:
        if not np.isin(y, (0, 1)).all():
            raise ValueError("is_poison must hold only True/False (or 0/1)")
        y = y.astype(bool)
    return y


def detection_metrics(scores: np.ndarray, is_poison: np.ndarray) -> dict[str, Any]:
    """Threshold-free detection quality of ``scores`` (``(N,)``, higher = more suspicious) against the
    poison tag (``(N,)`` bool).

    Returns ``auroc`` (probability that a random poison Gaussian scores above a random clean one, ties
    counting half; 0.5 = chance), ``average_precision`` (area under the precision-recall curve, step-wise
    as sklearn computes it; chance = ``prevalence``), ``prevalence`` (poison share), ``n_poison``,
    ``n_clean``, ``n_nonfinite`` (scores that were NaN/±inf) and ``reason`` (None, or why the metrics
    are None: both need both classes, so with no poison or no clean Gaussian both are None).

    Computed with torchmetrics' ``binary_auroc`` / ``binary_average_precision`` (exact, no threshold
    binning) on the scores' dense ranks scaled into (0, 1]: both metrics depend only on the order and
    the ties, and torchmetrics would otherwise squash scores outside [0, 1] through a sigmoid, which in
    float32 merges large scores (z = 20 and z = 40 both become 1.0). NaN ranks as ``+inf`` (most
    suspicious, as everywhere in the defences); ``+inf`` above every finite score, ``-inf`` below.
    torchmetrics accumulates the true/false-positive counts in float32: the metrics carry a relative
    error of about 1e-7 (0.75 and other dyadic values come out exact), and counts stay exact up to
    2**24 (16.7 M) Gaussians.
    """
    raw = np.asarray(scores, dtype=np.float64)
    s = nan_as_suspicious(raw)
    y = _labels(is_poison, s.shape[0])
    n_poison = int(y.sum())
    n_clean = int(y.shape[0] - n_poison)
    out: dict[str, Any] = {
        "auroc": None,
        "average_precision": None,
        "prevalence": n_poison / y.shape[0] if y.shape[0] else None,
        "n_poison": n_poison,
        "n_clean": n_clean,
        "n_nonfinite": int((~np.isfinite(raw)).sum()),
        "reason": None,
    }
    if n_poison == 0 or n_clean == 0:
        out["reason"] = f"AUROC and AP need both classes; got {n_poison} poison and {n_clean} clean Gaussians"
        return out
    # imported here, not at the top: torchmetrics imports torchvision and torch's dynamo, seconds of
    # the start of every command that imports this module, and most never compute these metrics
    from torchmetrics.functional.classification import binary_auroc, binary_average_precision

    preds = torch.from_numpy(rank_scores(s))
    target = torch.from_numpy(y.astype(np.int64))
    out["auroc"] = float(binary_auroc(preds, target))
    out["average_precision"] = float(binary_average_precision(preds, target))
    return out


def rank_scores(scores: np.ndarray) -> np.ndarray:
    """``(N,)`` float64 dense ranks of ``scores`` scaled into (0, 1] (NaN as ``+inf``): the same order and
    ties, in the range torchmetrics takes as probabilities (it squashes anything else through a sigmoid,
    which in float32 merges large scores)."""
    ranks = rankdata(nan_as_suspicious(scores), method="dense")
    return ranks / ranks.max()


def prune_mask_top_fraction(scores: np.ndarray, fraction: float) -> np.ndarray:
    """``(N,)`` bool, True = pruned: the ``round(fraction * N)`` highest scores (rounded half up), NaN
    as ``+inf``, ties by ascending index (:func:`stealth_ns.defences.scores.pruning_order`), so the masks
    of increasing fractions are nested. ``fraction`` in [0, 1], else ValueError."""
    fraction = float(fraction)
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must be in [0, 1], got {fraction}")
    n = np.asarray(scores).shape[0]
    return prune_mask_top_count(scores, int(math.floor(fraction * n + 0.5)))


def prune_mask_threshold(scores: np.ndarray, threshold: float) -> np.ndarray:
    """``(N,)`` bool, True = pruned: ``scores > threshold`` (strict), NaN as ``+inf`` (always pruned)."""
    return nan_as_suspicious(scores) > float(threshold)


def operating_point(is_poison: np.ndarray, pruned: np.ndarray) -> dict[str, Any]:
    """What a pruning mask did (``(N,)`` bool each): ``n_pruned``, ``n_poison``, ``n_clean``,
    ``n_poison_pruned``, ``n_clean_pruned``, ``poison_removed`` (share of the poison Gaussians pruned,
    in [0, 1]; None when there is no poison) and ``clean_removed`` (share of the clean Gaussians pruned;
    None when every Gaussian is poison)."""
    y = _labels(is_poison)
    p = _labels(pruned, y.shape[0])
    n_poison = int(y.sum())
    n_clean = int(y.shape[0] - n_poison)
    n_poison_pruned = int((p & y).sum())
    n_clean_pruned = int((p & ~y).sum())
    return {
        "n_pruned": int(p.sum()),
        "n_poison": n_poison,
        "n_clean": n_clean,
        "n_poison_pruned": n_poison_pruned,
        "n_clean_pruned": n_clean_pruned,
        "poison_removed": n_poison_pruned / n_poison if n_poison else None,
        "clean_removed": n_clean_pruned / n_clean if n_clean else None,
    }


def sweep_fractions(n_points: int = 9) -> list[float]:
    """Pruned fractions for the V-illusory vs V-test curve, ascending, starting at 0 (the unpruned model).

    The poison is a small share of the Gaussians (typically 0.5-8%), so the fractions are log-spaced
    where that share lies rather than uniform: the default (``n_points = 9``) is :data:`DEFAULT_SWEEP`,
    ``[0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.2, 0.3, 0.5]``. Any other ``n_points >= 2`` gives 0 followed
    by ``n_points - 1`` fractions geometrically spaced from 0.001 to 0.5, rounded to 3 significant digits
    (duplicates that rounding would make are dropped).
    """
    n_points = int(n_points)
    if n_points < 2:
        raise ValueError(f"n_points must be at least 2, got {n_points}")
    if n_points == len(DEFAULT_SWEEP):
        return list(DEFAULT_SWEEP)
    spaced = np.geomspace(0.001, 0.5, n_points - 1)
    return list(dict.fromkeys([0.0] + [float(f"{f:.3g}") for f in spaced]))
