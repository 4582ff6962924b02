"""The post-hoc defences: a suspicion score for every Gaussian of a trained model, and where each cuts.

=====================  =====================================================  ==========================
defence                score (higher = more suspicious)                       pruning rule
=====================  =====================================================  ==========================
zscore                 largest robust z-score of centre distance, scale,      z > zscore_threshold
                       volume, opacity (statCull)
sor                    standardised mean distance to the k nearest centres    > sor_std_ratio
                       (open3d's statistical outlier removal)
count-cap              minus the summed blending weight over the training     keep the count_cap_keep
                       views (least important first; Poison-splat's cap)      most important
view-support           1 / effective number of training views that see the    > concentration_threshold
                       Gaussian (from the per-view blending weights)
grad-concentration     1 / effective number of training views its gradient    > concentration_threshold
                       comes from during a short fine-tune
camera-proximity       minus its smallest depth in a training camera that     ratio < proximity_threshold
                       has it in view, over that camera's median scene depth
=====================  =====================================================  ==========================
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from stealth_ns.defences import scores
from stealth_ns.defences.config import DefendConfig
from stealth_ns.defences.detection import prune_mask_threshold
from stealth_ns.defences.signals import (
    FineTune,
    frustum_depth_ratios,
    gradient_energy_matrix,
    near_depth_share,
    view_weights_and_depths,
)
from stealth_ns.method.camera_geometry import CameraGeometry, camera_geometry, geometry_of
from stealth_ns.method.model import TRAINABLE, StealthSplatModel

DESCRIPTIONS: dict[str, str] = {
    "zscore": "robust z-score of position, scale, volume and opacity (statCull)",
    "sor": "statistical outlier removal of the centres (open3d's rule)",
    "count-cap": "keep only the most important Gaussians (Poison-splat's count cap)",
    "view-support": "blending weight concentrated in few training views",
    "grad-concentration": "gradient concentrated in few training views during a short fine-tune",
    "camera-proximity": "floats close in front of a training camera (depth / the camera's scene depth)",
}


@dataclass
class Scored:
    """One post-hoc defence applied to a model."""

    name: str
    scores: np.ndarray
    """``[N]`` float64 suspicion (higher = pruned first)."""
    pruned: np.ndarray
    """``[N]`` bool: what the defence's rule prunes."""
    rule: str
    """The rule as text, with its number."""
    seconds: float


@dataclass
class DefenceInputs:
    """What the post-hoc defences read: the model, the training views and their images."""

    model: StealthSplatModel
    cameras: object
    """The training cameras (nerfstudio ``Cameras``, V views)."""
    images: Sequence[torch.Tensor]
    """View v's training image as the defender has it (the poisoned view's is the illusion)."""
    learning_rates: dict[str, float]
    """The run's final Adam rate of each trainable parameter (grad-concentration's fine-tune)."""
    _weights: np.ndarray | None = None
    _depths: np.ndarray | None = None
    _nears: np.ndarray | None = None

    def view_weights(self) -> np.ndarray:
        """``[N, V]`` blending weights, computed once (count-cap and view-support share them), with
        each view's scene depth from the same renders (camera-proximity's, :meth:`geometry`)."""
        if self._weights is None:
            self._weights, self._depths, self._nears = view_weights_and_depths(self.model, self.cameras)
        return self._weights

    def near_share(self) -> float:
        """The scene's near depth as a share of each view's median depth
        (:func:`~stealth_ns.defences.signals.near_depth_share`), from the view weights' renders."""
        self.view_weights()
        return near_depth_share(self._depths, self._nears)

    def geometry(self) -> CameraGeometry:
        """The cameras with each one's median rendered depth: from the view weights' renders when
        they were made, else rendered now."""
        if self._depths is None:
            return camera_geometry(self.model, self.cameras)
        return geometry_of(self.cameras, self._depths)


def _gaussian_arrays(model: StealthSplatModel) -> dict[str, np.ndarray]:
    g = model.gauss_params
    return {k: g[k].detach().cpu().double().numpy() for k in ("means", "scales", "opacities")}


