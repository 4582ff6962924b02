"""The training loss and evaluation metrics of :class:`stealth_ns.method.model.StealthSplatModel` (a mixin).

The training loss is splatfacto's. Its main term ``(1 - lambda) L1 + lambda (1 - SSIM)`` runs as one
compiled function on the CPU (:func:`stealth_ns.images.ssim.l1_ssim_loss`: the same value and gradient bit for
bit) where that applies and splatfacto's optional terms are off; splatfacto's own code otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from stealth_ns.images.ssim import SSIM, l1_ssim_loss


class LossesAndMetrics:
    """``get_loss_dict`` and ``get_image_metrics_and_images`` for a ``SplatfactoModel`` subclass (listed
    before it among the bases), which provides the attributes below."""

    config: Any
    ssim: SSIM
    psnr: Callable[[Tensor, Tensor], Tensor]
    lpips_metric: Callable[[Tensor, Tensor], float | None]
    camera_optimizer: Any
    composite_with_background: Callable[[Tensor, Tensor], Tensor]
    get_gt_img: Callable[[Tensor], Tensor]

    def get_loss_dict(
        self, outputs: dict[str, Any], batch: dict[str, Any], metrics_dict: Any = None
    ) -> dict[str, Tensor]:
        """splatfacto's losses (see the module docstring)."""
        config = self.config
        main = None
        if "mask" not in batch and not config.use_scale_regularization and not config.use_bilateral_grid:
            gt = self.composite_with_background(self.get_gt_img(batch["image"]), outputs["background"])
            main = l1_ssim_loss(outputs["rgb"], gt, self.ssim, config.ssim_lambda)
        if main is None:
            return super().get_loss_dict(outputs, batch, metrics_dict)
        loss_dict = {"main_loss": main, "scale_reg": torch.tensor(0.0).to(self.device)}
        if self.training:
            self.camera_optimizer.get_loss_dict(loss_dict)
        return loss_dict

    def get_image_metrics_and_images(
        self, outputs: dict[str, Tensor], batch: dict[str, Tensor]
    ) -> tuple[dict[str, float], dict[str, Tensor]]:
        gt_rgb = self.composite_with_background(self.get_gt_img(batch["image"]), outputs["background"])
        pred = outputs["rgb"]
        gt_b = torch.moveaxis(gt_rgb, -1, 0)[None]
        pred_b = torch.moveaxis(pred, -1, 0)[None]
        metrics = {"psnr": float(self.psnr(gt_b, pred_b).item()), "ssim": float(self.ssim(gt_b, pred_b))}
        lpips = self.lpips_metric(gt_b, pred_b)
        if lpips is not None:
            metrics["lpips"] = lpips
        return metrics, {"img": torch.cat([gt_rgb, pred], dim=1)}
