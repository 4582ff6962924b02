"""Shared pieces of the stealth-splat method configs (splatfacto's optimizers and schedules)."""

from __future__ import annotations

import torch
from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig

from stealth_ns.method import nerfstudio_startup
from stealth_ns.method.datamanager import StealthDataManagerConfig
from stealth_ns.method.model import StealthSplatModelConfig
from stealth_ns.method.optimizers import FusedAdamOptimizerConfig
from stealth_ns.method.pipeline import StealthPipelineConfig
from stealth_ns.method.schedulers import FloatExponentialDecaySchedulerConfig
from stealth_ns.method.trainer import StealthTrainerConfig

# nerfstudio imports these configs (its entry points) just before it registers its external methods,
# which is where every ns-train / ns-eval spent seconds in inspect.stack() (see the module)
nerfstudio_startup.install()

#: The viewer's default bind address during ns-train: loopback, not every interface.
VIEWER_HOST = "127.0.0.1"


def default_device_type() -> str:
    """CUDA when this machine has it, else CPU (override with --machine.device-type)."""
    return "cuda" if torch.cuda.is_available() else "cpu"


def gaussian_optimizers(max_steps: int, camera_warmup: int) -> dict:
    """splatfacto's per-parameter-group Adam settings; the means' LR decays over ``max_steps``. The
    Gaussians' groups use the fused kernel (:mod:`stealth_ns.method.optimizers`)."""
    return {
        "means": {
            "optimizer": FusedAdamOptimizerConfig(lr=1.6e-4, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(lr_final=1.6e-6, max_steps=max_steps),
        },
        "features_dc": {"optimizer": FusedAdamOptimizerConfig(lr=0.0025, eps=1e-15), "scheduler": None},
        "features_rest": {
            "optimizer": FusedAdamOptimizerConfig(lr=0.0025 / 20, eps=1e-15),
            "scheduler": None,
        },
        "opacities": {"optimizer": FusedAdamOptimizerConfig(lr=0.05, eps=1e-15), "scheduler": None},
        "scales": {"optimizer": FusedAdamOptimizerConfig(lr=0.005, eps=1e-15), "scheduler": None},
        "quats": {"optimizer": FusedAdamOptimizerConfig(lr=0.001, eps=1e-15), "scheduler": None},
        "camera_opt": {
            "optimizer": AdamOptimizerConfig(lr=1e-4, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(
                lr_final=5e-7, max_steps=max_steps, warmup_steps=camera_warmup, lr_pre_warmup=0
            ),
        },
        "bilateral_grid": {
            "optimizer": AdamOptimizerConfig(lr=2e-3, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(
                lr_final=1e-4, max_steps=max_steps, warmup_steps=camera_warmup, lr_pre_warmup=0
            ),
        },
    }


def trainer_config(
    method_name: str,
    max_steps: int,
    model: StealthSplatModelConfig,
    steps_per_eval_image: int,
    steps_per_eval_all_images: int,
    steps_per_save: int,
) -> StealthTrainerConfig:
    """A splatfacto-shaped ``TrainerConfig`` (whose trainer checks what it resumes from) for the
    stealth-splat model."""
    return StealthTrainerConfig(
        method_name=method_name,
        steps_per_eval_image=steps_per_eval_image,
        steps_per_eval_batch=0,
        steps_per_save=steps_per_save,
        steps_per_eval_all_images=steps_per_eval_all_images,
        max_num_iterations=max_steps,
        mixed_precision=False,
        machine=MachineConfig(device_type=default_device_type()),
        pipeline=StealthPipelineConfig(
            datamanager=StealthDataManagerConfig(
                dataparser=NerfstudioDataParserConfig(load_3D_points=True),
                cache_images_type="uint8",
            ),
            model=model,
        ),
        optimizers=gaussian_optimizers(max_steps, camera_warmup=max(1, max_steps // 30)),
        # this machine only (nerfstudio: 0.0.0.0, every interface); open it up with
        # --viewer.websocket-host 0.0.0.0 (docs/design/viewer.md)
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15, websocket_host=VIEWER_HOST),
        vis="viewer",
    )
