"""``stealth-ns bench scan``: the scan's verdict on every run a ``bench attack`` folder holds, against
what each run is (clean, or attacked with its poisoned views): a confusion table, the ROC of the
largest group region as a score, and each run's row (docs/design/scan.md).

A run is *poisoned* when it was trained with the attack or on a poisoned copy (data-only, IPA-Splat);
the scan is *right* on a poisoned run when it names one of the run's poisoned views, or of their
support views (docs/design/stealth.md: their training images show the poison too), and every group it names
is in such a view or is poison by the run's tag (:func:`~stealth_ns.bench.scan_calibration.on_target`).
The poisoned runs whose attack failed (the paper's rule, from the bench's results when measured) are
kept apart: there may be no illusion to find in them.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.attack.record import AttackRecord
from stealth_ns.bench.scan_calibration import calibration_lines, held_out, on_target
from stealth_ns.bench.scan_runs import (
    PLYS_DIR,
    RECORD,
    RESULTS_FILE,
    ROC_FILE,
    TABLE_FILE,
    WRITTEN_BY,
    PlyFrame,
    check_arguments,
    inputs_of,
    output_plan,
)
from stealth_ns.datasets.frames import frame_transforms
from stealth_ns.datasets.source import inspect_folder
from stealth_ns.defence_eval.evaluate import Evaluator, defeat_metrics, target_of
from stealth_ns.defences.detection import detection_metrics
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import json_safe, write_json_atomic, write_text_atomic
from stealth_ns.foundation.output_folder import claim_output, record_output
from stealth_ns.gaussians.ply import write_gaussian_ply
from stealth_ns.gaussians.transform import transform_cloud
from stealth_ns.runs.imported import ImportedModel, load_model
from stealth_ns.runs.loaded import attack_record
from stealth_ns.scan.config import ScanConfig
from stealth_ns.scan.outputs import ground_truth
from stealth_ns.scan.scanner import Group, scan_model
from stealth_ns.scan.verdict import is_detailed


def as_foreign_ply(imported: ImportedModel, path: Path, frame: PlyFrame = "dataset") -> Path:
    """Write a loaded run's Gaussians to ``path`` as another trainer would: a 3DGS PLY without the poison
    tag, in ``frame`` -- the dataset's own, OpenSplat's ``--center`` or gsplat's default normalised one
    (:mod:`stealth_ns.datasets.frames`). Returns ``path``; a one-line StealthNSError when the dataset
    does not define ``frame``."""
    run = imported.run
    scene = inspect_folder("--data", str(run.data))
    transforms = frame_transforms(run.pipeline.datamanager.train_dataparser_outputs, scene)
    if frame not in transforms:
        raise StealthNSError(
            f"--ply-frame {frame}: the dataset {run.data} does not define it (gsplat's needs seed points, "
            "neither reads a Blender dataset); leave its runs out with --only"
        )
    cloud = transform_cloud(imported.cloud, np.linalg.inv(transforms[frame]))
    cloud.extra = {}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_gaussian_ply(path, cloud, comment="stealth-ns bench scan --as-ply")
    return path


def scan_run(
    run: dict[str, Any], cfg: ScanConfig, ply: Path | None = None, frame: PlyFrame = "dataset"
) -> dict[str, Any]:
    """One row: the scan's verdict on ``run`` and whether it is right; with ``ply``, the run is first
    written there in ``frame`` by :func:`as_foreign_ply` and that PLY is scanned on the run's dataset."""
    t0 = time.perf_counter()
    imported = load_model(run["config"])
    record = None if run["clean"] else attack_record(imported.run, run["config"])
    poison = imported.cloud.poison_mask()  # the foreign PLY keeps the rows' order, not the tag
    if ply is not None:
        imported = load_model(as_foreign_ply(imported, ply, frame), imported.run.data)
    truth, support, poisoned, tampered = [], [], set(), set()
    if record is not None:
        truth = [v.name for v in record.views]
        if record.injection is not None:  # support views' training images show the poison too
            support = sorted({s for names in record.injection.support_views.values() for s in names})
        # by training index: a poisoned copy may name a view's file otherwise (external/images/...)
        poisoned = {v.index for v in record.views}
        tampered = poisoned | set(record.support_targets)
    result = scan_model(imported, cfg)
    groups = [_group_row(g, cfg, poison) for g in result.groups]
    named = [g.name for g in result.targeted]
    named_views = {g.view for g in result.targeted}
    failed = not run["clean"] and run["success"] is False
    on = [on_target(row, tampered) for g, row in zip(result.groups, groups, strict=True) if g.targeted]
    right = (not named) if run["clean"] else bool(named_views & tampered) and all(on)
    return {
        "run": run["key"],
        "scene": run["scene"],
        "label": run["label"],
        "poisoned": not run["clean"],
        "attack_failed": failed,
        "v_illusory": run["v_illusory"],
        "poisoned_views": truth,
        "support_views": support,
        "verdict": result.verdict,
        "named_views": named,
        "named_regions": {g.name: round(g.region.share, 5) for g in result.targeted},
        "right": right,
        "views_found": len(named_views & poisoned),
        "largest_region": result.groups[0].region.share if result.groups else 0.0,
        "near_depth_share": round(result.near_share, 4),
        "groups": groups,
        "tampered": sorted(tampered),
        "gaussians": int(result.flagged.shape[0]),
        "ground_truth": ground_truth(result),
        "frame": imported.frame,
        "cleaned": None if record is None else cleaning_effect(imported, record, result.removed),
        "seconds": round(time.perf_counter() - t0, 1),
    }


