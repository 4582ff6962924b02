"""Full-image datamanager: the attack's training images, and no CUDA requirement.

Training images (``next_train``), when the pipeline has set up an attack:
  - the poisoned views get the illusion composite I_ILL instead of the clean image;
  - innocent views get ``clip(I + N(0, sigma_t^2))`` with sigma_t from the noise schedule,
    deterministic for (seed, view, step).
Both are out of place: the cached images stay clean, and evaluation images are never
touched (``next_eval*`` and the fixed eval dataloader are nerfstudio's, unchanged).

nerfstudio's ``FullImageDatamanager`` pins cached images (``pin_memory()``) when
``cache_images="cpu"`` -- which it forces for datasets of more than 500 images -- and
pinning fails on a machine without CUDA. Pinning only speeds up host-to-GPU copies, so when
training runs on the CPU the cache simply stays in ordinary memory.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.data.datamanagers.full_images_datamanager import (
    FullImageDatamanager,
    FullImageDatamanagerConfig,
)
from torch import Tensor

from stealth_ns.attack.noise_schedule import NoiseDecay, noise_sigma, noisy_image


@dataclass(frozen=True)
class NoiseSpec:
    """View-consistency-disruption noise: sigma0 (0-255 scale) decaying over total_steps."""

    sigma0: float
    decay: NoiseDecay
    total_steps: int
    seed: int


@dataclass
class StealthDataManagerConfig(FullImageDatamanagerConfig):
    """nerfstudio's full-image datamanager options."""

    _target: type = field(default_factory=lambda: StealthDataManager)


class StealthDataManager(FullImageDatamanager):
    """Full images, cached on the training device; no pinned memory on CPU."""

    config: StealthDataManagerConfig

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.poison_targets: dict[int, Tensor] = {}
        self.noise: NoiseSpec | None = None

    def set_poison(self, targets: dict[int, Tensor], noise: NoiseSpec | None) -> None:
        """Training images from now on: ``targets`` (train index -> uint8 [H, W, C] I_ILL)
        replace their views; every other training view gets ``noise`` (None = no noise)."""
        self.poison_targets = dict(targets)
        self.noise = noise

    @property
    def train_image_names(self) -> list[str]:
        """Training image paths relative to the dataset folder (as users name views)."""
        base = Path(self.config.dataparser.data)
        base = base if base.is_dir() else base.parent
        paths = self.train_dataparser_outputs.image_filenames
        return [str(p.relative_to(base)) if p.is_relative_to(base) else p.name for p in paths]

    def next_train(self, step: int) -> tuple[Cameras, dict]:
        camera, data = super().next_train(step)
        index = int(camera.metadata["cam_idx"])
        if index in self.poison_targets:
            data["image"] = self.poison_targets[index].to(data["image"].device)
        elif self.noise is not None:
            sigma = noise_sigma(step, self.noise.total_steps, self.noise.sigma0, self.noise.decay)
            if sigma > 0:
                data["image"] = noisy_image(data["image"], sigma, self.noise.seed, index, step)
        return camera, data

    def _load_images(self, split: Literal["train", "eval"], cache_images_device: Literal["cpu", "gpu"]):
        if cache_images_device == "cpu" and torch.device(self.device).type == "cpu":
            cache_images_device = "gpu"  # nerfstudio's "gpu" means "on the training device", here the CPU
        return super()._load_images(split, cache_images_device)
