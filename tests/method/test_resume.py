"""A poisoned run that stops can be resumed (``ns-train ... --load-dir``) with its poison tags,
optimizer and densification state and its attack record intact."""

from __future__ import annotations

import json

import pytest
import torch
from conftest import train_tiny

# densify early and often so that the resumed part of the run refines (steps 50 and 60)
REFINE = ("--pipeline.model.warmup-length", "10", "--pipeline.model.refine-every", "10")


def _checkpoint(run_dir):
    (ckpt,) = sorted((run_dir / "nerfstudio_models").glob("step-*.ckpt"))[-1:]
    return torch.load(ckpt, map_location="cpu", weights_only=True)


@pytest.mark.slow
def test_resumed_attack_keeps_its_poison_and_record(tiny_orbit_scene, tmp_path):
    first = train_tiny(
        tiny_orbit_scene, tmp_path, "first", *REFINE, "--pipeline.attack.injection-step", "20", iterations=45
    ).parent
    stopped = _checkpoint(first)
    tags_when_stopped = int((stopped["pipeline"]["_model.gauss_params.poison"] > 0.5).sum())
    assert tags_when_stopped > 0
    assert {"grad2d", "count"} <= set(stopped["pipeline"]["_model._extra_state"])

    # before the fix: IndexError in gsplat's duplicate at the first refinement, and a record of 0 poison
    resumed = train_tiny(
        tiny_orbit_scene, tmp_path, "resumed", *REFINE, "--pipeline.attack.injection-step", "20",
        "--load-dir", str(first / "nerfstudio_models"), iterations=20,
    ).parent  # fmt: skip
    before = json.loads((first / "attack" / "attack.json").read_text())
    after = json.loads((resumed / "attack" / "attack.json").read_text())
    assert after["n_poison_gaussians"] == before["n_poison_gaussians"] > 0
    assert after["injected_at_step"] == 20
    assert after["resumed"] == [{"step": 45, "poison_gaussians": tags_when_stopped, "from": str(first)}]
    assert (resumed / "attack" / "poison_points.ply").is_file()

    final = _checkpoint(resumed)["pipeline"]
    n = final["_model.gauss_params.means"].shape[0]
    assert n > stopped["pipeline"]["_model.gauss_params.means"].shape[0]  # it refined after resuming
    assert final["_model.gauss_params.poison"].shape == (n,)
    assert int((final["_model.gauss_params.poison"] > 0.5).sum()) > 0
    # the optimizer trained the rows the model renders: its moments have one row per Gaussian
    state = _checkpoint(resumed)["optimizers"]["means"]["state"]
    assert all(s["exp_avg"].shape[0] == n for s in state.values())

    # resumed for one step without a refinement (step 45): it ends with the poison it stopped with
    one_step = train_tiny(
        tiny_orbit_scene, tmp_path, "one-step", *REFINE, "--pipeline.attack.injection-step", "20",
        "--load-dir", str(first / "nerfstudio_models"), iterations=1,
    ).parent  # fmt: skip
    ended = _checkpoint(one_step)["pipeline"]["_model.gauss_params.poison"]
    assert int((ended > 0.5).sum()) == tags_when_stopped
