"""The density-guided injection on the training pipeline: the current model's depth at the training
views, where the poison goes (:func:`poison_placement`), what the support views show from then on,
and the training callback that appends the poison and writes its artifacts (:func:`inject_poison`).

The placement's math is :mod:`stealth_ns.attack.injection`, the support views' images
:mod:`stealth_ns.attack.support`; this module feeds them the model's renders. Its functions read the
pipeline through :class:`InjectionSource`, which :class:`~stealth_ns.method.pipeline.StealthPipeline`
satisfies (the poisoning commands hand it theirs).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Protocol

import torch
from nerfstudio.utils.rich_utils import CONSOLE

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.injection import CAMERA_PLACEMENTS, PoisonPlacement, injection_entry, place_poison
from stealth_ns.attack.options import option_name
from stealth_ns.attack.record import AttackRecord, PoisonView, write_injection_files
from stealth_ns.attack.support import render_poison, support_target
from stealth_ns.attack.visibility import CameraDepths
from stealth_ns.foundation import thread_invariant
from stealth_ns.foundation.errors import fail
from stealth_ns.images.io import cached_format, rgb_float
from stealth_ns.method.datamanager import StealthDataManager
from stealth_ns.method.model import NEAR_PLANE, StealthSplatModel
from stealth_ns.raster.projection import viewmat_from_c2w

__all__ = [
    "InjectionSource",
    "cameras_with_depth",
    "inject_poison",
    "innocent_cameras",
    "poison_placement",
    "render_depths",
    "support_indices",
    "support_targets",
    "support_training_images",
    "support_view_names",
]


class AttackSettings(Protocol):
    """The pipeline config's side: the attack's settings."""

    @property
    def attack(self) -> AttackConfig:
        """``--pipeline.attack.*``."""
        ...


class InjectionSource(Protocol):
    """What the injection reads from (and, for the record, writes to) the pipeline."""

    @property
    def config(self) -> AttackSettings:
        """The pipeline's config."""
        ...

    @property
    def model(self) -> StealthSplatModel:
        """The model the poison is placed in and appended to."""
        ...

    @property
    def datamanager(self) -> StealthDataManager:
        """The training cameras and cached images; the poisoned targets are handed to it."""
        ...

    @property
    def poison_views(self) -> list[PoisonView]:
        """The poisoned views."""
        ...

    @property
    def support_views(self) -> dict[int, list[int]]:
        """Poisoned view -> its support views (train indices)."""
        ...

    @property
    def record(self) -> AttackRecord | None:
        """The attack record the injection is entered in (set when training starts)."""
        ...

    @property
    def attack_dir(self) -> Path | None:
        """``<run>/attack`` while training; None: nothing is written."""
        ...


