"""Image metrics that never crash a run.

LPIPS (torchmetrics, AlexNet backbone) needs torchvision's AlexNet weights. Nothing in
stealth-ns downloads at run time: when the weights file is not already in torch's hub
cache, LPIPS is reported as unavailable with the reason, and callers leave it out (or
write ``null``) instead of failing.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

ALEXNET_WEIGHTS = "alexnet-owt-7be5be79.pth"


def alexnet_weights_path() -> Path:
    """Where torchvision looks for (and would download) the AlexNet weights LPIPS uses."""
    return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_WEIGHTS


class LazyLPIPS:
    """LPIPS built on first use; ``None`` results (and ``reason``) when it cannot be built."""

    def __init__(self) -> None:
        self._metric = None
        self._tried = False
        self.reason: str | None = None

    def _build(self) -> None:
        self._tried = True
        weights = alexnet_weights_path()
        if not weights.exists():
            self.reason = f"AlexNet weights not found at {weights} (stealth-ns never downloads at run time)"
        else:
            try:
                from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

                self._metric = LearnedPerceptualImagePatchSimilarity(normalize=True)
            except Exception as err:  # noqa: BLE001 - any failure means "unavailable", never a crash
                self.reason = f"{type(err).__name__}: {err}".splitlines()[0]
        if self._metric is None:
            from nerfstudio.utils.rich_utils import CONSOLE

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
        self._metric = self._metric.to(a.device)
        return float(self._metric(a.clamp(0, 1), b.clamp(0, 1)))
