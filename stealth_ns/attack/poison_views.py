"""The attack's poisoned views: which training views, and the illusion target each trains on.

:func:`build_poison_views` resolves ``--pipeline.attack.views`` / ``multi-view`` against the training
split and composites the configured illusion (:func:`resolve_illusion`) over each view's clean image;
:func:`training_target` is that target as the datamanager's cache holds a training image. The inputs
are plain (image names, cameras, one cached image per index), so the pipeline and the poisoning
commands share it without this package knowing the datamanager.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.illusion import (
    BUILTIN_ILLUSIONS,
    Illusion,
    builtin_illusion,
    composite,
    load_illusion,
    place_illusion,
)
from stealth_ns.attack.options import option_name
from stealth_ns.attack.record import PoisonView
from stealth_ns.attack.views import median_view, multi_view_indices, resolve_views
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import cached_format, rgb_float

if TYPE_CHECKING:
    from nerfstudio.cameras.cameras import Cameras

__all__ = ["build_poison_views", "resolve_illusion", "training_target"]


def resolve_illusion(cfg: AttackConfig) -> Illusion:
    """The configured illusion: a built-in name or an image path (+ optional mask)."""
    if cfg.illusion in BUILTIN_ILLUSIONS:
        return builtin_illusion(cfg.illusion)
    path = Path(cfg.illusion)
    if not path.suffix and not path.exists():
        builtins = ", ".join(BUILTIN_ILLUSIONS)
        raise StealthNSError(
            f"unknown illusion {cfg.illusion!r}: use a built-in ({builtins}) or an image path"
        )
    return load_illusion(path, cfg.illusion_mask)


def build_poison_views(
    cfg: AttackConfig, names: Sequence[str], cameras: Cameras, image: Callable[[int], torch.Tensor]
) -> list[PoisonView]:
    """Resolve the poisoned views and their illusion targets; StealthNSError on bad input.

    Args:
        cfg: the attack's settings (views, multi-view, illusion and its placement).
        names: the training images' names, as users name views, by train index.
        cameras: the training cameras, by train index.
        image: train index -> its cached training image ([H, W, 3 or 4], uint8 or float).
    """
    if cfg.multi_view not in (1, 2, 3, 4):
        raise StealthNSError(f"{option_name('multi_view')} must be 1..4, got {cfg.multi_view}")
    base = resolve_views(list(cfg.views), names) if cfg.views else [median_view(len(names))]
    if cfg.multi_view > 1:
        if len(base) != 1:
            raise StealthNSError(
                f"{option_name('multi_view')} places views around ONE base view; give one view"
            )
        base = multi_view_indices(cameras.camera_to_worlds, cfg.multi_view, base=base[0])
    illusion = resolve_illusion(cfg)
    views = []
    for index in base:
        clean = image(index)
        height, width = clean.shape[:2]
        rgb, alpha = place_illusion(illusion, (height, width), cfg.illusion_center, cfg.illusion_scale)
        target = composite(rgb_float(clean), torch.as_tensor(rgb), torch.as_tensor(alpha))
        cam = cameras[index]
        views.append(
            PoisonView(
                index=index,
                name=names[index],
                c2w=cam.camera_to_worlds.float(),
                fx=float(cam.fx),
                fy=float(cam.fy),
                cx=float(cam.cx),
                cy=float(cam.cy),
                mask=torch.as_tensor(alpha) > 0.5,
                target=target,
            )
        )
    return views


def training_target(view: PoisonView, clean: torch.Tensor) -> torch.Tensor:
    """The poisoned view's training image in the cache's dtype/channels (RGBA keeps its alpha, and the
    illusion is opaque where its mask is)."""
    return cached_format(view.target, clean, view.mask)
