"""Build a StealthPipeline on a generated scene and step it like nerfstudio's Trainer does."""

from __future__ import annotations

import copy
import random
from pathlib import Path

import numpy as np
import torch
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.engine.optimizers import Optimizers

from stealth_ns.attack.config import AttackConfig
from stealth_ns.method.datamanager import StealthDataManagerConfig
from stealth_ns.method.model import StealthSplatModelConfig
from stealth_ns.method.pipeline import StealthPipeline, StealthPipelineConfig
from stealth_ns.method_configs.base import gaussian_optimizers


def build_pipeline(
    scene: Path, attack: AttackConfig | None = None, seed: int = 42, **model_kw
) -> StealthPipeline:
    """The pipeline ns-train would build, with its random state seeded as ns-train seeds it
    (``--machine.seed``, 42 by default), so that a test's numbers do not depend on which tests ran
    before it in the same worker."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    model = {"num_downscales": 0, "warmup_length": 5, "refine_every": 5, "sh_degree": 1, **model_kw}
    config = StealthPipelineConfig(
        datamanager=StealthDataManagerConfig(
            dataparser=NerfstudioDataParserConfig(data=scene, load_3D_points=True), cache_images_type="uint8"
        ),
        model=StealthSplatModelConfig(**model),
        attack=attack or AttackConfig(),
    )
    return config.setup(device="cpu", test_mode="val")


class Stepper:
    """The Trainer's iteration: BEFORE callbacks, loss, backward, optimizer step, AFTER callbacks."""

    def __init__(self, pipeline: StealthPipeline, max_steps: int = 200) -> None:
        self.pipeline = pipeline
        self.optimizers = Optimizers(gaussian_optimizers(max_steps, 10), pipeline.get_param_groups())
        attrs = TrainingCallbackAttributes(
            optimizers=self.optimizers, grad_scaler=None, pipeline=pipeline, trainer=None
        )
        self.callbacks = pipeline.get_training_callbacks(attrs)

    def step(self, step: int) -> float:
        for cb in self.callbacks:
            cb.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        self.optimizers.zero_grad_all()
        _, loss_dict, _ = self.pipeline.get_train_loss_dict(step=step)
        loss = sum(loss_dict.values())
        loss.backward()
        self.optimizers.optimizer_step_all()
        for cb in self.callbacks:
            cb.run_callback_at_location(step, TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
        return float(loss.detach())


def poison_count(pipeline: StealthPipeline) -> int:
    return int(pipeline.model.poison_mask.sum())


def reload(pipeline: StealthPipeline, scene: Path, attack: AttackConfig, step: int) -> StealthPipeline:
    """A fresh pipeline with the first one's checkpoint loaded (what ns-eval does)."""
    state = copy.deepcopy(pipeline.state_dict())
    fresh = build_pipeline(scene, attack)
    fresh.load_pipeline(state, step)
    return fresh
