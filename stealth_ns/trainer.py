"""nerfstudio's trainer with a checked resume: ``--load-dir`` / ``--load-checkpoint`` give one line, not a
traceback, for a missing folder, a missing step, a stray file in ``nerfstudio_models/`` or a truncated
checkpoint (:mod:`stealth_ns.checkpoints`). Whether the checkpoint belongs to this run -- its scene, its
attack -- the pipeline checks when it loads the state (``StealthPipeline.load_pipeline``). Its
TensorBoard images are encoded faster (:mod:`stealth_ns.tensorboard_images`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.utils.rich_utils import CONSOLE

from stealth_ns.checkpoints import TRAINING_KEYS, find_checkpoint, read_checkpoint
from stealth_ns.errors import StealthNSError, fail
from stealth_ns.tensorboard_images import use_fast_png


@dataclass
class StealthTrainerConfig(TrainerConfig):
    """``TrainerConfig`` whose trainer checks the checkpoint it resumes from."""

    _target: type = field(default_factory=lambda: StealthTrainer)


class StealthTrainer(Trainer):
    """``Trainer`` with :meth:`_load_checkpoint` reading through :mod:`stealth_ns.checkpoints`."""

    def setup(self, test_mode: Literal["test", "val", "inference"] = "val") -> None:
        super().setup(test_mode)
        use_fast_png()

    def _load_checkpoint(self) -> None:
        config = self.config
        try:
            if config.load_dir is not None:
                path = find_checkpoint(config.load_dir, config.load_step)
            elif config.load_checkpoint is not None:
                path = config.load_checkpoint
            else:
                CONSOLE.print("No Nerfstudio checkpoint to load, so training from scratch.")
                return
            state = read_checkpoint(path, TRAINING_KEYS)
        except StealthNSError as err:
            fail(err)
        self._start_step = int(state["step"]) + 1
        self.pipeline.load_pipeline(state["pipeline"], state["step"])
        self.optimizers.load_optimizers(state["optimizers"])
        if "schedulers" in state and config.load_scheduler:
            self.optimizers.load_schedulers(state["schedulers"])
        self.grad_scaler.load_state_dict(state["scalers"])
        CONSOLE.print(f"Done loading Nerfstudio checkpoint from {path}")
