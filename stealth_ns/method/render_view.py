"""Rendering one view in eval mode, the way evaluation, the attack's injection, the report, the
defences and the viewer all do: :func:`render_camera`."""

from __future__ import annotations

import contextlib
from typing import Any, Literal

import torch
from nerfstudio.cameras.cameras import Cameras

RenderFilter = Literal["all", "hide_poison", "only_poison"]
"""What a render draws: every Gaussian, all but the poison, or the poison alone (eval only)."""


@torch.no_grad()
def render_camera(
    model: torch.nn.Module, camera: Cameras, render_filter: RenderFilter = "all"
) -> dict[str, Any]:
    """Render ``camera`` (one view) with ``model`` in eval mode, on the model's device.

    Any nerfstudio model works (a clean run may be stock splatfacto); a ``render_filter`` other than
    "all" needs a :class:`StealthSplatModel`. The model's train/eval mode and filter are restored after.

    Returns:
        The model's outputs: ``rgb`` ``[H, W, 3]`` in [0, 1], ``depth`` ``[H, W, 1]`` (z, scene units),
        ``accumulation`` ``[H, W, 1]``, ...
    """
    was_training = model.training
    model.eval()
    try:
        filtered = model.filtered(render_filter) if render_filter != "all" else contextlib.nullcontext()
        with filtered:
            return model.get_outputs(camera.to(model.device))
    finally:
        model.train(was_training)
