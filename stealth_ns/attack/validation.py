"""Up-front checks of every :class:`~stealth_ns.attack.config.AttackConfig` option.

:func:`validate_attack_config` is pure (no data, no files read except an illusion mask's
existence) and raises :class:`~stealth_ns.foundation.errors.StealthNSError` with one line naming the option as
the command the user typed spells it (:class:`~stealth_ns.attack.options.OptionSpelling`: ns-train's
``--pipeline.attack.t-min``, stealth-ns' ``--t-min``), the value given and the allowed range.
The pipeline calls it when it is built, before any data is loaded, so that a bad value never
ends in a traceback (or, worse, in a silently useless attack) after start-up; ``stealth-ns
poison-dataset`` and ``ipa-poison`` call it with their own spelling before they load anything.
"""

from __future__ import annotations

import math
import typing
from dataclasses import fields
from typing import Any

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.options import OptionSpelling, command_spelling, option_words
from stealth_ns.foundation.errors import StealthNSError

__all__ = ["MAX_GRID_RESOLUTION", "MAX_SAMPLES_PER_RAY", "validate_attack_config"]

MAX_GRID_RESOLUTION = 1024
"""Largest KDE grid side: the density grid holds ``grid_resolution**3`` floats (4 GiB at 1024)."""
MAX_SAMPLES_PER_RAY = 1 << 16
"""Most samples per illusion ray (the authors used 8192)."""
MAX_SUPPORT_VIEWS = 8
"""Most support views per poisoned view: beyond, the view-specific illusion is an object in the scene."""


