"""Options of ``stealth-ns scan`` (a plain dataclass), each default with where it comes from."""

from __future__ import annotations

import math
from dataclasses import dataclass

from stealth_ns.defences.config import DefendConfig
from stealth_ns.scan.verdict import EffectRule

#: The per-Gaussian signals the scan can flag with (the post-hoc defences that need no ground truth).
SIGNALS: tuple[str, ...] = ("view-support", "camera-proximity", "grad-concentration")


def near_line(ratio: float, near_share: float) -> float:
    """Both near lines, as a share of a camera's median scene depth: ``ratio`` times ``near_share`` of
    the near depth, which is itself ``near_share`` of the median depth (``ratio * near_share**2``)."""
    return ratio * near_share**2


@dataclass
class ScanConfig:
    """What flags a Gaussian and when a group of flagged Gaussians makes a model suspicious."""

    signals: tuple[str, ...] = ("view-support", "camera-proximity")
    """Per-Gaussian signals; a Gaussian is flagged when any of them flags it (defend's scores).
    grad-concentration (a short fine-tune over every view, the slowest) only on request."""
    concentration_threshold: float = 0.5
    """view-support / grad-concentration flag a Gaussian seen by fewer than 1/threshold effective
    views (defend's default: 2 views)."""
    proximity_threshold: float = 0.9
    """camera-proximity flags a Gaussian nearer a training camera that has it in view than this share
    of the camera's near depth times the scene's near share ``s``: ``proximity_threshold * s**2`` of the
    camera's median scene depth. ``s`` is the median over the training views of each one's 5th-percentile
    surface depth over its median (0.38-0.40 on a walk-through, ``forward``; 0.72-0.74 on ``fox``).
    The second factor ``s`` moves the line in front of the near surfaces of a scene that comes close to
    its cameras, where the scene's own objects pass near them. Measured (docs/design/scan.md, tenth pass): the
    line at 0.13-0.14 of the median depth on ``forward`` (boxes beside the path at 0.13-0.28; every
    attack there with its poison beyond 0.1 fails) and at 0.48 on ``fox`` (the adaptive attack that
    succeeds furthest out, a depth floor of 0.35 with support views, draws at 0.34-0.42). Measured over
    values of it: the clean walk-throughs stay clean up to 1.15, that attack is found from 0.7."""
    group_share: float = 0.5
    """A flagged Gaussian is in the group of the view that sees it most (its largest blending weight) and
    of every view where its weight is at least this share of its largest (1: the first view alone).
    Poison that K + 1 views see nearly alike (support views) is split among them by the first view
    alone, each view's group drawing part of the picture. Measured (docs/design/scan.md, eighth pass, 51
    models): at 0.5 the weakest successful attack's region at its view went from 1.07 % to 3.49 % (the
    largest elsewhere from 0.28 % to 0.40 %), the held-out table got every model right on both splits
    (at 1: 2 wrong views and 1 miss on one) and every cleaned model defeats its attack (at 1: 16 of 20);
    0.25 and 0.75 get both splits right too, with a narrower gap."""
    min_group: int = 5
    """Fewest flagged Gaussians that make a group worth rendering (fewer cannot cover a region)."""
    opaque: float = 0.5
    """A pixel is covered when the group alone, and the model without it, both exceed this opacity."""
    depth_ratio: float = 0.5
    """...and the group's expected depth is below this share of the rest's there (it floats in front
    of a surface)..."""
    near_ratio: float = 0.9
    """...and below this share of the view's near depth times the near share (as for
    ``proximity_threshold``: it floats near the camera). Measured (docs/design/scan.md): the poison's pixels
    sit at 0.02-0.22 of the median depth (adaptive attacks' up to 0.42 on ``fox``), a walk-through's boxes
    beside the path at 0.13-0.28, the edge of a capture that one view sees alone (the rearmost view of a
    forward trajectory) at 0.37-1.0."""
    colour_change: float = 0.1
    """...and removing the group changes one of its colour channels by more than this (in [0, 1])."""
    region_threshold: float = 0.01
    """A view is targeted when its group's largest connected effect covers this share of the image.
    Measured (docs/design/scan.md, eighth pass, 51 models of 7 scenes): the clean models' largest region is at
    most 0.35 % of a view and a region off an attack's poisoned views at most 0.40 %, a successful
    attack's region at its view at least 3.49 %; thresholds fitted on half the scenes fall at 0.74-1.60 %."""
    max_pixels_per_gaussian: float = 64.0
    """...and its group has at least one Gaussian per this many pixels of the region (an 8x8 block): an
    illusion is a picture, a few large Gaussians paint only a blob. Measured (docs/design/scan.md): every
    poison group's region has 0.05-8.6 pixels per Gaussian of its group, a clean capture's floater
    (``bird``, 10 Gaussians over 1.30 % of a view) 677."""
    frame: str = "auto"
    """World frame of a PLY, one of auto (each frame below tried, the best-matching kept), nerfstudio
    (ns-export), dataset (the dataset's own poses: official 3DGS, OpenSplat without --center, gsplat
    --no-normalize-world-space), colmap (the COLMAP model a nerfstudio-data folder was converted from),
    opensplat-center (OpenSplat --center) or gsplat-normalized (gsplat simple_trainer's default)
    (docs/design/scan.md)."""
    render_match_floor: float = 0.0
    """dB by which the model's renders of three training views must match their photos better than a
    flat image of each photo's mean colour does (in the frame chosen); below it the model is refused,
    not judged: it shows no sign of sitting on these cameras. Measured (docs/design/scan.md): aligned models
    beat the flat image by +1.13 to +10.74 dB (the tests' 60-iteration orbit runs +1.68), models moved
    by a random similarity or put on another scene's cameras fall below it by 0.57 to 5.84 dB; a PSNR
    alone cannot tell them apart (misaligned up to 16.1 dB, aligned down to 11.7)."""
    seed: int = 0
    """Seed of grad-concentration's fine-tune order (everything else is deterministic)."""

    def defend_config(self, near_share: float) -> DefendConfig:
        """The same rules as ``stealth-ns defend`` applies them, camera-proximity's line at
        :func:`near_line` of ``proximity_threshold``."""
        return DefendConfig(
            defences=self.signals,
            concentration_threshold=self.concentration_threshold,
            proximity_threshold=near_line(self.proximity_threshold, near_share),
            seed=self.seed,
        )

    def effect_rule(self, near_share: float) -> EffectRule:
        """The effect's thresholds, its near line at :func:`near_line` of ``near_ratio``."""
        line = near_line(self.near_ratio, near_share)
        return EffectRule(self.opaque, self.depth_ratio, line, self.colour_change)

    def validate(self) -> None:
        """ValueError naming the option when a value is out of range or unknown."""
        unknown = [s for s in self.signals if s not in SIGNALS]
        if unknown or not self.signals:
            raise ValueError(
                f"--signals: {'unknown signal ' + repr(unknown[0]) if unknown else 'none given'}; "
                f"choose from {', '.join(SIGNALS)}"
            )
        checks = (
            ("--concentration-threshold", 0.0 < self.concentration_threshold <= 1.0, "in (0, 1]"),
            ("--proximity-threshold", self.proximity_threshold > 0, "positive"),
            ("--min-group", self.min_group >= 1, "at least 1"),
            ("--group-share", 0.0 < self.group_share <= 1.0, "in (0, 1]"),
            ("--opaque", 0.0 <= self.opaque < 1.0, "in [0, 1)"),
            ("--colour-change", 0.0 <= self.colour_change < 1.0, "in [0, 1)"),
            ("--depth-ratio", 0.0 < self.depth_ratio <= 1.0, "in (0, 1]"),
            ("--near-ratio", self.near_ratio > 0, "positive"),
            ("--region-threshold", 0.0 < self.region_threshold <= 1.0, "in (0, 1]"),
            ("--max-pixels-per-gaussian", self.max_pixels_per_gaussian > 0, "positive"),
            ("--render-match-floor", math.isfinite(self.render_match_floor), "a number"),
        )
        for name, ok, rule in checks:
            if not ok:
                raise ValueError(f"{name} must be {rule}, got {getattr(self, name[2:].replace('-', '_'))}")
