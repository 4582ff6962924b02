"""What a table of ``stealth-ns bench attack`` is: column groups (a scene, or a difficulty level of one)
and rows, each naming the run it shows in each group (:class:`TableSpec`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from stealth_ns.method_configs.experiment_runs import get_run
from stealth_ns.method_configs.experiment_scenes import PRESETS, scene_kind, scene_label

#: Metric families of a column group: masked metrics at the poisoned view(s), held-out views.
Metric = Literal["v_illusory", "v_test"]
V_ILLUSORY: tuple[Metric, ...] = ("v_illusory",)
BOTH: tuple[Metric, ...] = ("v_illusory", "v_test")


@dataclass(frozen=True)
class Group:
    """A column group: one scene's numbers (V-illusory and/or V-test, PSNR/SSIM/LPIPS each)."""

    scene: str
    level: str = ""
    """A sub-column of the scene (Table 2's "Easy", "Median", "Hard"); empty for the scene itself."""
    metrics: tuple[Metric, ...] = BOTH

    @property
    def label(self) -> str:
        """The group's header: the scene's label, or ``scene Level``."""
        return f"{self.scene} {self.level}" if self.level else scene_label(self.scene)


@dataclass(frozen=True)
class Row:
    """A table row: its key cells and, per column group, the run it shows."""

    keys: tuple[str, ...]
    runs: tuple[str, ...]
    """Run names, one per column group (on that group's scene)."""
    naive: bool = False
    """Show the clean run instead, at the poisoned views of ``runs`` (the paper's "Naive 3DGS
    (w/o attack)" row: the clean model against the same illusion target)."""


@dataclass(frozen=True)
class TableSpec:
    """One of the paper's tables, reproduced on the generated scenes and dataset folders."""

    number: int
    title: str
    key_header: tuple[str, ...]
    groups: tuple[Group, ...]
    rows: tuple[Row, ...]
    asr: bool = False
    """Add the attack-success-rate column (V-illusory > 25 dB and V-test drop <= 3 dB), as n/N
    over the row's column groups (scenes)."""
    notes: tuple[str, ...] = ()
    template: str | None = None
    """A declared scene whose column groups (and runs) every other scene of its kind given to
    ``--scenes`` gets too (see :meth:`for_scenes`); None: the table has its declared groups only."""

    @property
    def scenes(self) -> tuple[str, ...]:
        """The scenes this table needs, in column order."""
        return tuple(dict.fromkeys(g.scene for g in self.groups))

    def for_scenes(self, scenes: tuple[str, ...]) -> TableSpec:
        """This table with column groups for the dataset folders of ``scenes`` it does not declare, when
        they are of its template's kind (a folder ``mine=PATH`` gets columns like ``fox``)."""
        if self.template is None:
            return self
        kind = scene_kind(self.template)
        extra = [s for s in scenes if s not in self.scenes + PRESETS and scene_kind(s) == kind]
        if not extra:
            return self
        like = [i for i, g in enumerate(self.groups) if g.scene == self.template]
        groups = self.groups + tuple(replace(self.groups[i], scene=s) for s in extra for i in like)
        rows = tuple(
            replace(r, runs=r.runs + tuple(r.runs[i] for _ in extra for i in like)) for r in self.rows
        )
        return replace(self, groups=groups, rows=rows)

    def for_attacks(self, attacks: tuple[str, ...]) -> TableSpec:
        """This table without the rows of attacks not in ``attacks`` (:data:`ATTACKS`); naive rows stay."""

        def kept(row: Row) -> bool:
            runs = zip(self.groups, row.runs, strict=True)
            kinds = {get_run(g.scene, name).poisoning or "in-loop" for g, name in runs}
            return row.naive or kinds <= set(attacks)

        return replace(self, rows=tuple(r for r in self.rows if kept(r)))

    def run_keys(self, scenes: tuple[str, ...] | None = None) -> list[str]:
        """``scene/name`` of every run the table shows (its clean baselines excluded)."""
        keys = [
            f"{g.scene}/{name}"
            for row in self.rows
            for g, name in zip(self.groups, row.runs, strict=True)
            if scenes is None or g.scene in scenes
        ]
        return list(dict.fromkeys(keys))
