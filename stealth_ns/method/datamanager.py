"""Full-image datamanager: the attack's training images, and no CUDA requirement.

Training images (``next_train``), when the pipeline has set up an attack:
  - the poisoned views get the illusion composite I_ILL instead of the clean image;
  - innocent views get ``clip(I + N(0, sigma_t^2))`` with sigma_t from the noise schedule,
    deterministic for (seed, view, step);
  - with ``set_view_repeat`` the views showing the illusion are drawn more than once a pass.
Both are out of place: the cached images stay clean, and evaluation images are never
touched (``next_eval*`` and the fixed eval dataloader are nerfstudio's, unchanged).

nerfstudio's ``FullImageDatamanager`` pins cached images (``pin_memory()``) when
``cache_images="cpu"`` -- which it forces for datasets of more than 500 images -- and
pinning fails on a machine without CUDA. Pinning only speeds up host-to-GPU copies, so when
training runs on the CPU the cache simply stays in ordinary memory.
"""

from __future__ import annotations

import os
import random
from collections.abc import Sequence
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


def dataset_image_names(data: Path, paths: Sequence[Path]) -> list[str]:
    """Image paths as users name views: relative to the dataset folder (``data``, a folder or its
    transforms file); images that live elsewhere (a seeded copy referring to a read-only
    dataset) relative to the parent of their common folder, e.g. ``images/0042.png``."""
    base = Path(os.path.abspath(data if data.is_dir() else data.parent))
    normal = [Path(os.path.abspath(p)) for p in paths]  # as nerfstudio gives them: relative to the cwd
    if all(p.is_relative_to(base) for p in normal):
        return [str(p.relative_to(base)) for p in normal]
    folder = Path(os.path.commonpath([q.parent for q in normal]))
    root = folder.parent
    return [str(p.relative_to(root)) for p in normal]


@dataclass(frozen=True)
class NoiseSpec:
    """View-consistency-disruption noise: sigma0 (0-255 scale) decaying over total_steps."""

    sigma0: float
    decay: NoiseDecay
    total_steps: int
    seed: int


def check_nerfstudio_data(config: FullImageDatamanagerConfig | None, eval_split: str = "val") -> None:
    """Stop with one line (file and frame) if a nerfstudio-data, COLMAP or Blender dataset is broken,
    before nerfstudio's parser meets the problem as a traceback (:mod:`stealth_ns.datasets.check`);
    ``eval_split``: the split nerfstudio evaluates on (Blender reads ``transforms_{eval_split}.json``)."""
    from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig
    from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    from stealth_ns.datasets.check import check_blender, check_colmap, check_dataset
    from stealth_ns.foundation.errors import StealthNSError, fail

    dataparser = getattr(config, "dataparser", None)
    if getattr(dataparser, "data", None) is None:
        return
    data = Path(dataparser.data)
    try:
        if isinstance(dataparser, NerfstudioDataParserConfig):
            check_dataset(data, downscale_factor=dataparser.downscale_factor, dataparser="nerfstudio-data")
        elif isinstance(dataparser, ColmapDataParserConfig):
            check_colmap(data, str(dataparser.colmap_path), str(dataparser.images_path))
        elif isinstance(dataparser, BlenderDataParserConfig):
            check_blender(data, ("train", eval_split), ply=dataparser.ply_path)
    except StealthNSError as err:
        fail(err)


@dataclass
class StealthDataManagerConfig(FullImageDatamanagerConfig):
    """nerfstudio's full-image datamanager options."""

    _target: type = field(default_factory=lambda: StealthDataManager)
    input_filter: Literal["none", "wavelet", "gaussian"] = "none"
    """A defence (stealth-ns defend's input-filter): denoise every training image the model receives,
    after the attack's changes (:mod:`stealth_ns.images.input_filter`). Evaluation images stay as
    they are."""
    input_filter_sigma: float = 1.0
    """Standard deviation (pixels) of the gaussian input filter."""


