"""Full-image datamanager that also works without CUDA.

nerfstudio's ``FullImageDatamanager`` pins cached images (``pin_memory()``) when
``cache_images="cpu"`` -- which it forces for datasets of more than 500 images -- and
pinning fails on a machine without CUDA. Pinning only speeds up host-to-GPU copies, so when
training runs on the CPU the cache simply stays in ordinary memory.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import torch
from nerfstudio.data.datamanagers.full_images_datamanager import (
    FullImageDatamanager,
    FullImageDatamanagerConfig,
)


@dataclass
class StealthDataManagerConfig(FullImageDatamanagerConfig):
    """nerfstudio's full-image datamanager options."""

    _target: type = field(default_factory=lambda: StealthDataManager)


class StealthDataManager(FullImageDatamanager):
    """Full images, cached on the training device; no pinned memory on CPU."""

    config: StealthDataManagerConfig

    def _load_images(self, split: Literal["train", "eval"], cache_images_device: Literal["cpu", "gpu"]):
        if cache_images_device == "cpu" and torch.device(self.device).type == "cpu":
            cache_images_device = "gpu"  # nerfstudio's "gpu" means "on the training device", here the CPU
        return super()._load_images(split, cache_images_device)
