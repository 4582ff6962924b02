"""A trained run, loaded: its pipeline, config, checkpoint and attack record, and renders of its cameras.

Every command that reads trained runs (report, defend, bench metrics) loads them through
:func:`load_run`: the config is read with a YAML loader that executes nothing
(:mod:`stealth_ns.method.safe_config`), the checkpoint is looked up next to it, and the usual mistakes give
one-line errors.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from stealth_ns.attack.record import AttackRecord
from stealth_ns.foundation.errors import StealthNSError, StealthNSExit
from stealth_ns.foundation.fingerprint import dataset_fingerprint, recorded_fingerprint
from stealth_ns.method.checkpoints import checkpoint_steps
from stealth_ns.method.render_view import render_camera
from stealth_ns.runs.paths import run_file


@dataclass
class LoadedRun:
    """A trained run loaded for evaluation."""

    config_path: Path
    pipeline: Any  # a nerfstudio Pipeline (a StealthPipeline for the poisoned run)
    step: int
    config: Any = None  # the run's TrainerConfig, as loaded
    checkpoint: Path | None = None  # the checkpoint nerfstudio loaded (the latest)

    @property
    def model(self) -> Any:
        return self.pipeline.model

    @property
    def attack_enabled(self) -> bool:
        attack = getattr(self.pipeline.config, "attack", None)
        return bool(attack is not None and attack.enabled)

    @property
    def data(self) -> Path:
        """The dataset the run was loaded with."""
        dm = self.pipeline.datamanager.config
        return Path(dm.data or dm.dataparser.data)

    def fingerprints(self) -> dict[str, dict[str, Any]]:
        """``{"train": ..., "held-out": ...}`` (:mod:`stealth_ns.foundation.fingerprint`): the training
        split's as recorded when the run was trained (recomputed for runs that lack the record), the held-out
        split's from the dataset as loaded."""
        dm = self.pipeline.datamanager
        train = recorded_fingerprint(self.config_path.parent)
        if train is None:
            train = dataset_fingerprint(dm.train_dataparser_outputs)
        return {"train": train, "held-out": dataset_fingerprint(dm.eval_dataset._dataparser_outputs)}


def load_run(config_path: Path) -> LoadedRun:
    """``eval_setup`` for a run folder's ``config.yml``, with one-line errors for the usual mistakes.

    The config is read with :func:`stealth_ns.method.safe_config.load_config` (a YAML loader that executes
    nothing). The checkpoint is looked up next to the config file, so a run folder that was moved
    (or a relative ``--output-dir``) still loads.
    """
    from stealth_ns.method.safe_config import safe_eval_setup

    config_path = run_file(config_path)
    if not config_path.is_file():
        raise StealthNSError(f"no run config at {config_path} (give the config.yml of a training run)")
    models = config_path.parent / "nerfstudio_models"
    if not checkpoint_steps(models):  # the names find_checkpoint reads
        raise StealthNSError(
            f"{config_path.parent} has no checkpoint (nerfstudio_models/*.ckpt): not trained?"
        )

    def relocate(config: Any) -> Any:
        config.output_dir = config_path.parent.resolve()
        config.experiment_name, config.method_name, config.timestamp = ".", ".", "."
        data = Path(config.pipeline.datamanager.data or config.pipeline.datamanager.dataparser.data)
        if not data.exists():
            raise StealthNSError(
                f"the scene of {config_path} is not at {data} (was the run trained from another folder?)"
            )
        return config

    try:
        config, pipeline, checkpoint, step = safe_eval_setup(
            config_path, test_mode="test", update_config_callback=relocate
        )
    except StealthNSExit as err:  # the pipeline's own one-line errors, as raised
        raise err.error from None
    # nerfstudio undistorts the training images, and their cameras in place, when it first caches them
    # (lazily); a run without the attack never did: cache them, so the training cameras are the ones
    # the run trained with and its attack record uses (a lens-distorted capture trains on cropped images)
    if hasattr(type(pipeline.datamanager), "cached_train"):
        pipeline.datamanager.cached_train  # noqa: B018 - the access does the work
    return LoadedRun(config_path, pipeline, step, config, Path(checkpoint))


def attack_record(run: LoadedRun, given: Path) -> AttackRecord:
    """The attack record of an attacked run, or of the poisoned dataset a plain run (a victim) trained on
    (``stealth-ns poison-dataset`` / ``ipa-poison``); ``given``: the run's path as the user gave it."""
    from stealth_ns.poisoned_datasets.dataset_copy import RECORD_DIR, is_poisoned_copy

    attack_dir = run.config_path.parent / "attack"
    if not run.attack_enabled and is_poisoned_copy(run.data):
        return AttackRecord.read(run.data / RECORD_DIR, run.pipeline.datamanager.train_dataset.cameras)
    if not run.attack_enabled or not AttackRecord.exists(attack_dir):
        raise StealthNSError(
            f"{given} is not an attacked run (trained with the attack disabled, not on a poisoned dataset)"
        )
    return AttackRecord.read(
        attack_dir, run.pipeline.datamanager.train_dataset.cameras, run.pipeline.poison_views
    )


@torch.no_grad()
def render(
    run: LoadedRun, cameras: Any, index: int, c2w: np.ndarray | None = None, render_filter: str = "all"
) -> np.ndarray:
    """Render camera ``index`` of ``cameras`` (optionally moved to ``c2w`` [3, 4]) -> [H, W, 3] in [0, 1].

    ``render_filter``: "all", "hide_poison" or "only_poison" (a StealthSplatModel's filter).
    """
    camera = cameras[index : index + 1].to("cpu")
    if c2w is not None:
        camera.camera_to_worlds = torch.as_tensor(c2w, dtype=torch.float32)[None]
    rgb = render_camera(run.model, camera, render_filter)["rgb"]
    return rgb.float().clamp(0, 1).cpu().numpy()


@torch.no_grad()
def poison_coverage(run: LoadedRun, cameras: Any, index: int) -> np.ndarray | None:
    """``[H, W]`` the accumulated opacity of the poison Gaussians of ``run`` rendered alone from camera
    ``index`` of ``cameras`` (:mod:`stealth_ns.attack.coverage`); None for a model without poison rows
    (a clean run, or the victim of a poisoned dataset)."""
    model = run.model
    if not hasattr(model, "poison_mask") or not bool(model.poison_mask.any()):
        return None
    camera = cameras[index : index + 1].to("cpu")
    accumulation = render_camera(model, camera, "only_poison")["accumulation"]
    return accumulation[..., 0].float().clamp(0, 1).cpu().numpy()