class StealthDataManager(FullImageDatamanager):
    """Full images, cached on the training device; no pinned memory on CPU."""

    config: StealthDataManagerConfig

    def __init__(self, *args, **kwargs) -> None:
        config = kwargs.get("config", args[0] if args else None)
        test_mode = kwargs.get("test_mode", args[2] if len(args) > 2 else "val")
        if test_mode != "inference":
            check_nerfstudio_data(config, "test" if test_mode == "test" else "val")
        super().__init__(*args, **kwargs)
        self.poison_targets: dict[int, Tensor] = {}
        self.noise: NoiseSpec | None = None
        self.view_repeat = 1
        self._filtered: dict[int, Tensor] = {}  # input filter of the images that do not change per step

    def set_poison(self, targets: dict[int, Tensor], noise: NoiseSpec | None) -> None:
        """Training images from now on: ``targets`` (train index -> uint8 [H, W, C] I_ILL)
        replace their views; every other training view gets ``noise`` (None = no noise)."""
        self.poison_targets = dict(targets)
        self.noise = noise
        self._filtered.clear()

    def set_view_repeat(self, repeat: int, seed: int) -> None:
        """From now on each view of ``poison_targets`` is drawn ``repeat`` times per pass over the
        training views (1: once, as every view), the extra draws at places a ``seed``-ed generator
        picks; the pass under way gets them too."""
        self.view_repeat = int(repeat)
        self._repeat_rng = random.Random(seed)
        if self.view_repeat > 1:
            self.train_unseen_cameras = self._with_repeats(list(self.train_unseen_cameras))

    def _with_repeats(self, order: list[int]) -> list[int]:
        """``order`` (training indices) with ``view_repeat - 1`` extra draws of each view of
        ``poison_targets`` inserted."""
        for index in sorted(self.poison_targets) * (self.view_repeat - 1):
            order.insert(self._repeat_rng.randint(0, len(order)), index)
        return order

    def sample_train_cameras(self) -> list[int]:
        order = super().sample_train_cameras()
        return self._with_repeats(list(order)) if getattr(self, "view_repeat", 1) > 1 else order

    @property
    def train_image_names(self) -> list[str]:
        """Training image paths relative to the dataset folder (as users name views)."""
        return dataset_image_names(
            Path(self.config.dataparser.data), self.train_dataparser_outputs.image_filenames
        )

    def next_train(self, step: int) -> tuple[Cameras, dict]:
        camera, data = super().next_train(step)
        index = int(camera.metadata["cam_idx"])
        noised = False
        if index in self.poison_targets:
            data["image"] = self.poison_targets[index].to(data["image"].device)
        elif self.noise is not None:
            sigma = noise_sigma(step, self.noise.total_steps, self.noise.sigma0, self.noise.decay)
            if sigma > 0:
                data["image"] = noisy_image(data["image"], sigma, self.noise.seed, index, step)
                noised = True
        if self.config.input_filter != "none":
            data["image"] = self._filter(index, data["image"], cache=not noised)
        return camera, data

    def _filter(self, index: int, image: Tensor, cache: bool) -> Tensor:
        """The input filter of one training image (cached when the image is the same every step)."""
        if cache and index in self._filtered:
            return self._filtered[index]
        from stealth_ns.images.input_filter import filter_image

        out = filter_image(image.cpu().numpy(), self.config.input_filter, self.config.input_filter_sigma)
        result = torch.from_numpy(out).to(image.device)
        if cache:
            self._filtered[index] = result
        return result

    def _load_images(self, split: Literal["train", "eval"], cache_images_device: Literal["cpu", "gpu"]):
        if cache_images_device == "cpu" and torch.device(self.device).type == "cpu":
            cache_images_device = "gpu"  # nerfstudio's "gpu" means "on the training device", here the CPU
        return super()._load_images(split, cache_images_device)
