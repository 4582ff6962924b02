"""``stealth.png`` of a benchmark: every attacked run's effectiveness against how well the
concentration detectors find it (the frontier of docs/stealth.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stealth_ns.defence_eval.stealth import KEY_DETECTORS
from stealth_ns.foundation.figures import save_plot

STEALTH_PLOT = "stealth.png"


def stealth_points(runs: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Per attacked run with a measured stealth: ``key``, ``scene``, ``auroc`` (the highest AUROC of
    :data:`KEY_DETECTORS`, None when the run has no poison tag), ``v_illusory`` (dB), ``stealthy``
    (stealthy success)."""
    points = []
    for key, entry in runs.items():
        metrics = entry.get("metrics")
        stealth = metrics.get("stealth") if isinstance(metrics, dict) else None
        if entry.get("clean") or not isinstance(stealth, dict) or stealth.get("unavailable"):
            continue
        aurocs = [a for name in KEY_DETECTORS if isinstance(a := stealth["auroc"].get(name), (int, float))]
        points.append(
            {
                "key": key,
                "scene": entry.get("scene", key.split("/")[0]),
                "auroc": max(aurocs) if aurocs else None,
                "v_illusory": metrics.get("v_illusory_psnr"),
                "stealthy": bool(metrics.get("stealthy_success")),
            }
        )
    return points


def plot_stealth(runs: dict[str, dict[str, Any]], path: Path) -> Path | None:
    """Write ``path``: V-illusory against the best concentration detector's AUROC, one colour per
    scene, filled markers for stealthy successes; None (nothing written) without such runs."""
    points = [p for p in stealth_points(runs) if p["auroc"] is not None and p["v_illusory"] is not None]
    if not points:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    scenes = list(dict.fromkeys(p["scene"] for p in points))
    colours = plt.get_cmap("tab10")
    for i, scene in enumerate(scenes):
        mine = [p for p in points if p["scene"] == scene]
        for stealthy in (False, True):
            chosen = [p for p in mine if p["stealthy"] == stealthy]
            if chosen:
                ax.scatter(
                    [p["auroc"] for p in chosen],
                    [p["v_illusory"] for p in chosen],
                    color=colours(i % 10),
                    facecolors=colours(i % 10) if stealthy else "none",
                    label=f"{scene}" + (" (stealthy success)" if stealthy else ""),
                )
        for p in mine:
            ax.annotate(p["key"].split("/", 1)[1], (p["auroc"], p["v_illusory"]), fontsize=6, alpha=0.7)
    ax.axhline(25.0, color="grey", linestyle="--", linewidth=0.8)
    ax.axvline(0.5, color="grey", linestyle=":", linewidth=0.8)
    save_plot(
        fig,
        ax,
        path,
        "AUROC of the better concentration detector (" + ", ".join(KEY_DETECTORS) + ")",
        "V-illusory PSNR (dB)",
        "Effectiveness against detectability (dashed: the paper's 25 dB success bar)",
    )
    return path
