"""The views the panel offers: every poisoned, innocent-training and held-out view, with its role and pose.

:func:`load_view_set` reads them once, when the viewer sets the panel up: names and cameras from the
pipeline (:meth:`PanelSource.split_views`), poisoned views from the pipeline when it resolved them
(``ns-train``, ``ns-viewer``), else from the run's attack record (``<run>/attack``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from nerfstudio.cameras.cameras import Cameras

from stealth_ns.attack.record import AttackRecord, PoisonView, RecordError
from stealth_ns.method.viewer.poses import ViewPose, match_view, view_poses
from stealth_ns.method.viewer.source import PanelSource

Role = Literal["poisoned", "innocent", "held-out"]
Split = Literal["train", "eval"]
SPLITS: tuple[Split, ...] = ("train", "eval")

ROLE_TEXT: dict[str, str] = {
    "poisoned": "poisoned training view: trained on the illusion composite, the illusion should appear here",
    "innocent": "innocent training view: trained on its clean image, the illusion should not be visible",
    "held-out": "held-out view: never trained on, the illusion should not be visible",
}


@dataclass(frozen=True)
class ViewEntry:
    """One entry of the view dropdown.

    Attributes:
        label: the dropdown option (unique), e.g. ``"poisoned: images/frame_00009.png"``.
        role: ``"poisoned"``, ``"innocent"`` (training) or ``"held-out"``.
        split: ``"train"`` or ``"eval"``: which dataset ``index`` refers to.
        index: index of the camera in that dataset.
        name: the image name shown to the user.
    """

    label: str
    role: Role
    split: Split
    index: int
    name: str


def build_view_entries(
    train_names: Sequence[str], eval_names: Sequence[str], poisoned: Sequence[int]
) -> list[ViewEntry]:
    """All views for the dropdown: the poisoned ones first (in attack order), then the innocent training
    views, then the held-out views (each in dataset order).

    Args:
        train_names: training image names, by training index.
        eval_names: held-out image names, by eval index.
        poisoned: training indices of the poisoned views.

    Returns:
        The entries; labels are ``"<role>: <name>"`` (unique).

    Raises:
        ValueError: a poisoned index is out of range.
    """
    n = len(train_names)
    bad = [i for i in poisoned if not 0 <= int(i) < n]
    if bad:
        raise ValueError(f"poisoned view indices {bad} are out of range: {n} training views")
    entries = [
        ViewEntry(f"poisoned: {train_names[i]}", "poisoned", "train", int(i), train_names[i])
        for i in poisoned
    ]
    chosen = {int(i) for i in poisoned}
    entries += [
        ViewEntry(f"innocent: {nm}", "innocent", "train", i, nm)
        for i, nm in enumerate(train_names)
        if i not in chosen
    ]
    entries += [ViewEntry(f"held-out: {nm}", "held-out", "eval", i, nm) for i, nm in enumerate(eval_names)]
    return entries


@dataclass(frozen=True)
class ViewSet:
    """The panel's views, read once (see the module docstring).

    Attributes:
        entries: the dropdown's views (:func:`build_view_entries`).
        poisoned: the poisoned views (targets and masks as trained), in attack order.
        problems: what could not be read, one line each (shown in the panel).
        poses: the pose of every view, by ``(split, index)``.
        train_cameras: the training cameras (the read-out renders poisoned views with them).
        entry_c2w: ``[len(entries), 3, 4]`` the entries' camera-to-worlds, for :func:`match_view`.
    """

    entries: list[ViewEntry]
    poisoned: list[PoisonView]
    problems: list[str]
    poses: dict[tuple[Split, int], ViewPose]
    train_cameras: Cameras | None
    entry_c2w: np.ndarray

    @classmethod
    def empty(cls) -> ViewSet:
        """No views (before a viewer sets the panel up)."""
        return cls([], [], [], {}, None, np.zeros((0, 3, 4)))

    def entry(self, label: str) -> ViewEntry | None:
        """The view with this dropdown label, if any."""
        return next((e for e in self.entries if e.label == label), None)

    def poisoned_view(self, index: int) -> PoisonView | None:
        """Poisoned training view ``index``, if it is one."""
        return next((v for v in self.poisoned if v.index == index), None)

    def pose(self, entry: ViewEntry) -> ViewPose:
        """The pose of a view."""
        return self.poses[(entry.split, entry.index)]

    def at(self, c2w: np.ndarray) -> ViewEntry | None:
        """The view a camera (``[3, 4]`` camera-to-world, scene units) sits on, if any: :func:`match_view`."""
        hit = match_view(c2w, self.entry_c2w)
        return None if hit is None else self.entries[hit]


def load_view_set(source: PanelSource, attack_dir: Path | None) -> ViewSet:
    """Every view of the pipeline, its poisoned views and what could not be read.

    Args:
        source: the pipeline.
        attack_dir: ``<run>/attack``, read when the pipeline resolved no poisoned views (None: not read).
    """
    splits = source.split_views()
    names = {split: splits[split][0] if split in splits else [] for split in SPLITS}
    train_cameras = splits["train"][1] if "train" in splits else None
    problems: list[str] = []
    poisoned = list(source.poison_views)
    if not poisoned and attack_dir is not None:
        try:
            poisoned = AttackRecord.read(attack_dir, cameras=train_cameras).views
        except RecordError as err:
            problems.append(str(err))
    valid = [v for v in poisoned if 0 <= v.index < len(names["train"])]
    if len(valid) < len(poisoned):
        problems.append("some poisoned views are not among this dataset's training views")
    entries = build_view_entries(names["train"], names["eval"], [v.index for v in valid])
    poses = {
        (split, i): pose
        for split in SPLITS
        if split in splits
        for i, pose in enumerate(view_poses(splits[split][1]))
    }
    c2ws = [poses[(e.split, e.index)].c2w for e in entries]
    entry_c2w = np.stack(c2ws) if c2ws else np.zeros((0, 3, 4))
    return ViewSet(entries, valid, problems, poses, train_cameras, entry_c2w)