def _group_row(group: Group, cfg: ScanConfig, poison: np.ndarray | None) -> dict[str, Any]:
    """A group as a row records it: its view, region, size, whether it is detailed enough to hold a
    picture and (``poison``: the run's ``[N]`` bool tag, or None) the share of its Gaussians that are
    poison."""
    n = int(group.members.sum())
    return {
        "view": group.name,
        "index": group.view,
        "share": round(group.region.share, 6),
        "gaussians": n,
        "pixels": group.region.pixels,
        "detailed": is_detailed(group.region.pixels, n, cfg.max_pixels_per_gaussian),
        "poison": None if poison is None or n == 0 else round(float(poison[group.members].mean()), 4),
    }


def cleaning_effect(imported: ImportedModel, record: AttackRecord, removed: np.ndarray) -> dict[str, Any]:
    """What the scan's cleaned model does to the attack, as defend measures a cut: V-illusory (dB)
    before and after removing ``removed``, the held-out PSNR it costs, whether that defeats the attack."""
    evaluate = Evaluator(target_of(imported.run, record))
    before = evaluate(None)
    after = defeat_metrics(evaluate, before, removed)
    return {
        "v_illusory_before": before["v_illusory_psnr"],
        "v_illusory_after": after["v_illusory_psnr"],
        "v_test_cost": after["v_test_cost"],
        "defeats_attack": after["defeats_attack"],
    }


def confusion(rows: list[dict[str, Any]]) -> dict[str, int]:
    """Counts over rows: clean runs called clean / suspicious; poisoned (successful) runs found with the
    right views / found with a wrong view / missed; failed attacks called suspicious / clean."""
    out = dict.fromkeys(("clean_clean", "clean_suspicious", "found", "wrong_view", "missed", "failed_found",
                         "failed_clean"), 0)  # fmt: skip
    for r in rows:
        if not r["poisoned"]:
            out["clean_clean" if r["verdict"] == "clean" else "clean_suspicious"] += 1
        elif r["attack_failed"]:
            out["failed_found" if r["verdict"] == "suspicious" else "failed_clean"] += 1
        else:
            out["found" if r["right"] else ("wrong_view" if r["verdict"] == "suspicious" else "missed")] += 1
    return out


def _cleaned(row: dict[str, Any]) -> str:
    c = row.get("cleaned")
    if not c or c["v_illusory_after"] is None:
        return "– | –"
    return f"{c['v_illusory_after']:.2f} | {c['v_test_cost']:.2f}"


def _support(row: dict[str, Any]) -> str:
    support = row.get("support_views") or []
    return f" (support: {', '.join(support)})" if support else ""


