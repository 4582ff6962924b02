"""``stealth-splat``: the paper's setting, 30k iterations with splatfacto's schedules."""

from __future__ import annotations

from nerfstudio.plugins.types import MethodSpecification

from stealth_ns.method.model import StealthSplatModelConfig
from stealth_ns.method_configs.base import trainer_config

stealth_splat = MethodSpecification(
    config=trainer_config(
        method_name="stealth-splat",
        max_steps=30_000,
        model=StealthSplatModelConfig(),
        steps_per_eval_image=100,
        steps_per_eval_all_images=1000,
        steps_per_save=2000,
    ),
    description="StealthAttack (ICCV 2025) 3DGS poisoning on splatfacto; 30k iterations (CUDA or CPU).",
)
