"""Presets of ``stealth-ns bench attack``: the runs and tables of the paper's experiments.

Installed as ``stealth_ns.method_configs.attack_experiments``: the bench's one place to read them from,
each table number mapped to its :class:`TableSpec` (:data:`TABLES`, :func:`get_table`). Everything is
declarative, in modules by concept:

* :mod:`~stealth_ns.method_configs.experiment_scenes` -- the scenes and each scene's *kind*, which
  says how its poisoned views are chosen and which runs it has: ``uniform`` scenes (``orbit``)
  poison the median-indexed frame and carry every ablation; ``kde`` scenes (``forward``,
  ``facing``, ``fox`` and any other dataset folder) are poisoned at the Easy / Median / Hard views
  of the KDE difficulty protocol.
* :mod:`~stealth_ns.method_configs.experiment_runs` -- :data:`RUNS`, every training run of the
  declared scenes, one :class:`RunSpec` per (scene, name) (:func:`scene_runs`). A run that several
  tables show is defined once: ``full`` (all three components, h = 7.5, sigma0 = 100, linear decay,
  the median-indexed view) is Table 1's orbit "Ours", Table 4's h = 7.5, Table 5's 100/linear and
  Table 6's last row. Every attack run spells out all the settings the tables vary, so a run never
  depends on the attack's defaults.
* :mod:`~stealth_ns.method_configs.experiment_tables` -- :class:`TableSpec`: column groups (a
  scene, or a difficulty level of one scene) and rows, each naming the run it shows in each group.
  Tables 1-3 (and the stealth tables) also take any other dataset folder given to ``--scenes``
  (:meth:`TableSpec.for_scenes`).
* :mod:`~stealth_ns.method_configs.paper_tables` -- the paper's Tables 1-6;
  :mod:`~stealth_ns.method_configs.stealth_tables` -- this project's stealth tables 7-9.

Scenes: the generated presets ``orbit`` (stands in for the paper's Mip-NeRF 360: inward 360
degree captures, the median-indexed frame is poisoned), ``forward`` (its Free dataset: free
trajectories), ``facing`` (LLFF-like forward-facing captures) and the real capture ``fox``
(instant-ngp's hand-held phone capture, read from a dataset folder). As in the paper, Table 1's
column of a KDE scene is the Median view of Table 2.

Dataset attacks (:attr:`RunSpec.poisoning`): the paper's IPA-Splat baseline and the data-only
StealthAttack are runs too. The bench writes a poisoned copy of the scene (``stealth-ns ipa-poison`` /
``poison-dataset``) and trains a plain victim (attack off) on it; Tables 1-3 show them beside the
in-loop attack. IPA-NeRF (Nerfacto / Instant-NGP) is not implemented (NeRF methods, not 3DGS).
"""

from __future__ import annotations

from stealth_ns.method_configs.experiment_runs import (
    ATTACKS,
    BANDWIDTHS,
    CLEAN,
    DATA_ONLY_LABEL,
    IPA_LABEL,
    KDE_LEVELS,
    MULTI_VIEWS,
    NOISE_DECAY_ROWS,
    NOISE_SIGMA0S,
    RUNS,
    RunSpec,
    ViewChoice,
    attack_settings,
    clean_run,
    get_run,
    scene_runs,
    shared_run,
    single_view_run,
    stealth_run,
)
from stealth_ns.method_configs.experiment_scenes import (
    CAPTURES,
    DEFAULT_SCENES,
    FOLDER_GROUPS,
    FOLDER_KIND,
    FOLDERS,
    KDE_SCENES,
    PRESETS,
    SCENE_KINDS,
    SCENE_LABELS,
    SCENES,
    SceneKind,
    scene_kind,
    scene_label,
)
from stealth_ns.method_configs.experiment_tables import BOTH, V_ILLUSORY, Group, Metric, Row, TableSpec
from stealth_ns.method_configs.paper_tables import DATA_ONLY_NOTE, NAIVE_NOTE, NO_BASELINES, PAPER_TABLE_SPECS
from stealth_ns.method_configs.stealth_tables import STEALTH_TABLE_SPECS

__all__ = [
    "ATTACKS",
    "BANDWIDTHS",
    "BOTH",
    "CAPTURES",
    "CLEAN",
    "DATA_ONLY_LABEL",
    "DATA_ONLY_NOTE",
    "DEFAULT_SCENES",
    "FOLDERS",
    "FOLDER_GROUPS",
    "FOLDER_KIND",
    "Group",
    "IPA_LABEL",
    "KDE_LEVELS",
    "KDE_SCENES",
    "MULTI_VIEWS",
    "Metric",
    "NAIVE_NOTE",
    "NOISE_DECAY_ROWS",
    "NOISE_SIGMA0S",
    "NO_BASELINES",
    "PAPER_TABLES",
    "PRESETS",
    "RUNS",
    "Row",
    "RunSpec",
    "SCENES",
    "SCENE_KINDS",
    "SCENE_LABELS",
    "SceneKind",
    "TABLES",
    "TableSpec",
    "V_ILLUSORY",
    "ViewChoice",
    "attack_settings",
    "clean_run",
    "get_run",
    "get_table",
    "scene_kind",
    "scene_label",
    "scene_runs",
    "shared_run",
    "single_view_run",
    "stealth_run",
]

#: Every table ``bench attack`` can reproduce, in number order.
TABLES: tuple[TableSpec, ...] = PAPER_TABLE_SPECS + STEALTH_TABLE_SPECS

#: The paper's tables (``bench attack``'s default); 7, 8 and 9 are this project's stealth tables.
PAPER_TABLES: tuple[int, ...] = (1, 2, 3, 4, 5, 6)


def get_table(number: int) -> TableSpec:
    """Table ``number`` (KeyError if none)."""
    for table in TABLES:
        if table.number == number:
            return table
    raise KeyError(number)
