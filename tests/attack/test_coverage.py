"""Where the illusion's error sits (attack/coverage.py): the open and the covered illusion pixels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stealth_ns.attack.coverage import coverage_split


def _case():
    target = np.full((10, 10, 3), 0.5)
    mask = np.zeros((10, 10), dtype=bool)
    mask[:, :5] = True  # 50 illusion pixels
    coverage = np.zeros((10, 10))
    coverage[:8, :5] = 0.9  # 40 covered ...
    pred = target.copy()
    pred[8:, :5] = 0.6  # ... 10 open, each 0.1 off in every channel: MSE 0.01, 20 dB
    pred[:, 5:] = 0.0  # outside the mask: counts nowhere
    return pred, target, mask, coverage


def test_the_error_of_open_pixels_is_theirs():
    split = coverage_split(*_case())
    assert split["coverage_mean"] == pytest.approx(0.72)
    assert split["open_share"] == pytest.approx(0.2)
    assert split["open_error_share"] == pytest.approx(1.0)
    assert split["open_psnr"] == pytest.approx(20.0)
    assert split["covered_psnr"] == math.inf


def test_error_where_the_poison_covers_is_counted_there():
    pred, target, mask, coverage = _case()
    pred[:4, :5] = 0.6  # 20 covered pixels as far off as the 10 open ones
    split = coverage_split(pred, target, mask, coverage)
    assert split["open_error_share"] == pytest.approx(1 / 3)
    assert split["covered_psnr"] == pytest.approx(20.0 + 10 * math.log10(2))  # half of them exact


def test_edge_cases():
    pred, target, mask, coverage = _case()
    exact = coverage_split(target, target, mask, coverage)
    assert exact["open_error_share"] is None and exact["open_psnr"] == math.inf
    full = coverage_split(pred, target, mask, np.ones((10, 10)))
    assert full["open_share"] == 0.0 and full["open_psnr"] is None and full["open_error_share"] == 0.0
    # a pixel exactly at the line is covered
    assert coverage_split(pred, target, mask, np.full((10, 10), 0.5))["open_share"] == 0.0
    with pytest.raises(ValueError, match="empty"):
        coverage_split(pred, target, np.zeros((10, 10), dtype=bool), coverage)