def table_lines(
    rows: list[dict[str, Any]], cfg: ScanConfig, calibration: dict[str, Any] | None = None
) -> list[str]:
    """scan.md: the rule, the confusion table, the ROC's AUROC, every run's row and (given) the
    held-out calibration (:mod:`stealth_ns.bench.scan_calibration`)."""
    c = confusion(rows)
    scores = np.array([r["largest_region"] for r in rows if not r["attack_failed"]])
    labels = np.array([r["poisoned"] for r in rows if not r["attack_failed"]])
    auroc = detection_metrics(scores, labels)["auroc"]
    lines = [
        f"signals: {', '.join(cfg.signals)}; region threshold {cfg.region_threshold:.1%}",
        "",
        "| models | called clean | called suspicious |",
        "|---|--:|--:|",
        f"| clean | {c['clean_clean']} | {c['clean_suspicious']} |",
        f"| poisoned, attack succeeded | {c['missed']} | {c['found']} right views, {c['wrong_view']} wrong |",
        f"| poisoned, attack failed | {c['failed_clean']} | {c['failed_found']} |",
        "",
        "AUROC of the largest region as a model-level score (failed attacks left out): "
        + ("n/a" if auroc is None else f"{auroc:.3f}"),
        "",
        "| run | poisoned views | V-illusory | verdict | views named | found | largest region | right | "
        "V-illusory after cleaning | V-test cost | s |",
        "|---|---|--:|---|---|--:|--:|:-:|--:|--:|--:|",
    ]
    for r in rows:
        v = "–" if r["v_illusory"] is None else f"{r['v_illusory']:.2f}"
        lines.append(
            f"| {r['run']} | {', '.join(r['poisoned_views']) or 'clean'}{_support(r)} | {v} | "
            f"{r['verdict']} | "
            f"{', '.join(r['named_views']) or '–'} | {r.get('views_found', 0)}/{len(r['poisoned_views'])} | "
            f"{100 * r['largest_region']:.2f}% | {'yes' if r['right'] else 'no'} | {_cleaned(r)} | "
            f"{r['seconds']:.0f} |"
        )
    if calibration is not None:
        lines += ["", *calibration_lines(calibration)]
    return lines


def plot_roc(path: Path, rows: list[dict[str, Any]]) -> None:
    """The model-level ROC: the largest group region as a score of poisoned (attack succeeded) against
    clean models; the default threshold marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch
    from torchmetrics.functional.classification import binary_roc

    from stealth_ns.defences.detection import rank_scores
    from stealth_ns.foundation.figures import save_plot

    kept = [r for r in rows if not r["attack_failed"]]
    scores = np.array([r["largest_region"] for r in kept])
    labels = torch.tensor([int(r["poisoned"]) for r in kept])
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    if 0 < int(labels.sum()) < len(kept):
        fpr, tpr, _ = binary_roc(torch.from_numpy(rank_scores(scores)), labels, thresholds=None)
        ax.plot(fpr.numpy(), tpr.numpy(), lw=1.5, marker="o", ms=3, label=f"{len(kept)} models")
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, ls="--")
    save_plot(fig, ax, path, "clean models called suspicious", "poisoned models found", "stealth-ns scan")


def run_bench_scan(
    bench_output: Path,
    output: Path,
    cfg: ScanConfig,
    only: tuple[str, ...] = (),
    as_ply: bool = False,
    first_half: tuple[str, ...] = (),
    ply_frame: PlyFrame = "dataset",
) -> list[dict]:
    """Scan every finished run of ``bench_output`` (or those whose key contains one of ``only``); write
    OUTPUT/scan-results.json, OUTPUT/scan.md and OUTPUT/roc.png (and the record of them,
    :data:`~stealth_ns.bench.scan_runs.RECORD`); returns the rows. ``as_ply``: scan each run as a
    foreign PLY in ``ply_frame`` (:func:`as_foreign_ply`, written to OUTPUT/plys/) instead.
    ``first_half``: the scenes the held-out calibration fits on first (default: every other scene)."""
    runs = check_arguments(bench_output, output, cfg, only, as_ply)  # before anything slow or written
    files, folders = output_plan(as_ply)
    claim_output(output, RECORD, WRITTEN_BY, files, folders, inputs_of(bench_output, runs))
    rows = []
    for i, run in enumerate(runs, 1):
        print(f"[{i}/{len(runs)}] scanning {run['key']}", flush=True)
        ply = output / PLYS_DIR / (run["key"].replace("/", "_") + ".ply") if as_ply else None
        rows.append(scan_run(run, cfg, ply, ply_frame))
        print(f"  {rows[-1]['verdict']} {rows[-1]['named_views']} (right: {rows[-1]['right']})", flush=True)
        write_json_atomic(output / RESULTS_FILE, json_safe({"config": vars(cfg), "rows": rows}))
    calibration = held_out(rows, first_half)
    doc = {"config": vars(cfg), "rows": rows, "calibration": calibration}
    write_json_atomic(output / RESULTS_FILE, json_safe(doc))
    write_text_atomic(output / TABLE_FILE, "\n".join(table_lines(rows, cfg, calibration)) + "\n")
    plot_roc(output / ROC_FILE, rows)
    record_output(output, RECORD, WRITTEN_BY, files, folders)
    return rows
