"""Generated scenes (``stealth-ns make-scene`` presets) made once into ``ROOT/scenes/PRESET-seedS``
and reused while complete.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def scene_dir(output: Path, preset: str, seed: int, scene_options: dict[str, Any] | None = None) -> Path:
    """``OUTPUT/scenes/PRESET-seedS`` (with the resolution and view count when not the defaults)."""
    name = f"{preset}-seed{seed}"
    if scene_options:
        name += "".join(f"-{k}{v}" for k, v in sorted(scene_options.items()))
    return output / "scenes" / name


def scene_info(path: Path) -> dict[str, Any] | None:
    """The ``scene.json`` of the generated scene in ``path``; None when it is absent, unreadable, or the
    scene has no transforms.json."""
    try:
        info = json.loads((path / "scene.json").read_text())
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) and (path / "transforms.json").is_file() else None


def scene_is_ready(path: Path, preset: str, seed: int, scene_options: dict[str, Any] | None = None) -> bool:
    """True when ``path`` holds a completely generated scene of this preset and seed.

    ``make_scene`` writes ``scene.json`` last, so its presence means the scene is complete.
    """
    info = scene_info(path)
    if info is None or info.get("preset") != preset or info.get("seed") != seed:
        return False
    opts = scene_options or {}
    if "views" in opts and info.get("views") != opts["views"]:
        return False
    if "resolution" in opts:
        width, height = (int(v) for v in str(opts["resolution"]).lower().split("x"))
        if info.get("resolution") != [width, height]:
            return False
    return True


def ensure_scene(path: Path, preset: str, seed: int, scene_options: dict[str, Any] | None = None) -> None:
    """Generate the scene unless a complete one is there."""
    if scene_is_ready(path, preset, seed, scene_options):
        return
    from stealth_ns.scene_generator import make_scene

    print(f"generating the {preset} scene in {path}", flush=True)
    make_scene(preset=preset, output=path, seed=seed, overwrite=True, **(scene_options or {}))
