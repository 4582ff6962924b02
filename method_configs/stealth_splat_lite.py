"""``stealth-splat-lite``: small scenes on a CPU, splatfacto's schedules compressed 10x.

30k -> 3k iterations; every step-based schedule is scaled by the same factor so that the
run has the same phases: warm-up before refinement (500 -> 50), refinement every 100 -> 10
steps until 15k -> 1.5k, an opacity reset every 30 refinements (3k -> 300 steps), a new SH
degree every 1000 -> 100 steps, screen-size culling until 4000 -> 400, and the
coarse-to-fine resolution schedule (3000 -> 300 steps per doubling).
"""

from __future__ import annotations

from nerfstudio.plugins.types import MethodSpecification

from stealth_ns.method_configs.base import trainer_config
from stealth_ns.model import StealthSplatModelConfig

LITE_STEPS = 3000

stealth_splat_lite = MethodSpecification(
    config=trainer_config(
        method_name="stealth-splat-lite",
        max_steps=LITE_STEPS,
        model=StealthSplatModelConfig(
            warmup_length=50,
            refine_every=10,
            stop_split_at=1500,
            reset_alpha_every=30,
            sh_degree_interval=100,
            stop_screen_size_at=400,
            resolution_schedule=300,
            num_downscales=1,
        ),
        steps_per_eval_image=100,
        steps_per_eval_all_images=1000,
        steps_per_save=1000,
    ),
    description="stealth-splat for small scenes and CPUs: 3k iterations, splatfacto's schedules scaled 10x.",
)
