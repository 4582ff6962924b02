"""The attacked run under defence and how a defence is judged on it.

:class:`Target` is the attacked run with its attack record, final checkpoint and learning rates;
:class:`Evaluator` renders a model with some Gaussians pruned and returns V-illusory (masked PSNR of
the poisoned views against the illusion target) and V-test (held-out PSNR); :func:`cut_metrics` turns
one pruning into what it removed, V-illusory after and the V-test cost, and whether it defeats the
attack (:data:`DEFEAT_RULE`).
"""

from __future__ import annotations

import contextlib
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from stealth_ns.attack.poison_views import training_target
from stealth_ns.attack.record import AttackRecord
from stealth_ns.defence_eval.rule import DEFEAT_V_ILLUSORY, DEFEAT_V_TEST_COST
from stealth_ns.defences import detection
from stealth_ns.defences.posthoc import final_learning_rates
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import cached_format, rgb_float
from stealth_ns.images.metrics import illusion_metrics, psnr, v_illusory
from stealth_ns.method.model import StealthSplatModel
from stealth_ns.method.render_view import render_camera
from stealth_ns.runs.loaded import LoadedRun, attack_record, load_run


@dataclass
class Target:
    """The attacked run under defence."""

    run: LoadedRun
    record: AttackRecord
    checkpoint: Path
    learning_rates: dict[str, float]

    @property
    def model(self) -> StealthSplatModel:
        return self.run.model


def load_target(config_path: Path) -> Target:
    """Load an attacked run: its pipeline, attack record, final checkpoint and final learning rates."""
    run = load_run(Path(config_path))
    if not isinstance(run.model, StealthSplatModel):
        raise StealthNSError(f"{config_path} is not a stealth-splat run (no poison tag to score against)")
    return target_of(run, attack_record(run, Path(config_path)))


def target_of(run: LoadedRun, record: AttackRecord) -> Target:
    """A loaded run under defence: its record, its final checkpoint and final learning rates."""
    return Target(run, record, run.checkpoint, final_learning_rates(run.config.optimizers))


def defender_images(target: Target) -> list[torch.Tensor]:
    """The training images as the defender has them: the poisoned views' illusion composites, the
    support views' renders of the poison (``support_views``), the clean images elsewhere (the
    view-consistency noise has decayed by the end of training)."""
    dm = target.run.pipeline.datamanager
    images = [dm.cached_train[i]["image"] for i in range(len(dm.train_dataset))]
    for v in target.record.views:
        images[v.index] = training_target(v, images[v.index])
    for index, image in target.record.support_targets.items():
        images[index] = cached_format(image, images[index])
    return images


@dataclass
class Evaluator:
    """V-illusory and V-test of a model with some Gaussians pruned (rendered, cached per mask).

    ``run`` is the model rendered (the attacked run, or its clean or retrained counterpart); the
    poisoned views are always rendered from the attacked run's cameras (``target``), as the report does.
    """

    target: Target
    run: LoadedRun | None = None
    _cache: dict[str, dict[str, float | None]] = field(default_factory=dict)

    def __call__(self, pruned: np.ndarray | None) -> dict[str, float | None]:
        """``v_illusory_psnr``/``_ssim`` (mean over the poisoned views) and ``v_test_psnr`` (mean over the
        held-out views) of the model without the ``pruned`` ([N] bool) Gaussians."""
        key = "none" if pruned is None or not pruned.any() else hashlib.sha1(np.packbits(pruned)).hexdigest()
        if key not in self._cache:
            keep = None if key == "none" else torch.from_numpy(~pruned)
            model = (self.run or self.target.run).model
            with model.kept(keep) if keep is not None else contextlib.nullcontext():
                self._cache[key] = self._render_metrics()
        return self._cache[key]

    def _render_metrics(self) -> dict[str, float | None]:
        run = self.run or self.target.run
        model, pipeline = run.model, run.pipeline
        cameras = self.target.run.pipeline.datamanager.train_dataset.cameras
        per_view = {}
        for v in self.target.record.views:
            pred = render_camera(model, cameras[v.index : v.index + 1])["rgb"].float().cpu()
            per_view[v.name] = illusion_metrics(pred, v.target, v.mask, None)
        held_out = []
        for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
            outputs = render_camera(model, camera)
            gt = model.composite_with_background(model.get_gt_img(batch["image"]), outputs["background"])
            held_out.append(psnr(outputs["rgb"].float().cpu(), rgb_float(gt.cpu())))
        ill = v_illusory(per_view)
        return {
            "v_illusory_psnr": ill["psnr"],
            "v_illusory_ssim": ill["ssim"],
            "v_test_psnr": float(np.mean(held_out)) if held_out else None,
        }


def cut_metrics(evaluate: Evaluator, baseline: dict, pruned: np.ndarray, is_poison: np.ndarray) -> dict:
    """The numbers of one cut: what it removed, V-illusory after and the V-test cost (dB)."""
    return {**detection.operating_point(is_poison, pruned), **defeat_metrics(evaluate, baseline, pruned)}


def defeat_metrics(evaluate: Evaluator, baseline: dict, pruned: np.ndarray) -> dict:
    """V-illusory and V-test of the model without ``pruned``, the V-test cost against ``baseline`` (dB;
    None when either V-test is) and whether that defeats the attack (:data:`DEFEAT_RULE`)."""
    after = evaluate(pruned)
    cost = None
    if after["v_test_psnr"] is not None and baseline["v_test_psnr"] is not None:
        cost = baseline["v_test_psnr"] - after["v_test_psnr"]
    defeats = bool(
        after["v_illusory_psnr"] is not None
        and cost is not None
        and after["v_illusory_psnr"] < DEFEAT_V_ILLUSORY
        and cost <= DEFEAT_V_TEST_COST
    )
    return {**after, "v_test_cost": cost, "defeats_attack": defeats}
