"""``stealth-ns poison-dataset`` and ``stealth-ns ipa-poison``: their options, as tyro parses them, checked
before torch and nerfstudio load, and the commands."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from stealth_ns.attack.config import AttackConfig
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.poisoned_datasets.config import IPAConfig, data_only_attack_defaults


@dataclass
class PoisonDataset:
    """Write a poisoned copy of a dataset (the data-only StealthAttack) that any 3DGS trainer can consume."""

    data: Path
    """nerfstudio-data (transforms.json) or COLMAP (sparse/0 + images/) dataset folder; never written."""
    output: Path
    """Folder for the poisoned copy (new or empty; its record goes to OUTPUT/attack)."""
    method: Literal["stealth-splat-lite", "stealth-splat"] = "stealth-splat-lite"
    """Method whose data loading and seed-point initialisation place the poison (as ns-train would)."""
    overwrite: bool = False
    """Replace OUTPUT when it is an earlier poisoned copy (never anything else)."""
    attack: Annotated[AttackConfig, tyro.conf.OmitArgPrefixes] = field(
        default_factory=data_only_attack_defaults
    )

    def main(self) -> None:
        from stealth_ns.attack.options import STEALTH_NS
        from stealth_ns.attack.validation import validate_attack_config

        if not self.attack.enabled:
            raise StealthNSError(
                "--enabled False: poison-dataset always writes the attack (copy the folder instead)"
            )
        # at once, not after torch and nerfstudio load (~10 s)
        validate_attack_config(self.attack, spelling=STEALTH_NS)
        from stealth_ns.poisoned_datasets.data_only import poison_dataset

        # --seed (the attack's) also seeds the set-up, as ns-train's --machine.seed would
        summary = poison_dataset(
            self.data, self.output, self.attack, self.method, self.attack.seed, self.overwrite
        )
        print(summary)


@dataclass
class IpaPoison:
    """Write an IPA-Splat poisoned copy of a dataset (the paper's baseline: IPA-NeRF's attack on 3DGS)."""

    data: Path
    """nerfstudio-data or COLMAP dataset folder; never written."""
    output: Path
    """Folder for the poisoned copy (new or empty); the record and the attacker's run go to OUTPUT/attack."""
    illusion: str = "astronaut"
    """The illusion at the backdoor view(s), as --pipeline.attack.illusion (a built-in or an image path)."""
    illusion_mask: Path | None = None
    """Mask image for an RGB illusion, as --pipeline.attack.illusion-mask."""
    illusion_center: tuple[float, float] = (0.5, 0.5)
    """Where the illusion's centre sits in the backdoor view, fractions of (width, height)."""
    illusion_scale: float = 0.4
    """Illusion height as a fraction of the view's height."""
    views: tuple[str, ...] = ()
    """Backdoor training views by index or image name; empty = the median training frame."""
    multi_view: int = 1
    """1..4 backdoor views at 0/90/180/270 degrees about the scene's up axis (as the StealthAttack option)."""
    method: Literal["stealth-splat-lite", "stealth-splat"] = "stealth-splat-lite"
    """The attacker's training method (attack off)."""
    iterations: int | None = None
    """Training steps of the attacker's run (default: the method's)."""
    seed: int = 0
    """Random seed of the attacker's training (--machine.seed)."""
    overwrite: bool = False
    """Replace OUTPUT when it is an earlier poisoned copy (never anything else)."""
    ipa: Annotated[IPAConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=IPAConfig)

    def main(self) -> None:
        from stealth_ns.attack.options import STEALTH_NS
        from stealth_ns.attack.validation import validate_attack_config

        attack = AttackConfig(
            illusion=self.illusion,
            illusion_mask=self.illusion_mask,
            illusion_center=self.illusion_center,
            illusion_scale=self.illusion_scale,
            views=self.views,
            multi_view=self.multi_view,
            gt_replacement=False,
            density_guided=False,
            view_noise=False,
            seed=self.seed,
        )
        validate_attack_config(attack, spelling=STEALTH_NS)
        if self.iterations is not None and self.iterations < 1:
            raise StealthNSError(f"--iterations must be a positive integer, got {self.iterations}")
        self.ipa.validate()  # these at once, not after torch and nerfstudio load (~10 s)
        from stealth_ns.poisoned_datasets.ipa_splat import ipa_poison

        summary = ipa_poison(
            self.data, self.output, attack, self.ipa, self.method, self.seed, self.iterations, self.overwrite
        )
        print(summary)
