"""The dataset attacks' settings without torch, so ``stealth-ns ipa-poison --help`` is quick: IPA-Splat's
(:class:`IPAConfig`) and the data-only attack's defaults (:func:`data_only_attack_defaults`)."""

from __future__ import annotations

from dataclasses import dataclass

from stealth_ns.attack.config import AttackConfig
from stealth_ns.foundation.errors import StealthNSError


def data_only_attack_defaults() -> AttackConfig:
    """The attack ``stealth-ns poison-dataset`` writes unless told otherwise: a static dataset gets no
    noise unless asked for, and then constant (the decaying schedule cannot apply)."""
    return AttackConfig(view_noise=False, noise_decay="constant")


@dataclass
class IPAConfig:
    """IPA-Splat's settings (``stealth-ns ipa-poison``)."""

    epsilon: float = 32.0
    """L-infinity budget of each poisoned image around the clean one, on the 0-255 scale: the paper's
    IPA-Splat setting (§4.1, "distortion budget 32"); IPA-NeRF's own default is 16."""
    every: int = 200
    """Normal training steps per attack epoch (the paper's T = 200)."""
    attack_steps: int = 10
    """Adam steps of each attack epoch (the paper's A = 10)."""
    neighbours: int = 8
    """Training views nearest each backdoor view (by camera centre) whose loss keeps the attacked copy
    faithful there (IPA-NeRF's K perturbation renderings, taken from the training views)."""
    neighbour_weight: float = 0.5
    """Weight of the neighbours' mean L1 loss against the backdoor view's (IPA's eta = 1 weighs their sum
    against the illusion; 0.5 of the mean as the authors' IPA-Splat code does)."""
    angle_limit: float = 15.0
    """Only training views whose viewing direction is within this many degrees of a backdoor view's
    get poisoned images (IPA-NeRF's view constraint, 15 degrees); the others stay clean."""
    budget_means: float = 0.02
    """Largest change of a Gaussian centre per coordinate in an attack epoch, nerfstudio's normalised
    scene units (the poses fill [-1, 1]^3): 1% of the scene."""
    budget_scales: float = 0.25
    """Largest change of a log-scale (a factor of 1.28)."""
    budget_quats: float = 0.1
    """Largest change of a (unnormalised) rotation quaternion component."""
    budget_features: float = 0.25
    """Largest change of a colour coefficient (SH DC and higher bands)."""
    budget_opacities: float = 1.0
    """Largest change of an opacity logit."""

    def budgets(self) -> dict[str, float]:
        """Per parameter group, the largest change of an attack epoch."""
        f = self.budget_features
        return {
            "means": self.budget_means,
            "scales": self.budget_scales,
            "quats": self.budget_quats,
            "features_dc": f,
            "features_rest": f,
            "opacities": self.budget_opacities,
        }

    def validate(self) -> None:
        """StealthNSError naming the first bad option."""
        if not 0 < self.epsilon <= 255:
            raise StealthNSError(f"--epsilon must be in (0, 255] (0-255 scale), got {self.epsilon}")
        for name in ("every", "attack_steps"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise StealthNSError(f"--{name.replace('_', '-')} must be a positive integer")
        if int(self.neighbours) != self.neighbours or self.neighbours < 0:
            raise StealthNSError(f"--neighbours must be a non-negative integer, got {self.neighbours}")
        if not 0 <= self.angle_limit <= 180:
            raise StealthNSError(f"--angle-limit must be in [0, 180] degrees, got {self.angle_limit}")
        if self.neighbour_weight < 0 or min(self.budgets().values()) < 0:
            raise StealthNSError("--neighbour-weight and the --budget-* options must be >= 0")