def _bad(spelling: OptionSpelling, name: str, value: Any, allowed: str) -> StealthNSError:
    return StealthNSError(f"{spelling.name(name)} must be {allowed}, got {value!r}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    """A finite int or float (NaN and +-inf are not)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _real(cfg: AttackConfig, sp: OptionSpelling, name: str, allowed: str, ok, optional: bool = False) -> None:
    value = getattr(cfg, name)
    if optional and value is None:
        return
    if not _is_real(value) or not ok(float(value)):
        raise _bad(sp, name, value, allowed)


def _int(cfg: AttackConfig, sp: OptionSpelling, name: str, allowed: str, ok, optional: bool = False) -> None:
    value = getattr(cfg, name)
    if optional and value is None:
        return
    if not _is_int(value) or not ok(value):
        raise _bad(sp, name, value, allowed)


def _choices(name: str) -> tuple[str, ...]:
    """The values the ``Literal`` type of option ``name`` allows (``noise_decay``: the schedule's
    :data:`~stealth_ns.attack.noise_schedule.NoiseDecay`)."""
    return typing.get_args(typing.get_type_hints(AttackConfig)[name])


def validate_attack_config(
    cfg: AttackConfig, max_iterations: int | None = None, spelling: OptionSpelling | None = None
) -> None:
    """Raise :class:`StealthNSError` (one line) for the first option of ``cfg`` out of its range.

    ``max_iterations``: the run's training length, when known; the injection step must come before it.
    ``spelling``: how the command the user typed spells the options (None: the command running's,
    :func:`~stealth_ns.attack.options.spelled_as`; ns-train's outside any).
    """
    sp = spelling or command_spelling()
    for name in ("enabled", "gt_replacement", "density_guided", "view_noise", "outlier_removal"):
        if not isinstance(getattr(cfg, name), bool):
            raise _bad(sp, name, getattr(cfg, name), "True or False")
    _check_illusion(cfg, sp)
    _check_views(cfg, sp)
    _check_density_and_search(cfg, sp)
    for name in ("placement", "tie_break", "noise_decay"):
        choices = _choices(name)
        if getattr(cfg, name) not in choices:
            raise _bad(sp, name, getattr(cfg, name), "one of " + ", ".join(choices))
    _check_injection(cfg, sp, max_iterations)
    _real(cfg, sp, "noise_sigma0", "finite and >= 0 (0-255 scale)", lambda v: v >= 0.0)
    _int(cfg, sp, "seed", "an integer >= 0", lambda v: v >= 0)

    unchecked = {f.name for f in fields(AttackConfig)} - _CHECKED
    if unchecked:  # a new option without a rule: fail loudly in tests, not silently for users
        raise AssertionError(f"AttackConfig options without a check: {sorted(unchecked)}")


def _check_illusion(cfg: AttackConfig, sp: OptionSpelling) -> None:
    """``illusion``, ``illusion_mask``, ``illusion_center``, ``illusion_scale``."""
    if not isinstance(cfg.illusion, str) or not cfg.illusion.strip():
        raise _bad(sp, "illusion", cfg.illusion, "a built-in illusion name or an image path")
    mask = cfg.illusion_mask
    if mask is not None and (not str(mask).strip() or not _path_exists(mask)):
        raise _bad(sp, "illusion_mask", str(mask), "None or an existing mask image")
    center = cfg.illusion_center
    if (
        not isinstance(center, (tuple, list))
        or len(center) != 2
        or not all(_is_real(c) and 0.0 <= float(c) <= 1.0 for c in center)
    ):
        raise _bad(
            sp,
            "illusion_center",
            center,
            "two fractions (x y) of the view's width and height, each in [0, 1]",
        )
    _real(
        cfg,
        sp,
        "illusion_scale",
        "in (0, 1] (a fraction of the view's height; a larger illusion does not fit)",
        lambda v: 0.0 < v <= 1.0,
    )


def _check_views(cfg: AttackConfig, sp: OptionSpelling) -> None:
    """``views`` and ``multi_view``."""
    views = cfg.views
    if not isinstance(views, (tuple, list)) or not all(
        (isinstance(v, str) and v.strip()) or (_is_int(v) and v >= 0) for v in views
    ):
        raise _bad(sp, "views", views, "training-view indices (>= 0) or image names")
    _int(cfg, sp, "multi_view", "1, 2, 3 or 4", lambda v: 1 <= v <= 4)
    most = MAX_SUPPORT_VIEWS
    _int(cfg, sp, "support_views", f"an integer in [0, {most}]", lambda v: 0 <= v <= most)
    if cfg.support_views and not (cfg.density_guided and cfg.gt_replacement):
        raise StealthNSError(
            f"{sp.name('support_views')} {cfg.support_views} shows the poison in more views: it needs "
            f"{option_words('density_guided', True, sp)} and {option_words('gt_replacement', True, sp)}"
        )


def _check_density_and_search(cfg: AttackConfig, sp: OptionSpelling) -> None:
    """The KDE grid (``voxel_size``, ``grid_resolution``, ``bandwidth``) and the ray search's numbers."""
    _real(cfg, sp, "voxel_size", "None or > 0 (scene units)", lambda v: v > 0.0, optional=True)
    _int(
        cfg,
        sp,
        "grid_resolution",
        f"an integer in [2, {MAX_GRID_RESOLUTION}]",
        lambda v: 2 <= v <= MAX_GRID_RESOLUTION,
    )
    _real(cfg, sp, "bandwidth", "> 0 (voxels)", lambda v: v > 0.0)
    _real(cfg, sp, "visibility_margin", ">= 0 (a fraction of the rendered depth)", lambda v: v >= 0.0)
    _real(
        cfg,
        sp,
        "t_min_fraction",
        "in (0, 1) (a fraction of the median rendered depth)",
        lambda v: 0.0 < v < 1.0,
    )
    _real(
        cfg,
        sp,
        "unseen_t_min_fraction",
        "in (0, 1) (a fraction of the median rendered depth)",
        lambda v: 0.0 < v < 1.0,
    )
    _real(
        cfg,
        sp,
        "depth_floor",
        "in [0, 1) (a share of each camera's median rendered depth; 0 = off)",
        lambda v: 0.0 <= v < 1.0,
    )
    _real(cfg, sp, "proximity_weight", ">= 0 (0 = off)", lambda v: v >= 0.0)
    if cfg.proximity_weight > 0.0 and not cfg.density_guided:
        raise StealthNSError(
            f"{sp.name('proximity_weight')} {cfg.proximity_weight:g} trains the poison Gaussians: it needs "
            f"{option_words('density_guided', True, sp)}"
        )
    _real(
        cfg,
        sp,
        "proximity_target",
        "in (0, 1) (a share of each camera's median rendered depth)",
        lambda v: 0.0 < v < 1.0,
    )
    _real(
        cfg,
        sp,
        "t_min",
        "None or > 0 (scene units, in front of the camera)",
        lambda v: v > 0.0,
        optional=True,
    )
    _int(
        cfg,
        sp,
        "samples_per_ray",
        f"an integer in [1, {MAX_SAMPLES_PER_RAY}]",
        lambda v: 1 <= v <= MAX_SAMPLES_PER_RAY,
    )


def _check_injection(cfg: AttackConfig, sp: OptionSpelling, max_iterations: int | None) -> None:
    """``injection_step`` (before ``max_iterations`` when known), ``poison_opacity``, ``poison_scale``,
    ``poisoned_view_repeat``."""
    if max_iterations is None:
        _int(
            cfg, sp, "injection_step", "None (end of warm-up) or a step >= 0", lambda v: v >= 0, optional=True
        )
    else:
        _int(
            cfg,
            sp,
            "injection_step",
            f"None (end of warm-up) or a step in [0, {max_iterations}) (the run's --max-num-iterations)",
            lambda v: 0 <= v < max_iterations,
            optional=True,
        )
    _real(cfg, sp, "poison_opacity", "in (0, 1) (open interval)", lambda v: 0.0 < v < 1.0)
    _real(cfg, sp, "poison_scale", "> 0 (pixel footprints)", lambda v: v > 0.0)
    _int(cfg, sp, "poisoned_view_repeat", "an integer >= 1 (draws per pass)", lambda v: v >= 1)


_CHECKED = frozenset(
    {
        "enabled",
        "gt_replacement",
        "density_guided",
        "view_noise",
        "outlier_removal",
        "illusion",
        "illusion_mask",
        "illusion_center",
        "illusion_scale",
        "views",
        "multi_view",
        "voxel_size",
        "grid_resolution",
        "bandwidth",
        "visibility_margin",
        "support_views",
        "t_min_fraction",
        "unseen_t_min_fraction",
        "depth_floor",
        "proximity_weight",
        "proximity_target",
        "t_min",
        "samples_per_ray",
        "placement",
        "tie_break",
        "noise_decay",
        "injection_step",
        "poison_opacity",
        "poison_scale",
        "poisoned_view_repeat",
        "noise_sigma0",
        "seed",
    }
)


def _path_exists(path: Any) -> bool:
    from pathlib import Path

    try:
        return Path(path).expanduser().is_file()
    except (OSError, TypeError, ValueError):
        return False
