"""Build a StealthSplatModel and its optimizers outside the trainer, for unit tests."""

from __future__ import annotations

import math

import torch
from nerfstudio.cameras.cameras import Cameras, CameraType
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.engine.optimizers import Optimizers

from stealth_ns.method.model import StealthSplatModel, StealthSplatModelConfig
from stealth_ns.method_configs.base import gaussian_optimizers


def pinhole_cameras(camera_to_worlds: torch.Tensor, width: int = 48, height: int = 32) -> Cameras:
    """Perspective cameras [N] with a 60 degree horizontal field of view and a centred principal point."""
    f = 0.5 * width / math.tan(math.radians(30))
    return Cameras(
        camera_to_worlds=camera_to_worlds.float(),
        fx=f,
        fy=f,
        cx=width / 2,
        cy=height / 2,
        width=width,
        height=height,
        camera_type=CameraType.PERSPECTIVE,
    )


def camera(width: int = 48, height: int = 32, eye=(0.0, 0.0, 3.0)) -> Cameras:
    """An OpenGL camera at ``eye`` looking down -z (towards the origin)."""
    c2w = torch.eye(4)[:3]
    c2w[:, 3] = torch.tensor(eye)
    return pinhole_cameras(c2w[None], width, height)


def build_model(n_points: int = 300, seed: int = 0, **config) -> tuple[StealthSplatModel, Optimizers]:
    g = torch.Generator().manual_seed(seed)
    xyz = (torch.rand(n_points, 3, generator=g) - 0.5) * 1.5
    rgb = (torch.rand(n_points, 3, generator=g) * 255).to(torch.uint8)
    cfg = StealthSplatModelConfig(**config)
    model = cfg.setup(
        scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]])),
        num_train_data=1,
        seed_points=(xyz, rgb),
    )
    opt_cfg = gaussian_optimizers(max_steps=1000, camera_warmup=10)
    optimizers = Optimizers(opt_cfg, model.get_param_groups())
    return model, optimizers


def train_step(
    model: StealthSplatModel, optimizers: Optimizers, step: int, cam: Cameras, target: torch.Tensor
) -> float:
    """One splatfacto iteration: before-callback, render, loss, backward, Adam, after-callback."""
    model.train()
    model.step_cb(optimizers, step)
    optimizers.zero_grad_all()
    out = model.get_outputs(cam)
    loss = sum(model.get_loss_dict(out, {"image": target}).values())
    loss.backward()
    optimizers.optimizer_step_all()
    model.step_post_backward(step)
    return loss.item()
