"""The attack's metrics of a trained model: V-illusory of the poisoned views and the innocent training
views' PSNR, which the pipeline adds to nerfstudio's evaluation metrics (ns-eval, training logs)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from stealth_ns.attack.record import PoisonView
from stealth_ns.images.io import rgb_float
from stealth_ns.images.metrics import illusion_metrics, psnr, v_illusory
from stealth_ns.method.datamanager import StealthDataManager
from stealth_ns.method.model import StealthSplatModel

__all__ = ["attack_metrics"]


@torch.no_grad()
def attack_metrics(
    model: StealthSplatModel,
    datamanager: StealthDataManager,
    poison_views: list[PoisonView],
    lpips_nulls: bool = True,
) -> dict[str, Any]:
    """V-illusory (masked metrics of each poisoned-view render against I_ILL) and the PSNR of
    the innocent training views against their clean images.

    Keys: ``v_illusory_{psnr,ssim,lpips}`` (:func:`stealth_ns.images.metrics.v_illusory` over the poisoned
    views), the same with ``[view name]`` per view, ``innocent_train_psnr``. When LPIPS is
    unavailable and ``lpips_nulls`` is set, ``v_illusory_lpips`` is None and ``lpips_unavailable``
    says why; otherwise keys without a value are left out (training logs take floats only).
    """
    cameras = datamanager.train_dataset.cameras
    per_view = {}
    for v in poison_views:
        pred = model.render_view(cameras[v.index : v.index + 1])["rgb"].float().cpu()
        per_view[v.name] = illusion_metrics(pred, v.target, v.mask, model.lpips_metric)
    results: dict[str, Any] = {
        f"v_illusory_{key}[{name}]": value
        for name, metrics in per_view.items()
        for key, value in metrics.items()
        if value is not None
    }
    for key, value in v_illusory(per_view).items():
        if value is not None or (key == "lpips" and lpips_nulls):
            results[f"v_illusory_{key}"] = value
    if results.get("v_illusory_lpips", 0.0) is None:
        results["lpips_unavailable"] = model.lpips_metric.reason
    poisoned = {v.index for v in poison_views}
    innocent = []
    for index in range(len(cameras)):
        if index not in poisoned:
            clean = rgb_float(datamanager.cached_train[index]["image"])
            innocent.append(psnr(model.render_view(cameras[index : index + 1])["rgb"].float().cpu(), clean))
    if innocent:
        results["innocent_train_psnr"] = float(np.mean(innocent))
    return results
