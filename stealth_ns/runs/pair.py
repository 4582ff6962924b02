"""A poisoned run and a clean run of the same scene, loaded and checked to share their dataset."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stealth_ns.attack.record import AttackRecord, PoisonView
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.fingerprint import fingerprint_differences, same_points
from stealth_ns.gaussians.model_files import is_model_file
from stealth_ns.runs.imported import load_model
from stealth_ns.runs.loaded import LoadedRun, attack_record, load_run


@dataclass
class RunPair:
    """A poisoned run and a clean run of the same scene, loaded."""

    poisoned: LoadedRun
    clean: LoadedRun
    record: AttackRecord  # the poisoned run's

    @classmethod
    def load(
        cls, poisoned: Path, clean: Path, poisoned_data: Path | None = None, clean_data: Path | None = None
    ) -> RunPair:
        """Load both; either may be a PLY of another trainer with the dataset it was trained on
        (``*_data``: required for a PLY; the victim of a poisoned copy is scored on that copy)."""
        ours, theirs = _load(poisoned, poisoned_data), _load(clean, clean_data)
        pair = cls(ours, theirs, attack_record(ours, poisoned))
        if pair.clean.attack_enabled:
            raise StealthNSError(
                f"{clean} was trained with the attack on; train the clean run with "
                "--pipeline.attack.enabled False (or any other splatting method)"
            )
        pair.check_distinct(poisoned, clean)
        pair.check_same_dataset()
        return pair

    def check_distinct(self, poisoned: Path, clean: Path) -> None:
        """StealthNSError (one line) when both are one model: the same Gaussians
        (:func:`~stealth_ns.foundation.fingerprint.same_points`), as a copy of the clean run or a PLY
        exported from it given as the poisoned one has; the comparison would measure nothing (a V-test drop
        of 0 dB). ``poisoned``, ``clean``: the runs as the user gave them."""
        ours, theirs = (run.model.means.detach().cpu().numpy() for run in (self.poisoned, self.clean))
        if same_points(ours, theirs):
            raise StealthNSError(
                f"the poisoned model {poisoned} is the clean run {clean}: both hold the same {len(ours)} "
                "Gaussians (a copy of the run, or a model exported from it); give the model trained on the "
                "poisoned data"
            )

    def check_same_dataset(self) -> None:
        """StealthNSError (one line, naming both runs and what differs) unless both runs were trained
        on the same images with the same poses, and are evaluated on the same held-out views."""
        ours, theirs = self.poisoned.fingerprints(), self.clean.fingerprints()
        copied = (self.record.poisoned_dataset or {}).get("source_train_fingerprint")
        if copied:  # a victim of a poisoned copy: its images differ by design; the source's must match
            ours["train"] = {**ours["train"], "images": copied["images"]}
        differ = []
        for split, label in (("train", "training"), ("held-out", "held-out")):
            for what in fingerprint_differences(ours[split], theirs[split]):
                differ.append(f"{label} {'images' if what == 'images' else 'camera poses'}")
        if differ:
            raise StealthNSError(
                f"the runs were not trained on the same dataset: their {_listing(differ)} differ "
                f"(poisoned run {self.poisoned.config_path}, data {self.poisoned.data}, "
                f"{ours['train']['n_images']} training images; clean run {self.clean.config_path}, "
                f"data {self.clean.data}, {theirs['train']['n_images']} training images)"
            )

    @property
    def views(self) -> list[PoisonView]:
        """The poisoned views, as the run's attack record has them."""
        return self.record.views

    @property
    def cameras(self) -> Any:
        return self.poisoned.pipeline.datamanager.train_dataset.cameras


def _load(path: Path, data: Path | None) -> LoadedRun:
    """A run as :func:`load_run` loads it; a model file (PLY, .splat, .spz), or a run given with its
    dataset, as :func:`~stealth_ns.runs.imported.load_model` does."""
    if data is None and not is_model_file(Path(path)):
        return load_run(path)
    return load_model(Path(path), None if data is None else Path(data)).run


def _listing(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]
