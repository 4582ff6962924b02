"""IPA-Splat: the paper's baseline, IPA-NeRF's bi-level poisoning on Gaussians, written as a poisoned dataset.

``stealth-ns ipa-poison --data DIR --output DIR`` trains the attacker's own model (the method's normal
training, attack off) and every ``--every`` steps runs an attack epoch on it (:class:`IPAEpochs`):

1. keep the Gaussians' parameters; fine-tune them for ``--attack-steps`` Adam steps on
   ``L1(backdoor render, I_ILL) + neighbour_weight * mean_j L1(render_j, clean_j)`` over the
   ``--neighbours`` training views nearest each backdoor view, at the trainer's current learning rates,
   clipping each parameter group's change to its budget after every step (the paper's "separate
   parameter constraints");
2. render every training view within ``--angle-limit`` degrees of a backdoor view from that attacked
   copy and project it into the L-infinity ball of ``--epsilon`` around the clean image;
3. put the parameters back and train on from there with those images in place of the clean ones.

The images of the last epoch are written into a copy of the dataset (:mod:`dataset_copy`), which a
victim then trains on normally. Deviations from the paper's description (§4.1: T = 200 normal steps per
epoch, A = 10 attack iterations, K = 100 perturbation renderings, epsilon = 32, eta = 1, view
constraints 13 and 15 degrees) are listed in ``docs/design/baselines.md``: the parameter budgets are ours (the
paper gives none), the K random perturbation renderings are the neighbouring training views, and one
angle limit selects the perturbed views.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.options import STEALTH_NS, spelled_as
from stealth_ns.attack.record import AttackRecord, PoisonView
from stealth_ns.foundation.fingerprint import dataset_fingerprint
from stealth_ns.images.io import cached_format, rgb_float, to_uint8
from stealth_ns.poisoned_datasets.config import IPAConfig
from stealth_ns.poisoned_datasets.data_only import victim_command
from stealth_ns.poisoned_datasets.dataset_copy import (
    PoisonedCopy,
    check_output,
    copy_dataset,
    max_abs_difference,
    open_source,
    write_record,
)
from stealth_ns.poisoned_datasets.ipa import (
    check_epochs,
    clip_parameter_change,
    linf_project,
    nearest_views,
    views_within_angle,
)
from stealth_ns.poisoned_datasets.setup import setup_trainer, trainer_config


def _rgb(pipeline: Any, index: int) -> Tensor:
    """[H, W, 3] float render of training camera ``index`` at full resolution (gradients on)."""
    cameras = pipeline.datamanager.train_dataset.cameras
    return pipeline.model.get_outputs(cameras[index : index + 1].to(pipeline.model.device))["rgb"]


class IPAEpochs:
    """The attack epochs of one IPA-Splat run, as a training callback (see the module docstring)."""

    def __init__(self, pipeline: Any, trainer: Any, views: list[PoisonView], cfg: IPAConfig) -> None:
        self.pipeline, self.trainer, self.views, self.cfg = pipeline, trainer, views, cfg
        dm = pipeline.datamanager
        c2w = dm.train_dataset.cameras.camera_to_worlds
        backdoor = [v.index for v in views]
        self.perturbed = views_within_angle(c2w, backdoor, cfg.angle_limit)
        self.neighbours = {b: nearest_views(c2w, b, cfg.neighbours, exclude=backdoor) for b in backdoor}
        used = set(self.perturbed) | {j for js in self.neighbours.values() for j in js}
        device = pipeline.model.device
        self.clean = {i: rgb_float(dm.cached_train[i]["image"]).to(device) for i in sorted(used)}
        self.targets = {v.index: v.target.to(device) for v in views}
        self.poisoned: dict[int, Tensor] = {}  # train index -> float [H, W, 3] in [0, 1], on the CPU
        self.epochs: list[dict[str, Any]] = []

    def _loss(self) -> Tensor:
        loss = torch.zeros((), device=self.pipeline.model.device)
        for b, target in self.targets.items():
            loss = loss + (_rgb(self.pipeline, b) - target).abs().mean()
            near = self.neighbours[b]
            if near and self.cfg.neighbour_weight > 0:
                terms = [(_rgb(self.pipeline, j) - self.clean[j]).abs().mean() for j in near]
                loss = loss + self.cfg.neighbour_weight * torch.stack(terms).mean()
        return loss

    def __call__(self, step: int) -> None:
        """One attack epoch after training step ``step``; the model is left exactly as it was."""
        t0 = time.perf_counter()
        optimizers = self.trainer.optimizers.optimizers
        losses, change = [], {}
        with self.pipeline.model.trial_parameters() as (params, saved):
            rates = {k: float(optimizers[k].param_groups[0]["lr"]) for k in params}
            adam = torch.optim.Adam([{"params": [p], "lr": rates[k]} for k, p in params.items()], eps=1e-15)
            for _ in range(self.cfg.attack_steps):
                adam.zero_grad(set_to_none=True)
                with torch.enable_grad():
                    loss = self._loss()
                    loss.backward()
                adam.step()
                change = clip_parameter_change(params, saved, self.cfg.budgets())
                losses.append(float(loss.detach()))
            eps = self.cfg.epsilon / 255.0
            with torch.no_grad():
                for i in self.perturbed:
                    self.poisoned[i] = linf_project(
                        _rgb(self.pipeline, i).clamp(0, 1), self.clean[i], eps
                    ).cpu()
        self._hand_over()
        self.epochs.append(
            {"step": step, "loss_first": losses[0], "loss_last": losses[-1], "largest_change": change,
             "seconds": time.perf_counter() - t0}
        )  # fmt: skip

    def _hand_over(self) -> None:
        """The next training steps train on the poisoned images (the datamanager's replacement images)."""
        dm = self.pipeline.datamanager
        cached = {i: cached_format(img, dm.cached_train[i]["image"]) for i, img in self.poisoned.items()}
        dm.set_poison(cached, None)


def _check_views(config: Any, attack: AttackConfig) -> None:
    """StealthNSError (with a did-you-mean) for backdoor views the dataset does not have."""
    from stealth_ns.attack.views import resolve_views
    from stealth_ns.method.datamanager import dataset_image_names

    if attack.views:
        parser = config.pipeline.datamanager.dataparser
        files = parser.setup().get_dataparser_outputs("train").image_filenames
        resolve_views(list(attack.views), dataset_image_names(Path(parser.data), files))


@spelled_as(STEALTH_NS)
def ipa_poison(
    data: Path,
    output: Path,
    attack: AttackConfig,
    cfg: IPAConfig,
    method: str = "stealth-splat-lite",
    seed: int = 0,
    iterations: int | None = None,
    overwrite: bool = False,
) -> str:
    """Run IPA-Splat on ``data`` and write the poisoned copy into ``output``; returns a console summary.

    ``attack`` chooses the illusion and the backdoor (poisoned) views; its components are not used.
    Errors name the attack's options as ``stealth-ns ipa-poison`` spells them (``--multi-view``).
    """
    from stealth_ns.attack.poison_views import build_poison_views

    t0 = time.perf_counter()
    cfg.validate()
    source = open_source(data)
    check_output(source, output, overwrite)
    config = trainer_config(source, dataclasses.replace(attack, enabled=False), method, seed)
    _check_views(config, attack)  # bad views fail before anything is written
    if iterations is not None:
        config.max_num_iterations = int(iterations)
    check_epochs(cfg.every, config.max_num_iterations)
    copy = copy_dataset(source, output, overwrite)
    config.output_dir = copy.root / "attack"
    config.experiment_name, config.method_name, config.timestamp = "attacker", method, "run"
    trainer = setup_trainer(config)  # seeded as ns-train: the same seed gives the same poisoned images
    pipeline = trainer.pipeline
    dm = pipeline.datamanager
    views = build_poison_views(
        dataclasses.replace(attack, enabled=True),
        dm.train_image_names,
        dm.train_dataset.cameras,
        lambda i: dm.cached_train[i]["image"],
    )
    epochs = IPAEpochs(pipeline, trainer, views, cfg)
    from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackLocation

    trainer.callbacks.append(
        TrainingCallback(
            [TrainingCallbackLocation.AFTER_TRAIN_ITERATION], epochs, update_every_num_iters=cfg.every
        )
    )
    trainer.train()
    _write_poisoned(copy, pipeline, epochs)
    details = {
        "threat_model": "ipa-splat",
        "source_train_fingerprint": dataset_fingerprint(pipeline.datamanager.train_dataparser_outputs),
        "ipa": dataclasses.asdict(cfg),
        "perturbed_views": [pipeline.datamanager.train_image_names[i] for i in epochs.perturbed],
        "neighbours": {
            pipeline.datamanager.train_image_names[b]: [pipeline.datamanager.train_image_names[j] for j in js]
            for b, js in epochs.neighbours.items()
        },
        "epochs": epochs.epochs,
        "attacker_run": str(trainer.base_dir),
        "method": method,
        "seed": seed,
        "seconds": time.perf_counter() - t0,
    }
    record = AttackRecord(config=dataclasses.asdict(attack), views=views, injection_step=None, noise=None)
    folder = write_record(copy, record, details)
    return _summary(copy, epochs, folder, victim_command(source, copy.root, method), cfg)


def _write_poisoned(copy: PoisonedCopy, pipeline: Any, epochs: IPAEpochs) -> None:
    """The last epoch's images into the copy, with their measured L-infinity distance to the clean image."""
    dm = pipeline.datamanager
    outputs = dm.train_dataparser_outputs
    names = dm.train_image_names
    for i, image in epochs.poisoned.items():
        written, source = copy.write_training_image(
            names[i], outputs, i, to_uint8(image), to_uint8(epochs.clean[i].cpu()), "IPA-Splat perturbation"
        )
        copy.images[names[i]]["linf_255"] = max_abs_difference(written, source)


def _summary(copy: PoisonedCopy, epochs: IPAEpochs, folder: Path, victim: str, cfg: IPAConfig) -> str:
    linf = max((e.get("linf_255", 0.0) for e in copy.images.values()), default=0.0)
    return "\n".join(
        [
            f"IPA-Splat poisoned copy of {copy.source.root} written to {copy.root}",
            "  backdoor view(s): " + ", ".join(v.name for v in epochs.views),
            f"  {len(epochs.epochs)} attack epochs; {len(epochs.poisoned)} image(s) perturbed "
            f"(within {cfg.angle_limit:g} degrees), largest change {linf:g}/255 (budget {cfg.epsilon:g})",
            f"  record: {folder}; the attacker's run: {folder / 'attacker'} (the input was not written)",
            f"train a victim on it: {victim}",
        ]
    )