def _zscore(inputs: DefenceInputs, cfg: DefendConfig) -> tuple[np.ndarray, np.ndarray, str]:
    a = _gaussian_arrays(inputs.model)
    s = scores.zscore_scores(a["means"], a["scales"], a["opacities"].reshape(-1))
    return s, prune_mask_threshold(s, cfg.zscore_threshold), f"z > {cfg.zscore_threshold:g}"


def _sor(inputs: DefenceInputs, cfg: DefendConfig) -> tuple[np.ndarray, np.ndarray, str]:
    s = scores.sor_scores(_gaussian_arrays(inputs.model)["means"], k=cfg.sor_neighbours)
    return (
        s,
        prune_mask_threshold(s, cfg.sor_std_ratio),
        f"{cfg.sor_neighbours} neighbours, std ratio {cfg.sor_std_ratio:g}",
    )


def _count_cap(inputs: DefenceInputs, cfg: DefendConfig) -> tuple[np.ndarray, np.ndarray, str]:
    importance = inputs.view_weights().astype(np.float64).sum(axis=1)
    keep = int(round(cfg.count_cap_keep * importance.shape[0]))
    pruned = scores.count_cap_mask(importance, keep)
    return scores.count_cap_scores(importance), pruned, f"keep the {keep} most important"


def _view_support(inputs: DefenceInputs, cfg: DefendConfig) -> tuple[np.ndarray, np.ndarray, str]:
    s = scores.concentration_scores(inputs.view_weights())
    t = cfg.concentration_threshold
    return s, prune_mask_threshold(s, t), f"1/effective views > {t:g}"


def _grad_concentration(inputs: DefenceInputs, cfg: DefendConfig) -> tuple[np.ndarray, np.ndarray, str]:
    energy = gradient_energy_matrix(
        inputs.model,
        inputs.cameras,
        inputs.images,
        inputs.learning_rates,
        FineTune(epochs=cfg.finetune_epochs, seed=cfg.seed),
    )
    s = scores.concentration_scores(energy)
    t = cfg.concentration_threshold
    return (
        s,
        prune_mask_threshold(s, t),
        f"1/effective views > {t:g} ({cfg.finetune_epochs} fine-tune passes)",
    )


def _camera_proximity(inputs: DefenceInputs, cfg: DefendConfig) -> tuple[np.ndarray, np.ndarray, str]:
    geometry = inputs.geometry()
    ratios = frustum_depth_ratios(
        _gaussian_arrays(inputs.model)["means"],
        geometry.viewmats,
        geometry.Ks,
        geometry.sizes,
        geometry.scene_depths,
    )
    t = cfg.proximity_threshold
    return scores.camera_proximity_scores(ratios), ratios < t, f"depth < {t:g} x the camera's scene depth"


SCORERS: dict[str, Callable[[DefenceInputs, DefendConfig], tuple[np.ndarray, np.ndarray, str]]] = {
    "zscore": _zscore,
    "sor": _sor,
    "count-cap": _count_cap,
    "view-support": _view_support,
    "grad-concentration": _grad_concentration,
    "camera-proximity": _camera_proximity,
}


def score(name: str, inputs: DefenceInputs, cfg: DefendConfig) -> Scored:
    """Apply the post-hoc defence ``name`` (a key of :data:`SCORERS`) to ``inputs.model``."""
    t0 = time.perf_counter()
    s, pruned, rule = SCORERS[name](inputs, cfg)
    return Scored(
        name,
        np.asarray(s, dtype=np.float64),
        np.asarray(pruned, dtype=bool),
        rule,
        round(time.perf_counter() - t0, 2),
    )


def final_learning_rates(optimizers: dict) -> dict[str, float]:
    """Each trainable parameter's Adam rate at the end of training, from a run config's ``optimizers``
    (the scheduler's ``lr_final`` when it has one, else the optimizer's ``lr``)."""
    rates = {}
    for name in TRAINABLE:
        entry = optimizers[name]
        final = getattr(entry.get("scheduler"), "lr_final", None)
        rates[name] = float(final if final is not None else entry["optimizer"].lr)
    return rates
