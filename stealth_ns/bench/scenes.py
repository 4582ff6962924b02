"""The scenes of ``bench attack --scenes`` (generated presets and dataset folders ``NAME=PATH``) and
their KDE views (Easy / Median / Hard), cached next to the scene.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from stealth_ns.datasets.check import DatasetSummary, check_colmap, check_dataset
from stealth_ns.datasets.source import SceneSource, inspect_folder
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.method_configs.attack_experiments import (
    CAPTURES,
    DEFAULT_SCENES,
    FOLDER_GROUPS,
    FOLDERS,
    KDE_LEVELS,
    PRESETS,
    SCENES,
)

_SCENE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def parse_scenes(values: Sequence[str] | None) -> tuple[tuple[SceneSource, ...], tuple[str, ...]]:
    """The scenes of ``--scenes`` (None: :data:`DEFAULT_SCENES`) and one "skipping ..." line per
    dataset folder of the default that is absent.

    Values are presets (``orbit``), ``all`` (the default list), a declared folder by its name
    (``fox``, ``beer``: its default path), ``captures`` (the phone captures, :data:`CAPTURES`) or
    ``NAME=PATH`` (a dataset folder; the path may hold commas and
    spaces). A folder given explicitly must exist; one of the default list (or of ``all``) that
    does not is skipped. Bad specs raise :class:`StealthNSError`: unknown name, empty path, a
    name given twice, a folder named like a preset, a missing folder, an unknown dataset format.
    """
    optional_default = values is None
    specs: list[tuple[str, str | None, bool]] = []  # (name, folder or None for a preset, optional)
    for value in DEFAULT_SCENES if values is None else values:
        text = str(value).strip()
        for item in [text] if "=" in text else text.replace(",", " ").split():
            if item.lower() == "all":
                specs += [_scene_spec(v, optional=True) for v in DEFAULT_SCENES]
            elif item.lower() in FOLDER_GROUPS:
                specs += [(name, path, False) for name, path in FOLDER_GROUPS[item.lower()].items()]
            else:
                specs.append(_scene_spec(item, optional=optional_default))
    if not specs:
        raise StealthNSError(f"no scene given; scenes: {_known_scenes()}")
    seen: dict[str, str | None] = {}
    chosen: list[tuple[str, str | None, bool]] = []
    for name, folder, optional in specs:
        if name in seen:
            if folder is None and seen[name] is None:
                continue  # a preset twice ("all orbit"): the same scene
            raise StealthNSError(f"scene {name!r} is given twice in --scenes")
        seen[name] = folder
        chosen.append((name, folder, optional))
    sources: list[SceneSource] = []
    skipped: list[str] = []
    for name, folder, optional in chosen:
        if folder is None:
            sources.append(SceneSource(name))
        elif optional and not Path(folder).expanduser().exists():
            skipped.append(
                f"skipping {name}: {folder} not found (a dataset folder of the default --scenes; "
                f"give --scenes {name}=PATH to use it from elsewhere)"
            )
        else:
            src = inspect_folder(name, folder)
            summary = check_source(src)  # what training would refuse, before any run is planned
            if summary is not None:
                src = replace(src, views=summary.n_frames, sizes=summary.sizes)
            sources.append(src)
    order = {name: i for i, name in enumerate(SCENES)}
    sources.sort(key=lambda src: order.get(src.name, len(order)))  # stable: other folders as given
    return tuple(sources), tuple(skipped)


def _known_scenes() -> str:
    return f"{' '.join((*SCENES, *CAPTURES, *FOLDER_GROUPS))}, or NAME=PATH for a dataset folder"


def _scene_spec(item: str, optional: bool) -> tuple[str, str | None, bool]:
    """``(name, folder or None, optional)`` of one ``--scenes`` item."""
    if "=" not in item:
        if item in PRESETS:
            return item, None, False
        if item in FOLDERS:
            return item, FOLDERS[item], optional
        if item in CAPTURES:
            return item, CAPTURES[item], False
        raise StealthNSError(f"unknown scene {item!r}; scenes: {_known_scenes()}")
    name, folder = (part.strip() for part in item.split("=", 1))
    if not _SCENE_NAME.fullmatch(name) or name.lower() == "all":
        raise StealthNSError(
            f"bad scene name {name!r} in {item!r}: use letters, digits, '_', '-' and '.' (NAME=PATH)"
        )
    if name in PRESETS or any(name.startswith(f"{p}-seed") for p in PRESETS):
        raise StealthNSError(
            f"scene name {name!r} ({item!r}) is taken by the generated preset {name.split('-')[0]}; "
            "give the folder another name"
        )
    if not folder:
        raise StealthNSError(f"no folder given for scene {name!r} ({item!r}); use NAME=PATH")
    return name, folder, optional


def kde_views(dataset: Path, cache: Path, fingerprint: str, write_cache: bool) -> dict[str, str]:
    """Easy / Median / Hard training views of a dataset by the KDE protocol (``rank_scene_views``).

    Cached in ``cache`` (next to the scene, under ``OUTPUT/scenes``) while the dataset's
    ``fingerprint`` (a generated scene's scene.json, a folder's content hash) is the same.
    """
    try:
        data = json.loads(cache.read_text())
        if data.get("fingerprint") == fingerprint and set(data.get("views", {})) == set(KDE_LEVELS):
            return {k: str(v) for k, v in data["views"].items()}
    except (OSError, ValueError, AttributeError):
        pass
    try:
        from stealth_ns.difficulty.rank import rank_scene_views
    except ImportError as err:
        raise StealthNSError(f"the KDE difficulty protocol is not available ({err})") from None
    ranking = rank_scene_views(dataset)
    views = {"easy": ranking.easy, "median": ranking.median, "hard": ranking.hard}
    if write_cache:
        cache.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(cache, {"fingerprint": fingerprint, "dataset": str(dataset), "views": views})
    return views


def scene_fingerprint(plan_dir: Path, src: SceneSource, record: dict[str, Any] | None) -> str:
    if src.is_preset:
        return (plan_dir / "scene.json").read_text()
    return src.sha256 + (f":{record['ply_sha256']}" if record else "")


def check_source(src: SceneSource) -> DatasetSummary | None:
    """The check ns-train runs when it starts (:func:`stealth_ns.method.datamanager.check_nerfstudio_data`),
    run on a dataset folder before a benchmark plans runs on it: StealthNSError with one line, naming the
    scene, for what training would refuse; else what it found (None for a preset, or a Blender folder:
    converted first, nothing to check)."""
    if src.path is None:
        return None
    try:
        if src.format == "nerfstudio-data":
            return check_dataset(src.path)
        if src.format == "colmap":
            return check_colmap(src.path, str(src.colmap_path))
    except StealthNSError as err:
        raise StealthNSError(f"scene {src.name}: {err}") from None
    return None
