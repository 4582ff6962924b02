"""The scenes of ``stealth-ns bench attack``: the generated presets and the declared dataset folders, their
column order and labels, and each scene's *kind* (how its poisoned views are chosen: ``uniform``, the
median-indexed frame; ``kde``, the KDE difficulty protocol's Easy / Median / Hard views)."""

from __future__ import annotations

from typing import Literal

#: Generated scenes (presets of ``stealth_ns.scene_generator``) the experiments run on.
PRESETS: tuple[str, ...] = ("orbit", "forward", "facing")
#: Dataset folders with a declared place in the tables, and where the default ``--scenes`` looks
#: for them (relative to the current directory).
FOLDERS: dict[str, str] = {"fox": "../shared/data/fox"}
#: The phone captures at their own resolution (``../shared/data/captures``, COLMAP ``sparse/0``):
#: ``--scenes captures`` names all three, ``--scenes beer`` one. Not in the default list: a run on
#: them takes several times as long as one on a generated scene (docs/design/captures.md).
CAPTURES: dict[str, str] = {name: f"../shared/data/captures/{name}" for name in ("beer", "bird", "cup")}
#: ``--scenes`` words that stand for several dataset folders.
FOLDER_GROUPS: dict[str, dict[str, str]] = {"captures": CAPTURES}
#: The declared scenes, in column order.
SCENES: tuple[str, ...] = (*PRESETS, *FOLDERS)
#: The default of ``--scenes``: every preset and every declared folder (skipped when absent).
DEFAULT_SCENES: tuple[str, ...] = (*PRESETS, *(f"{name}={path}" for name, path in FOLDERS.items()))
SCENE_LABELS: dict[str, str] = {
    "orbit": "orbit (360°, Mip-NeRF 360-like)",
    "forward": "forward (free trajectory, Free-like)",
    "facing": "facing (forward-facing, LLFF-like)",
    "fox": "fox (real hand-held capture)",
}

#: How a scene's poisoned views are chosen (and so which runs it has).
SceneKind = Literal["uniform", "kde"]
SCENE_KINDS: dict[str, SceneKind] = {"orbit": "uniform", "forward": "kde", "facing": "kde", "fox": "kde"}
#: The kind of a dataset folder that is not declared above (``--scenes mine=PATH``).
FOLDER_KIND: SceneKind = "kde"


def scene_kind(scene: str) -> SceneKind:
    """The kind of ``scene``: declared in :data:`SCENE_KINDS`, else a dataset folder's."""
    return SCENE_KINDS.get(scene, FOLDER_KIND)


def scene_label(scene: str) -> str:
    """A scene's label in table headers."""
    return SCENE_LABELS.get(scene, f"{scene} (dataset folder)")


#: The scenes of the KDE protocol's Easy / Median / Hard views, in column order.
KDE_SCENES: tuple[str, ...] = tuple(s for s in SCENES if scene_kind(s) == "kde")
