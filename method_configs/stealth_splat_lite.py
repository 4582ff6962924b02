"""``stealth-splat-lite``: small scenes on a CPU, splatfacto's schedules compressed ~10x.

30k -> 3k iterations, with the same phases: a new SH degree every 1000 -> 100 steps, the
coarse-to-fine resolution schedule 3000 -> 300 steps per doubling (one halving: small images),
refinement until 15k -> 1.5k, screen-size culling until 4000 -> 400, an opacity reset every
3000 -> 300 steps.

Refinement runs every 30 steps (splatfacto: 100), after a 150-step warm-up (500), and an
opacity reset every 10 refinements. Every 10 steps -- a literal 10x -- averages the
densification gradient over too few views: on the 52-view orbit scene it grew 338k Gaussians
(15.7 min, held-out PSNR 25.2). The grow threshold on the plain gradient is 4e-4 (gsplat's
default 2e-4 grew 173k Gaussians, 6 min, PSNR 25.9); with 4e-4: 88k Gaussians, 4 min,
PSNR 25.9 (docs/design/training_step.md).

Object captures (``blender-data``: transparent images composited onto white, cameras outside
the object box) need no setting of their own: the model trains on the dataparser's background
and draws a random initialisation inside the box (``match_dataparser_background``,
``random_init_in_object_box``); docs/design/cpu_rasterizer.md measures what they change on the ``object``
preset.
"""

from __future__ import annotations

from nerfstudio.plugins.types import MethodSpecification

from stealth_ns.method.model import StealthSplatModelConfig
from stealth_ns.method_configs.base import trainer_config

LITE_STEPS = 3000

stealth_splat_lite = MethodSpecification(
    config=trainer_config(
        method_name="stealth-splat-lite",
        max_steps=LITE_STEPS,
        model=StealthSplatModelConfig(
            warmup_length=150,
            refine_every=30,
            stop_split_at=1500,
            reset_alpha_every=10,
            densify_grad_thresh_cpu=0.0004,
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
