"""Options of ``stealth-ns defend`` (a plain dataclass: importing it pulls in neither torch nor nerfstudio).

Each default says where it comes from. The defences themselves: docs/design/defences.md.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Defences that score and prune the Gaussians of a trained model.
POSTHOC: tuple[str, ...] = (
    "zscore",
    "sor",
    "count-cap",
    "view-support",
    "grad-concentration",
    "camera-proximity",
)
#: Defences applied while training (the model is retrained).
TRAINING_TIME: tuple[str, ...] = ("input-filter",)
DEFENCES: tuple[str, ...] = POSTHOC + TRAINING_TIME
#: Image filters of the input-filter defence (:mod:`stealth_ns.images.input_filter`).
INPUT_FILTERS: tuple[str, ...] = ("wavelet", "gaussian")


@dataclass
class DefendConfig:
    """How each defence scores and where it cuts."""

    defences: tuple[str, ...] = DEFENCES
    """Which defences to run (input-filter retrains the run: a training's time)."""
    zscore_threshold: float = 3.5
    """zscore prunes Gaussians whose largest robust (median/MAD) z-score exceeds this: Iglewicz and
    Hoaglin's outlier cut for the modified z-score."""
    sor_neighbours: int = 20
    """sor: neighbours of each centre. 20 and 2.0 are what the authors' pre-processing passes to
    open3d's statistical outlier removal before placing poison (../shared/notes)."""
    sor_std_ratio: float = 2.0
    """sor prunes centres whose mean neighbour distance exceeds the cloud's mean by this many stds."""
    count_cap_keep: float = 0.9
    """count-cap keeps this share of the Gaussians, the most important ones (summed blending weight
    over the training views), as Poison-splat's naive defence caps the count."""
    concentration_threshold: float = 0.5
    """view-support and grad-concentration prune Gaussians whose support is concentrated in fewer
    than 1/threshold views (effective view count 1/score < 2 at 0.5)."""
    finetune_epochs: int = 2
    """grad-concentration: passes over the training views of the short fine-tune (one Adam step per
    view, the run's final learning rates)."""
    proximity_threshold: float = 0.15
    """camera-proximity prunes Gaussians nearer a training camera that has them in view than this
    share of the camera's median scene depth. Measured on the clean runs of the stealth tables
    (docs/design/stealth.md): the nearest clean Gaussian sits at 0.19 (forward), 0.31 (facing), 0.34
    (orbit), 0.44 (fox), so 0.15 prunes no clean Gaussian there; the default attack's poison sits at
    a median 0.03 (facing), 0.05 (orbit), 0.20 (fox)."""
    input_filter: str = "wavelet"
    """input-filter's image filter: wavelet (scikit-image BayesShrink soft thresholding, as
    DefenseSplat filters inputs) or gaussian (low-pass, sigma input_filter_sigma pixels)."""
    input_filter_sigma: float = 1.0
    """Standard deviation (pixels) of the gaussian input filter."""
    seed: int = 0
    """Seed of the fine-tune's view order (everything else is deterministic)."""

    def validate(self) -> None:
        """ValueError naming the option when a value is out of range or unknown."""
        unknown = [d for d in self.defences if d not in DEFENCES]
        if unknown:
            raise ValueError(f"unknown defence {unknown[0]!r}; choose from {', '.join(DEFENCES)}")
        if not self.defences:
            raise ValueError("--defences is empty; choose from " + ", ".join(DEFENCES))
        if self.input_filter not in INPUT_FILTERS:
            raise ValueError(
                f"--input-filter must be one of {', '.join(INPUT_FILTERS)}, got {self.input_filter!r}"
            )
        checks = (
            ("--count-cap-keep", 0.0 < self.count_cap_keep <= 1.0, "in (0, 1]"),
            ("--concentration-threshold", 0.0 < self.concentration_threshold <= 1.0, "in (0, 1]"),
            ("--sor-neighbours", self.sor_neighbours >= 1, "at least 1"),
            ("--sor-std-ratio", self.sor_std_ratio > 0, "positive"),
            ("--zscore-threshold", self.zscore_threshold > 0, "positive"),
            ("--finetune-epochs", self.finetune_epochs >= 1, "at least 1"),
            ("--proximity-threshold", self.proximity_threshold > 0, "positive"),
            ("--input-filter-sigma", self.input_filter_sigma > 0, "positive"),
        )
        for name, ok, rule in checks:
            if not ok:
                raise ValueError(f"{name} must be {rule}, got {getattr(self, name[2:].replace('-', '_'))}")