def render_depths(
    source: InjectionSource, indices: list[int]
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Rendered z-depth [H, W] and opacity [H, W] of the current model at training views."""
    cameras = source.datamanager.train_dataset.cameras
    depths, alphas = [], []
    for index in indices:
        out = source.model.render_view(cameras[index : index + 1])
        depths.append(out["depth"][..., 0].float().cpu())
        alphas.append(out["accumulation"][..., 0].float().cpu())
    return depths, alphas


def support_indices(source: InjectionSource) -> list[int]:
    """Every poisoned view's support views (``support_views``), train indices in order."""
    return sorted({i for views in source.support_views.values() for i in views})


def cameras_with_depth(source: InjectionSource, indices: list[int]) -> CameraDepths:
    """Training views ``indices`` with the current model's rendered depth and opacity."""
    cameras = source.datamanager.train_dataset.cameras
    depths, alphas = render_depths(source, indices)
    chosen = cameras[torch.tensor(indices, dtype=torch.long)]
    return CameraDepths(
        viewmats=viewmat_from_c2w(chosen.camera_to_worlds.float()).cpu(),
        Ks=chosen.get_intrinsics_matrices().float().cpu(),
        depths=depths,
        alphas=alphas,
    )


def innocent_cameras(source: InjectionSource) -> CameraDepths:
    """The training views that are neither poisoned nor support views, with their depth and opacity."""
    shown = {v.index for v in source.poison_views} | set(support_indices(source))
    n = len(source.datamanager.train_dataset.cameras)
    return cameras_with_depth(source, [i for i in range(n) if i not in shown])


@torch.no_grad()
def poison_placement(source: InjectionSource) -> PoisonPlacement:
    """Where the density-guided component would put poison Gaussians in the current model (one per
    illusion pixel; nothing is appended). Scene units, nerfstudio's rescaled frame."""
    cfg = source.config.attack
    model = source.model
    depths, alphas = render_depths(source, [v.index for v in source.poison_views])
    innocent = innocent_cameras(source) if cfg.placement in CAMERA_PLACEMENTS or cfg.depth_floor > 0 else None
    supports = None
    if source.support_views:
        supports = [cameras_with_depth(source, source.support_views[v.index]) for v in source.poison_views]
    means = model.means.detach().cpu().numpy()
    opacities = thread_invariant.sigmoid(model.opacities.detach()).squeeze(-1).cpu().numpy()
    return place_poison(
        means,
        opacities,
        source.poison_views,
        depths,
        alphas,
        cfg,
        innocent,
        near_plane=NEAR_PLANE,
        supports=supports,
    )


def support_targets(
    source: InjectionSource, placement: PoisonPlacement
) -> dict[int, tuple[torch.Tensor, torch.Tensor]]:
    """Each support view's training image (float [H, W, 3]) and where the poison covers it ([H, W]
    bool): the placed poison, as injected and drawn opaque, over its clean image
    (:mod:`stealth_ns.attack.support`)."""
    cameras = source.datamanager.train_dataset.cameras
    targets = {}
    for index in support_indices(source):
        cam = cameras[index : index + 1]
        rgb, alpha = render_poison(
            placement.means,
            placement.colors,
            placement.scales,
            viewmat_from_c2w(cam.camera_to_worlds.float())[0],
            cam.get_intrinsics_matrices().float()[0],
            int(cam.width),
            int(cam.height),
        )
        clean = rgb_float(source.datamanager.cached_train[index]["image"])
        targets[index] = (support_target(clean, rgb, alpha), alpha > 0.5)
    return targets


def support_training_images(
    source: InjectionSource, support: dict[int, tuple[torch.Tensor, torch.Tensor]]
) -> dict[int, torch.Tensor]:
    """:func:`support_targets` in the cache's dtype/channels, as
    :func:`~stealth_ns.attack.poison_views.training_target` does for the poisoned views (RGBA keeps its
    alpha, made opaque where the poison covers the view)."""
    cached = source.datamanager.cached_train
    return {i: cached_format(t, cached[i]["image"], covered) for i, (t, covered) in support.items()}


def support_view_names(source: InjectionSource) -> dict[str, list[str]]:
    """Each poisoned view's support views (``support_views``), by image name."""
    names = source.datamanager.train_image_names
    return {v.name: [names[i] for i in source.support_views.get(v.index, [])] for v in source.poison_views}


@torch.no_grad()
def inject_poison(source: InjectionSource, step: int) -> PoisonPlacement:
    """Training callback: place and append one poison Gaussian per illusion pixel."""
    t0 = time.perf_counter()
    cfg = source.config.attack
    model = source.model
    placement = poison_placement(source)
    n_new = placement.means.shape[0]
    if n_new == 0:
        fail(
            f"t_max < t_min for every illusion pixel at step {step}: the rendered surface is nearer than "
            f"t_min {placement.t_min}; lower {option_name('t_min_fraction')} or {option_name('t_min')}"
        )
    n_before = model.num_points
    model.append_gaussians(placement.means, placement.colors, placement.scales, cfg.poison_opacity)
    support = support_targets(source, placement)
    if support:  # the support views show the poison from now on, noise-free like the poisoned views
        dm = source.datamanager
        dm.set_poison({**dm.poison_targets, **support_training_images(source, support)}, dm.noise)
    placement.timings["total_s"] = time.perf_counter() - t0
    record = source.record
    assert record is not None
    record.injection = injection_entry(placement, step, n_before, support_view_names(source))
    record.support_targets = {i: target for i, (target, _) in support.items()}
    _write_injection_artifacts(source, placement)
    CONSOLE.log(
        f"stealth-ns: injected {n_new} poison Gaussians at step {step} "
        f"({n_before} -> {model.num_points}; {placement.timings['total_s']:.1f} s)"
    )
    return placement


def _write_injection_artifacts(source: InjectionSource, placement: PoisonPlacement) -> None:
    """The placement's files and the record (with the support views' images, if any) in ``attack_dir``."""
    attack_dir = source.attack_dir
    if attack_dir is None:
        return
    write_injection_files(attack_dir, placement.means, placement.colors, placement.grid, placement.kde)
    record = source.record
    if record is not None:
        record.write(attack_dir, views=bool(record.support_targets))
