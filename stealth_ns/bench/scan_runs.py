"""``stealth-ns bench scan``'s inputs, checked before anything slow (before torch and nerfstudio load):
its options, the ``bench attack`` results it reads (one line for a file that is not one), and the
files it writes into ``--output`` (:func:`~stealth_ns.foundation.output_folder.claim_output`'s rules: never
through a link, never over an input or a file it did not write, recorded in :data:`RECORD`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import check_output_plan, check_outside, check_writable
from stealth_ns.method.checkpoints import checkpoint_steps
from stealth_ns.scan.config import ScanConfig

RESULTS_FILE = "scan-results.json"
TABLE_FILE = "scan.md"
ROC_FILE = "roc.png"
#: ``--as-ply``'s PLYs, a folder the bench scan owns whole.
PLYS_DIR = "plys"
#: The record of the files the bench scan wrote into --output (:mod:`stealth_ns.foundation.file_manifest`).
RECORD = ".stealth-ns-bench-scan.json"
WRITTEN_BY = "stealth-ns bench scan"


def results_path(bench_output: Path) -> Path:
    """The results.json of a ``bench attack`` folder (or that file itself)."""
    return bench_output if bench_output.suffix == ".json" else bench_output / "results.json"


def _read_results(path: Path) -> dict[str, Any]:
    """results.json's ``runs`` table; one-line StealthNSError for a file that is not a bench's results."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise StealthNSError(f"cannot read {path}: {err.strerror or err}") from None
    except UnicodeDecodeError:
        raise StealthNSError(f"{path} is not a `bench attack` results file: not text") from None
    except json.JSONDecodeError as err:
        raise StealthNSError(
            f"{path} is not a `bench attack` results file: not JSON ({err.msg}, line {err.lineno})"
        ) from None
    runs = doc.get("runs") if isinstance(doc, dict) else None
    if not isinstance(runs, dict):
        raise StealthNSError(f"{path} is not a `bench attack` results file: it has no table of runs")
    for key, run in runs.items():
        if not isinstance(run, dict) or not isinstance(run.get("scene"), str):
            raise StealthNSError(f"{path}: run {key!r} is not a run entry of `bench attack` (no scene)")
        if not isinstance(run.get("config", ""), str) or not isinstance(run.get("metrics") or {}, dict):
            raise StealthNSError(
                f"{path}: run {key!r} has a config or metrics that are not a path or a table"
            )
    return runs


def bench_runs(bench_output: Path) -> list[dict[str, Any]]:
    """Every finished run of a ``bench attack`` folder (its results.json, or that file itself), with
    its V-illusory and whether the attack succeeded."""
    path = results_path(bench_output)
    if not path.is_file():
        raise StealthNSError(
            f"{bench_output} holds no results.json: run `stealth-ns bench attack --output DIR` first"
        )
    runs = []
    for key, run in _read_results(path).items():
        config = Path(run.get("config", ""))
        if not config.is_file() or not checkpoint_steps(config.parent / "nerfstudio_models"):
            continue
        metrics = run.get("metrics") or {}
        runs.append({"key": key, "scene": run["scene"], "clean": bool(run.get("clean")), "config": config,
                     "label": run.get("label", key), "v_illusory": metrics.get("v_illusory_psnr"),
                     "success": metrics.get("attack_success")})  # fmt: skip
    return runs


#: The frames ``bench scan --as-ply`` writes its PLYs in (``--ply-frame``).
PlyFrame = Literal["dataset", "opensplat-center", "gsplat-normalized"]


def output_plan(as_ply: bool) -> tuple[list[str], list[str]]:
    """The files and the folders (owned whole) the bench scan writes into ``--output``."""
    return [RESULTS_FILE, TABLE_FILE, ROC_FILE], ([PLYS_DIR] if as_ply else [])


def inputs_of(bench_output: Path, runs: list[dict[str, Any]]) -> dict[str, Path]:
    """What the bench scan reads: the results file and every run's folder."""
    inputs = {"--runs": results_path(bench_output)}
    inputs.update({f"run {r['key']}": r["config"].parent for r in runs})
    return inputs


def check_arguments(
    bench_output: Path, output: Path, cfg: ScanConfig, only: tuple[str, ...] = (), as_ply: bool = False
) -> list[dict[str, Any]]:
    """The runs to scan (:func:`bench_runs`, those whose key contains one of ``only``), after one-line
    StealthNSErrors for bad options, a results file that is not one, no run to scan, or an output
    that is not writable, lies inside a run folder or would be written through a link, over an input
    or over files an earlier bench scan did not write."""
    try:
        cfg.validate()
    except ValueError as err:
        raise StealthNSError(str(err)) from None
    output, bench_output = Path(output), Path(bench_output)
    check_writable(output, "bench scan results")
    runs = [r for r in bench_runs(bench_output) if not only or any(o in r["key"] for o in only)]
    if not runs:
        raise StealthNSError(
            f"no finished run in {bench_output}" + (f" matches {', '.join(only)}" if only else "")
        )
    for run in runs:
        check_outside(output, run["config"].parent, f"the run folder of {run['key']}")
    files, folders = output_plan(as_ply)
    check_output_plan(output, RECORD, files, folders, inputs_of(bench_output, runs))
    return runs


def check_scenes(runs: list[dict[str, Any]], scenes: tuple[str, ...], option: str) -> None:
    """One-line StealthNSError for a scene of ``option`` that no run to scan belongs to."""
    known = list(dict.fromkeys(r["scene"] for r in runs))
    unknown = [s for s in scenes if s not in known]
    if unknown:
        raise StealthNSError(
            f"{option}: no run of scene {', '.join(unknown)} to scan; scenes: {', '.join(known)}"
        )
