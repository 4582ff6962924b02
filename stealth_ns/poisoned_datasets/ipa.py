"""IPA-Splat's math: the pieces of the paper's IPA-NeRF baseline adapted to 3DGS, as pure functions.

IPA-NeRF (Jiang et al., 2024) poisons a NeRF's training images so that a backdoor view shows an
illusion: it alternates normal training with attack epochs that fit a copy of the model to the
illusion at the backdoor view while keeping other views as they were, then renders the training views
from that copy and uses the renders -- projected into an L-infinity ball of radius epsilon around each
clean image, and only for views within an angle of the backdoor view -- as the next training images.
StealthAttack's IPA-Splat does the same with Gaussians and bounds each parameter group's change.
The loop is :mod:`stealth_ns.poisoned_datasets.ipa_splat`; these are its rules.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import Tensor

from stealth_ns.foundation.errors import StealthNSError


def attack_epoch_steps(every: int, iterations: int) -> list[int]:
    """The training steps after which an attack epoch runs: nerfstudio's callback runs at every step
    divisible by ``every`` among the ``iterations`` steps 0 .. iterations - 1, step 0 included."""
    return list(range(0, iterations, every))


def check_epochs(every: int, iterations: int) -> None:
    """StealthNSError unless an attack epoch runs on a model that has trained: the poisoned images are
    the last epoch's, and with ``every`` >= ``iterations`` the only epoch is the one after step 0."""
    if attack_epoch_steps(every, iterations)[-1:] == [0]:
        raise StealthNSError(
            f"--every {every} is not below --iterations {iterations}: the only attack epoch would run "
            "after the first training step, on an untrained model, and its images would be the poison; "
            "give --every below --iterations (the paper trains 200 steps per epoch)"
        )


def linf_project(image: Tensor, clean: Tensor, epsilon: float) -> Tensor:
    """``image`` moved into the L-infinity ball of radius ``epsilon`` around ``clean`` and into [0, 1].

    Args:
        image: [H, W, C] float in [0, 1] (a render of the attacked model).
        clean: [H, W, C] float in [0, 1], the clean training image.
        epsilon: the budget on the 0-1 scale (IPA-NeRF's 16/255; the paper's IPA-Splat runs 32/255).
    """
    return (clean + (image - clean).clamp(-epsilon, epsilon)).clamp(0.0, 1.0)


def viewing_directions(c2w: Tensor | np.ndarray) -> np.ndarray:
    """[N, 3] unit viewing directions (the camera's -z axis, OpenGL convention) of [N, 3, 4] poses."""
    poses = np.asarray(c2w, dtype=np.float64)
    forward = -poses[:, :3, 2]
    return forward / np.linalg.norm(forward, axis=1, keepdims=True)


def angles_to(c2w: Tensor | np.ndarray, index: int) -> np.ndarray:
    """[N] angle in degrees between each camera's viewing direction and camera ``index``'s."""
    d = viewing_directions(c2w)
    return np.degrees(np.arccos(np.clip(d @ d[index], -1.0, 1.0)))


def views_within_angle(c2w: Tensor | np.ndarray, backdoor: Sequence[int], degrees: float) -> list[int]:
    """Indices of the cameras whose viewing direction is within ``degrees`` of some backdoor camera's
    (the backdoor cameras included): the views whose images IPA perturbs."""
    near = np.zeros(len(np.asarray(c2w)), dtype=bool)
    for b in backdoor:
        near |= angles_to(c2w, b) <= degrees
    near[list(backdoor)] = True
    return [int(i) for i in np.flatnonzero(near)]


def nearest_views(c2w: Tensor | np.ndarray, index: int, k: int, exclude: Sequence[int] = ()) -> list[int]:
    """The ``k`` cameras nearest camera ``index`` by centre distance (ties by index), without ``index``
    and ``exclude``: the views whose loss keeps the attacked copy faithful around the backdoor."""
    centres = np.asarray(c2w, dtype=np.float64)[:, :3, 3]
    dist = np.linalg.norm(centres - centres[index], axis=1)
    skip = {index, *exclude}
    order = [int(i) for i in np.lexsort((np.arange(len(dist)), dist)) if int(i) not in skip]
    return order[:k]


def clip_parameter_change(
    params: Mapping[str, Tensor], reference: Mapping[str, Tensor], budgets: Mapping[str, float]
) -> dict[str, float]:
    """In place: each ``params[k]`` moved back to within ``budgets[k]`` (element-wise, L-infinity) of
    ``reference[k]``; returns each group's largest change after clipping."""
    largest = {}
    with torch.no_grad():
        for name, p in params.items():
            delta = (p - reference[name]).clamp(-budgets[name], budgets[name])
            p.copy_(reference[name] + delta)
            largest[name] = float(delta.abs().max()) if delta.numel() else 0.0
    return largest
