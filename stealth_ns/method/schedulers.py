"""Learning-rate schedule whose multipliers are Python floats.

nerfstudio's ``ExponentialDecayScheduler`` computes its multiplier with numpy, so the
optimizer's ``lr`` becomes a ``numpy.float64`` and ends up in every checkpoint. Since
PyTorch 2.6, ``torch.load`` defaults to ``weights_only=True`` and refuses numpy scalars,
which breaks ``ns-eval`` / ``ns-viewer`` on our checkpoints. Same schedule, plain floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from nerfstudio.engine.schedulers import ExponentialDecayScheduler, ExponentialDecaySchedulerConfig
from torch.optim import Optimizer, lr_scheduler


def exponential_decay_lr(
    step: int,
    lr_init: float,
    lr_final: float,
    max_steps: int,
    warmup_steps: int = 0,
    lr_pre_warmup: float = 1e-8,
    ramp: str = "cosine",
) -> float:
    """Learning rate at ``step``: warm-up from ``lr_pre_warmup`` to ``lr_init`` over
    ``warmup_steps`` (linear or cosine ramp), then log-linear decay to ``lr_final`` at ``max_steps``."""
    if step < warmup_steps:
        frac = min(max(step / warmup_steps, 0.0), 1.0)
        if ramp == "cosine":
            frac = math.sin(0.5 * math.pi * frac)
        return lr_pre_warmup + (lr_init - lr_pre_warmup) * frac
    t = min(max((step - warmup_steps) / max(max_steps - warmup_steps, 1), 0.0), 1.0)
    return math.exp(math.log(lr_init) * (1 - t) + math.log(lr_final) * t)


@dataclass
class FloatExponentialDecaySchedulerConfig(ExponentialDecaySchedulerConfig):
    """nerfstudio's exponential decay with warm-up; multipliers are Python floats."""

    _target: type = field(default_factory=lambda: FloatExponentialDecayScheduler)


class FloatExponentialDecayScheduler(ExponentialDecayScheduler):
    config: FloatExponentialDecaySchedulerConfig

    def get_scheduler(self, optimizer: Optimizer, lr_init: float) -> lr_scheduler.LRScheduler:
        cfg = self.config
        lr_final = lr_init if cfg.lr_final is None else cfg.lr_final

        def multiplier(step: int) -> float:
            lr = exponential_decay_lr(
                step, lr_init, lr_final, cfg.max_steps, cfg.warmup_steps, cfg.lr_pre_warmup, cfg.ramp
            )
            return lr / lr_init

        return lr_scheduler.LambdaLR(optimizer, lr_lambda=multiplier)
