"""Object captures (Blender format): random initialisation inside the object box, and the
background the dataparser composited the images onto (docs/design/cpu_rasterizer.md, "Object captures")."""

from __future__ import annotations

import copy
import math
from types import SimpleNamespace

import torch
from model_helpers import camera
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.engine.callbacks import TrainingCallbackAttributes

from stealth_ns.method.model import StealthSplatModel, StealthSplatModelConfig

BOX = 1.5  # blender-data's scene box: the NeRF-synthetic object bound


def _model(random_init: bool = True, seed_points=None, **config) -> StealthSplatModel:
    torch.manual_seed(0)
    cfg = StealthSplatModelConfig(random_init=random_init, num_random=2000, **config)
    return cfg.setup(
        scene_box=SceneBox(aabb=torch.tensor([[-BOX] * 3, [BOX] * 3])),
        num_train_data=8,
        seed_points=seed_points,
    )


def _ring(radius: float, n: int = 8) -> torch.Tensor:
    """[n, 3] camera centres on a horizontal ring (Blender: radius ~4; nerfstudio-data: < 1)."""
    a = torch.arange(n) * 2 * math.pi / n
    return torch.stack([radius * torch.cos(a), radius * torch.sin(a), torch.full((n,), 0.5)], -1)


def _in_box(means: torch.Tensor) -> bool:
    return bool((means.abs() <= BOX).all())


def test_random_init_is_drawn_in_the_box_when_the_cameras_are_outside_it():
    model = _model()
    before = model.means.detach().clone()
    assert not _in_box(before)  # splatfacto's 10-unit cube: Gaussians beside and behind the cameras
    model.adapt_to_dataset(_ring(4.0), alpha_color=None)
    after = model.means.detach()
    assert after.shape == before.shape  # same count, same Parameter objects
    assert _in_box(after) and after.abs().max() > 0.9 * BOX  # the whole box, not a corner of it
    # scales follow the denser cloud (splatfacto's kNN rule), so footprints stay small
    assert model.scales.exp().mean() < 0.6 * torch.exp(model._initial_log_scales(before)).mean()
    assert torch.allclose(model.scales.detach(), model._initial_log_scales(after))
    # only once: a second call (e.g. a second callbacks set-up) leaves the Gaussians alone
    model.adapt_to_dataset(_ring(4.0), alpha_color=None)
    assert torch.equal(model.means.detach(), after)


def test_cameras_inside_the_box_or_seed_points_keep_the_initialisation():
    ns_data = _model()  # nerfstudio-data / colmap frame: the box bounds the cameras
    before = ns_data.means.detach().clone()
    ns_data.adapt_to_dataset(_ring(0.9), alpha_color=None)
    assert torch.equal(ns_data.means.detach(), before)

    seeds = (torch.rand(500, 3) * 6 - 3, torch.zeros(500, 3, dtype=torch.uint8))
    seeded = _model(random_init=False, seed_points=seeds)
    seeded.adapt_to_dataset(_ring(4.0), alpha_color=None)
    assert torch.equal(seeded.means.detach(), seeds[0])

    off = _model(random_init_in_object_box=False)
    before = off.means.detach().clone()
    off.adapt_to_dataset(_ring(4.0), alpha_color=None)
    assert torch.equal(off.means.detach(), before)


def test_a_loaded_checkpoint_is_not_redrawn():
    trained = _model()
    trained.adapt_to_dataset(_ring(4.0), alpha_color=None)
    state = copy.deepcopy(trained.state_dict())
    state["gauss_params.means"] += 0.25  # stands in for training
    resumed = _model()
    resumed.load_state_dict(state)
    resumed.adapt_to_dataset(_ring(4.0), alpha_color=None)  # trainer: checkpoint, then callbacks
    assert torch.equal(resumed.means.detach(), state["gauss_params.means"])


def test_background_is_the_dataparsers_alpha_color_in_training_eval_and_checkpoints():
    model = _model()
    # splatfacto's "random": a new colour every training step, viser's grey-blue in eval
    model.train()
    assert not torch.equal(model._get_background_color(), model._get_background_color())

    cameras = SimpleNamespace(camera_to_worlds=torch.eye(4)[None, :3])
    attrs = TrainingCallbackAttributes(
        optimizers=None,
        grad_scaler=None,
        pipeline=SimpleNamespace(
            datamanager=SimpleNamespace(
                train_dataset=SimpleNamespace(cameras=cameras),
                train_dataparser_outputs=SimpleNamespace(alpha_color=torch.ones(3)),  # blender-data's white
            )
        ),
        trainer=None,
    )
    model.get_training_callbacks(attrs)
    model.train()
    assert torch.equal(model._get_background_color(), torch.ones(3))
    model.eval()
    out = model.get_outputs(camera())
    assert torch.equal(out["background"][0, 0], torch.ones(3))

    # ns-eval / the viewer: a fresh model without the dataset gets the colour from the checkpoint
    fresh = _model()
    fresh.load_state_dict(copy.deepcopy(model.state_dict()))
    fresh.eval()
    assert torch.equal(fresh._get_background_color(), torch.ones(3))
    # a checkpoint from before the buffer loads and keeps background_color
    old = {k: v for k, v in copy.deepcopy(model.state_dict()).items() if k != "data_background"}
    legacy = _model()
    legacy.load_state_dict(old)
    legacy.eval()
    assert torch.equal(legacy._get_background_color(), legacy.background_color)


def test_datasets_that_are_not_composited_and_the_switch_keep_background_color():
    plain = _model(background_color="black")
    plain.adapt_to_dataset(_ring(0.9), alpha_color=None)  # nerfstudio-data: alpha_color is None
    plain.train()
    assert torch.equal(plain._get_background_color(), torch.zeros(3))

    off = _model(match_dataparser_background=False, background_color="black")
    off.adapt_to_dataset(_ring(4.0), alpha_color=torch.ones(3))
    off.train()
    assert torch.equal(off._get_background_color(), torch.zeros(3))
