"""The scan itself: score, flag, group and judge the Gaussians of a model (nothing written).

``stealth-ns scan``: is there poison in a trained 3DGS model, and where? No poison tags used.

The model (a PLY from any trainer, or a nerfstudio run: :mod:`stealth_ns.runs.imported`) is put on
the training cameras of its dataset. Each Gaussian is scored by the post-hoc defences that need no
ground truth (:mod:`stealth_ns.defences.posthoc`: view-support, camera-proximity and, when asked for,
grad-concentration) and flagged by their rules; the flagged Gaussians are grouped by the views that
see them most, and each group's effect on its view is rendered (:mod:`stealth_ns.scan.verdict`).
A group whose connected effect covers ``region_threshold`` of its view, with no more than
``max_pixels_per_gaussian`` pixels of it per Gaussian of the group, makes the model *suspicious*
and names that view as targeted; the cleaned model is the input without those groups.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from stealth_ns.attack.injection import median_scene_depth
from stealth_ns.defences.posthoc import DefenceInputs, Scored, final_learning_rates, score
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method.datamanager import dataset_image_names
from stealth_ns.method.render_view import render_camera
from stealth_ns.runs.imported import ImportedModel
from stealth_ns.scan.config import ScanConfig
from stealth_ns.scan.fit import check_fit
from stealth_ns.scan.photos import PhotoUse, photo_signals_refused
from stealth_ns.scan.verdict import (
    EffectRule,
    Region,
    RenderedView,
    effect_mask,
    groups_by_view,
    is_targeted,
    largest_region,
)


@dataclass
class Group:
    """The flagged Gaussians one training view sees most, and what they do to it."""

    view: int
    name: str
    members: np.ndarray
    """``[N]`` bool."""
    region: Region
    targeted: bool
    renders: dict[str, np.ndarray] = field(default_factory=dict)
    """For a targeted view: ``full``, ``without`` and ``flagged`` ([H, W, 3] in [0, 1]) and ``effect``
    ([H, W] bool, the region)."""


@dataclass
class ScanResult:
    """Everything the scan found, before it is written."""

    model: ImportedModel
    config: ScanConfig
    scored: dict[str, Scored]
    flagged: np.ndarray
    """``[N]`` bool: flagged by any signal."""
    groups: list[Group]
    """Every group rendered, largest region first."""
    seconds: dict[str, float]
    render_match: float = float("nan")
    """dB above a flat image of each photo's mean colour: the model's training views rendered against
    their photos (:mod:`stealth_ns.scan.fit`); NaN without photos."""
    photos: PhotoUse = field(default_factory=PhotoUse)
    near_share: float = 1.0
    """The scene's near depth as a share of each view's median depth
    (:meth:`~stealth_ns.defences.posthoc.DefenceInputs.near_share`): the near lines are shares of it."""

    @property
    def targeted(self) -> list[Group]:
        return [g for g in self.groups if g.targeted]

    @property
    def verdict(self) -> str:
        return "suspicious" if self.targeted else "clean"

    @property
    def removed(self) -> np.ndarray:
        """``[N]`` bool: the Gaussians of the targeted views' groups (what the cleaned model lacks)."""
        out = np.zeros_like(self.flagged)
        for g in self.targeted:
            out |= g.members
        return out


@torch.no_grad()
def _render(model: Any, camera: Any, keep: np.ndarray | None) -> RenderedView:
    with model.kept(None if keep is None else torch.from_numpy(keep)):
        out = render_camera(model, camera)
    return RenderedView(
        out["rgb"].float().clamp(0, 1).cpu().numpy(),
        out["accumulation"][..., 0].float().cpu().numpy(),
        out["depth"][..., 0].float().cpu().numpy(),
    )


def _group_effect(model: Any, camera: Any, members: np.ndarray, rule: EffectRule) -> tuple[Region, dict]:
    full, rest, group = (_render(model, camera, keep) for keep in (None, ~members, members))
    depth = median_scene_depth(torch.from_numpy(full.depth), torch.from_numpy(full.alpha), np.inf)
    region = largest_region(effect_mask(full, rest, group, depth, rule))
    return region, {"full": full.rgb, "without": rest.rgb, "flagged": group.rgb, "effect": region.mask}


def _render_match(
    imported: ImportedModel, cfg: ScanConfig, photos: PhotoUse, echo: Callable[[str], None]
) -> float:
    """:func:`check_fit`'s render match with photos; NaN, the step skipped, without."""
    if not photos.used:
        refused = photo_signals_refused(photos, cfg.signals)
        if refused:
            raise StealthNSError(refused)
        echo("  render match: skipped (no photos): the model is judged on its cameras alone")
        return float("nan")
    render_match = check_fit(imported, cfg.render_match_floor)
    echo(
        f"  render match: {render_match:+.1f} dB against a flat image of each photo's mean colour "
        f"(floor {cfg.render_match_floor:+g} dB)"
    )
    return render_match


def scan_model(
    imported: ImportedModel,
    cfg: ScanConfig,
    echo: Callable[[str], None] = lambda line: None,
    photos: PhotoUse | None = None,
) -> ScanResult:
    """Score, flag, group and judge the Gaussians of ``imported`` (nothing written); a one-line
    StealthNSError for a model that does not sit on its dataset's cameras (:func:`check_fit`).
    ``photos`` says whether the dataset's images are photos (the default) or placeholders: without
    photos the steps that compare with them are skipped (:mod:`stealth_ns.scan.photos`) and the
    images are never read."""
    cfg.validate()
    photos = photos or PhotoUse()
    render_match = _render_match(imported, cfg, photos, echo)
    run = imported.run
    model, dm = run.model, run.pipeline.datamanager
    cameras = dm.train_dataset.cameras
    names = dataset_image_names(run.data, dm.train_dataparser_outputs.image_filenames)
    images = [dm.cached_train[i]["image"] for i in range(len(dm.train_dataset))] if photos.used else []
    inputs = DefenceInputs(model, cameras, images, final_learning_rates(run.config.optimizers))
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    weights = inputs.view_weights()  # the grouping needs them, whatever the signals
    seconds["view weights"] = round(time.perf_counter() - t0, 2)
    near_share = inputs.near_share()
    defend, effect = cfg.defend_config(near_share), cfg.effect_rule(near_share)
    lines = f"{defend.proximity_threshold:.2f} (flags) and {effect.near_ratio:.2f} (effect)"
    echo(f"  near depth: {near_share:.2f} of each view's median depth; near lines at {lines} of the median")
    scored = {}
    for name in cfg.signals:
        scored[name] = score(name, inputs, defend)
        seconds[name] = scored[name].seconds
        count = int(scored[name].pruned.sum())
        echo(f"  {name}: {count} of {model.num_points} Gaussians flagged ({scored[name].rule})")
    flagged = np.logical_or.reduce([s.pruned for s in scored.values()])
    t0 = time.perf_counter()
    groups = []
    for view, members in groups_by_view(flagged, weights, cfg.min_group, cfg.group_share).items():
        region, renders = _group_effect(model, cameras[view : view + 1], members, effect)
        targeted = is_targeted(region, int(members.sum()), cfg.region_threshold, cfg.max_pixels_per_gaussian)
        groups.append(Group(view, names[view], members, region, targeted, renders if targeted else {}))
    groups.sort(key=lambda g: (-g.region.share, g.view))
    seconds["groups"] = round(time.perf_counter() - t0, 2)
    return ScanResult(imported, cfg, scored, flagged, groups, seconds, render_match, photos, near_share)
