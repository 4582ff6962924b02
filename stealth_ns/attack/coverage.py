"""Where a poisoned view's illusion error sits: the pixels the poison covers and those it leaves open.

A pixel's coverage is the accumulated opacity of the poison Gaussians rendered alone there (``[0, 1]``;
1: the poison alone paints the whole pixel). V-illusory's squared error, split between the illusion
pixels the poison covers and the open ones (coverage below :data:`OPEN_BELOW`), says whether a short
illusion lacks poison (holes: the error sits in open pixels) or lacks detail where the poison is
(the covered pixels' PSNR is low too). docs/design/captures.md measures it on the phone captures.
"""

from __future__ import annotations

import numpy as np

from stealth_ns.images.metrics import masked_psnr

__all__ = ["OPEN_BELOW", "coverage_split"]

OPEN_BELOW = 0.5
"""An illusion pixel is open when the poison alone covers less than half of it."""


def coverage_split(
    pred: np.ndarray,
    target: np.ndarray,
    mask: np.ndarray,
    coverage: np.ndarray,
    open_below: float = OPEN_BELOW,
) -> dict[str, float | None]:
    """V-illusory's masked squared error split by the poison's coverage.

    Args:
        pred, target: ``[H, W, 3]`` render and illusion target in [0, 1].
        mask: ``[H, W]`` bool illusion mask (non-empty).
        coverage: ``[H, W]`` the poison's own accumulated opacity in [0, 1].
        open_below: coverage under which a pixel is open.

    Returns:
        ``coverage_mean`` (mean coverage over the mask), ``open_share`` (share of the mask's pixels
        that are open), ``open_error_share`` (their share of the mask's squared error; None when the
        render matches exactly), ``open_psnr`` and ``covered_psnr`` (dB over each part; None for an
        empty part, inf for an exact match).
    """
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        raise ValueError("coverage_split: the mask is empty")
    cov = np.asarray(coverage, dtype=np.float64)
    err = ((np.asarray(pred, dtype=np.float64) - np.asarray(target, dtype=np.float64)) ** 2).mean(-1)
    open_ = m & (cov < open_below)
    covered = m & ~open_
    total = float(err[m].sum())
    return {
        "coverage_mean": float(cov[m].mean()),
        "open_share": float(open_.sum() / m.sum()),
        "open_error_share": float(err[open_].sum() / total) if total > 0 else None,
        "open_psnr": masked_psnr(pred, target, open_) if open_.any() else None,
        "covered_psnr": masked_psnr(pred, target, covered) if covered.any() else None,
    }
