"""``results.json`` of a benchmark: environment, scenes (where each comes from), runs with their
metrics, and the tables' numbers; written with ``tables.md`` after every run.
"""

from __future__ import annotations

import datetime as _dt
import json
import subprocess
import time
from pathlib import Path
from typing import Any

from stealth_ns.bench.plan import Plan, PlannedRun
from stealth_ns.bench.stealth_plot import FRONTIER_PLOT, STEALTH_PLOT, plot_frontier, plot_stealth
from stealth_ns.bench.tables import NOT_IMPLEMENTED, SUCCESS_RULE, render_markdown, table_data
from stealth_ns.datasets.generated import scene_info
from stealth_ns.datasets.source import SceneSource
from stealth_ns.foundation.json_io import json_safe, write_json_atomic
from stealth_ns.foundation.provenance import software_and_hardware
from stealth_ns.method_configs.attack_experiments import (
    scene_kind,
)


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and commit else None


def environment(plan: Plan, started: float, executor: dict[str, Any] | None = None) -> dict[str, Any]:
    """Method, iterations, seed, date, versions and hardware of this benchmark, and where it trained
    (``executor``: the executor's record; default: the plan's options)."""
    return {
        "method": plan.method,
        "iterations": plan.iterations,
        "seed": plan.seed,
        "scene_seed": plan.seed,
        "attack_noise_seed": plan.seed,
        "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "wall_seconds": round(time.time() - started, 1),
        **software_and_hardware(),
        "git_commit": _git_commit(),
        "executor": executor or {"name": plan.executor.name},
    }


def run_entry(p: PlannedRun) -> dict[str, Any]:
    return {
        "scene": p.run.scene,
        "name": p.run.name,
        "label": p.run.label,
        "clean": p.run.clean,
        "tables": list(p.tables),
        "view_choice": p.run.view,
        "kde_view": p.view,
        "args": list(p.spec.options),
        "run_dir": str(p.spec.run_dir),
        "config": str(p.spec.config_path),
        "command": p.spec.command(),
        "status": "pending",
    }


def _folder_info(src: SceneSource) -> dict[str, Any]:
    """Views and resolution (the first view's, width x height) of a nerfstudio-data folder (its
    transforms.json) or a COLMAP folder (as the dataset check found them when the scenes were
    parsed), else unknowns."""
    info: dict[str, Any] = {"resolution": None, "views": None}
    if src.path is None:
        return info
    if src.format == "colmap":
        if src.views is not None:
            info["views"] = src.views
            info["resolution"] = list(src.sizes[0]) if len(src.sizes) == 1 else None
            info["resolutions"] = [list(size) for size in src.sizes]
        return info
    if src.format != "nerfstudio-data":
        return info
    try:
        meta = json.loads((src.path / "transforms.json").read_text(encoding="utf-8"))
        frames = meta["frames"]
        first = frames[0] if frames else {}
        w, h = first.get("w", meta.get("w")), first.get("h", meta.get("h"))
        info["views"] = len(frames)
        info["resolution"] = [int(w), int(h)] if w and h else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    return info


def scene_entry(plan: Plan, scene: str) -> dict[str, Any]:
    """A scene's record in results.json: where it comes from (preset + seed, or folder + content
    hash), what it trains on, its seed points and KDE views."""
    src = plan.sources.get(scene, SceneSource(scene))
    dataparser, dataparser_args = src.dataparser
    entry: dict[str, Any] = {
        "kind": scene_kind(scene),
        "dataset": str(plan.scene_dirs[scene]),
        "dataparser": [dataparser, *dataparser_args],
    }
    if src.is_preset:
        info = scene_info(plan.scene_dirs[scene]) or {}
        entry.update(
            source="preset",
            preset=scene,
            seed=plan.seed,
            path=str(plan.scene_dirs[scene]),
            resolution=info.get("resolution"),
            views=info.get("views"),
            n_train=info.get("n_train"),
            n_test=info.get("n_test"),
            seed_points="generated",
        )
    else:
        entry.update(
            source="folder",
            path=str(src.path),
            given=src.given,
            format=src.format,
            content_sha256=src.sha256,
            files_sha256=dict(src.files),
            **_folder_info(src),
            seed_points=src.seed_points,
        )
        if src.triangulated:
            entry["seed_points_made"] = plan.seed_points.get(scene)
    entry["kde_views"] = plan.views.get(scene)
    if scene in plan.scene_errors:
        entry["error"] = plan.scene_errors[scene]
    return entry


def build_results(plan: Plan, runs: dict[str, dict[str, Any]], env: dict[str, Any], complete: bool) -> dict:
    """The results.json document: environment, scenes, runs (with metrics) and the tables' numbers."""
    return {
        "generator": "stealth-ns bench attack",
        "complete": complete,
        "environment": env,
        "not_implemented": NOT_IMPLEMENTED,
        "success_rule": SUCCESS_RULE,
        "scenes": {scene: scene_entry(plan, scene) for scene in plan.scenes},
        "skipped_scenes": list(plan.skipped_scenes),
        "only": list(plan.only),
        "runs": runs,
        "tables": {str(t.number): table_data(t, runs, plan.scenes) for t in plan.tables},
    }


def write_outputs(
    plan: Plan,
    runs: dict[str, dict[str, Any]],
    started: float,
    complete: bool,
    executor: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write results.json and tables.md (each replaced whole); returns the results document."""
    results = json_safe(build_results(plan, runs, environment(plan, started, executor), complete))
    write_results(plan.output, results)
    return results


def write_results(output: Path, results: dict[str, Any]) -> None:
    """``output/results.json``, ``output/tables.md`` and (when a run's stealth was measured)
    ``output/stealth.png``, with Table 9 runs ``output/frontier.png``, of ``results``, each replaced
    whole."""
    output.mkdir(parents=True, exist_ok=True)
    write_json_atomic(output / "results.json", results)
    tmp = output / ".tables.md.tmp"
    tmp.write_text(render_markdown(results))
    tmp.replace(output / "tables.md")
    plot_stealth(results.get("runs", {}), output / STEALTH_PLOT)
    plot_frontier(results.get("runs", {}), output / FRONTIER_PLOT)
