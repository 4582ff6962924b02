"""The files of ``stealth-ns defend`` besides defend.json: the table and the figures."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from stealth_ns.defence_eval.rule import DEFEAT_V_TEST_COST, lowest_within_cost
from stealth_ns.foundation.figures import figure_grid, save_plot
from stealth_ns.foundation.json_io import write_text_atomic
from stealth_ns.runs.loaded import render

if TYPE_CHECKING:
    from stealth_ns.defence_eval.evaluate import Target
    from stealth_ns.defences.posthoc import Scored

FIGURES = {"roc": "roc.png", "curves": "curves.png", "poisoned_view": "poisoned_view.png"}
TABLE_FILE = "defend.md"
COLUMNS = (
    "defence",
    "rule",
    "AUROC",
    "AP",
    "poison removed",
    "clean removed",
    "V-illusory after (dB)",
    "V-test cost (dB)",
    "defeats",
)


def fmt(value: Any, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def pct(value: Any) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}%"


def table_rows(result: dict[str, Any]) -> list[list[str]]:
    """One row per defence (strings, in :data:`COLUMNS` order), the undefended model first."""
    base = result["undefended"]
    rows = [["none (undefended)", "", "", "", "", "", fmt(base["v_illusory_psnr"]), "0.00", ""]]
    for name, e in result["defences"].items():
        op = e["operating_point"]
        rows.append(
            [
                name,
                e["rule"],
                fmt(e.get("auroc"), 3),
                fmt(e.get("average_precision"), 3),
                pct(op.get("poison_removed")),
                pct(op.get("clean_removed")),
                fmt(op.get("v_illusory_psnr")),
                fmt(op.get("v_test_cost")),
                "yes" if op.get("defeats_attack") else "no",
            ]
        )
    return rows


def render_table(result: dict[str, Any]) -> str:
    """defend.md: the table of every defence, with the defeat rule and the best sweep point."""
    lines = [f"# Stealth under defences: {result['run']}", ""]
    lines.append(
        f"{result['n_gaussians']} Gaussians, {result['n_poison']} poison; poisoned views: "
        f"{', '.join(result['poisoned_views'])}. A defence defeats the attack when {result['defeat_rule']}."
    )
    lines += ["", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(row) + " |" for row in table_rows(result)]
    best = best_cuts(result)
    if best:
        lines += ["", "Best cut of each sweep (lowest V-illusory with V-test cost <= 0.5 dB):", ""]
        lines += [f"- {name}: {text}" for name, text in best.items()]
    return "\n".join(lines) + "\n"


def best_cuts(result: dict[str, Any], max_cost: float = DEFEAT_V_TEST_COST) -> dict[str, str]:
    """Per post-hoc defence, the sweep point with the lowest V-illusory at a V-test cost <= ``max_cost``."""
    out = {}
    for name, e in result["defences"].items():
        p = lowest_within_cost(e.get("curve", []), max_cost)
        if p is not None:
            out[name] = (
                f"prune {100 * p['fraction']:.1f}%: V-illusory {fmt(p['v_illusory_psnr'])} dB, "
                f"V-test cost {fmt(p['v_test_cost'])} dB, poison removed {pct(p['poison_removed'])}"
            )
    return out


def _plot_roc(path: Path, scored: dict[str, Scored], is_poison: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from torchmetrics.functional.classification import binary_roc

    from stealth_ns.defences.detection import rank_scores

    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    target = torch.from_numpy(is_poison.astype(np.int64))
    for name, s in scored.items():
        fpr, tpr, _ = binary_roc(torch.from_numpy(rank_scores(s.scores)), target, thresholds=None)
        ax.plot(fpr.numpy(), tpr.numpy(), lw=1.5, label=name)
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, ls="--")
    save_plot(
        fig,
        ax,
        path,
        "clean Gaussians flagged (FPR)",
        "poison Gaussians flagged (TPR)",
        "Detecting the poison Gaussians",
    )


def _plot_curves(path: Path, result: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.2, 4.2))
    for i, (name, e) in enumerate(result["defences"].items()):
        pts = [
            p for p in e.get("curve", []) if p["v_test_cost"] is not None and p["v_illusory_psnr"] is not None
        ]
        if pts:
            ax.plot(
                [p["v_test_cost"] for p in pts],
                [p["v_illusory_psnr"] for p in pts],
                "o-",
                ms=3,
                lw=1,
                color=f"C{i}",
                label=name,
            )
        op = e["operating_point"]
        if op.get("v_test_cost") is not None and op.get("v_illusory_psnr") is not None:
            ax.plot(
                op["v_test_cost"],
                op["v_illusory_psnr"],
                "*",
                ms=12,
                color=f"C{i}",
                label=None if pts else name,
                markeredgecolor="k",
            )
    ax.axhline(15.0, color="0.5", ls="--", lw=0.8)
    ax.axvline(0.5, color="0.5", ls="--", lw=0.8)
    ax.set_xscale("symlog", linthresh=0.1)
    save_plot(
        fig,
        ax,
        path,
        "V-test cost (dB of held-out PSNR lost)",
        "V-illusory after the defence (dB)",
        "Pruning sweep (stars: each defence's own rule)",
    )


def _poisoned_view_grid(
    path: Path, result: dict[str, Any], target: Target, scored: dict[str, Scored]
) -> None:
    cameras = target.run.pipeline.datamanager.train_dataset.cameras
    rows = []
    for v in target.record.views[:3]:
        row = [
            (f"{v.name}: target", v.target.numpy()),
            (
                f"undefended ({fmt(result['undefended']['v_illusory_psnr'])} dB)",
                render(target.run, cameras, v.index),
            ),
        ]
        for name, s in scored.items():
            with target.model.kept(torch.from_numpy(~s.pruned)):
                image = render(target.run, cameras, v.index)
            ill = result["defences"][name]["operating_point"]["v_illusory_psnr"]
            row.append((f"{name} ({fmt(ill)} dB)", image))
        rows.append(row)
    figure_grid(path, rows)


def write_outputs(output: Path, result: dict[str, Any], target: Target, scored: dict[str, Scored]) -> None:
    """defend.md and the figures into ``output``, each written whole or not at all (a one-line
    StealthNSError naming the file when that fails); their names go into ``result["figures"]``."""
    from stealth_ns.defences.signals import poison_tags

    output.mkdir(parents=True, exist_ok=True)
    figures = {}
    is_poison = poison_tags(target.model)
    if scored and 0 < int(is_poison.sum()) < is_poison.shape[0]:
        _plot_roc(output / FIGURES["roc"], scored, is_poison)
        figures["roc"] = FIGURES["roc"]
    _plot_curves(output / FIGURES["curves"], result)
    figures["curves"] = FIGURES["curves"]
    _poisoned_view_grid(output / FIGURES["poisoned_view"], result, target, scored)
    figures["poisoned_view"] = FIGURES["poisoned_view"]
    result["figures"] = figures
    write_text_atomic(output / TABLE_FILE, render_table(result))
