"""The stealth figures of a benchmark: ``stealth.png``, every attacked run's effectiveness against how
well the concentration detectors find it; ``frontier.png``, the adaptive attacks of Table 9 against
what the strongest post-hoc defence leaves of them (docs/design/stealth.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stealth_ns.defence_eval.rule import DEFEAT_V_ILLUSORY, DEFEAT_V_TEST_COST
from stealth_ns.defence_eval.stealth import KEY_DETECTORS
from stealth_ns.foundation.figures import save_plot

STEALTH_PLOT = "stealth.png"
FRONTIER_PLOT = "frontier.png"
#: The bench table whose runs ``frontier.png`` shows (the adaptive attacks and the default row).
FRONTIER_TABLE = "9"
SUCCESS_V_ILLUSORY = 25.0


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
    ax.axhline(SUCCESS_V_ILLUSORY, color="grey", linestyle="--", linewidth=0.8)
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


def _variant(name: str, label: str | None) -> str:
    """The legend's name of a Table 9 run: its label for an adaptive run (``ad-*``), else the default
    attack (Table 9's first row, whose run is another table's: ``full``, ``median``)."""
    return (label or name) if name.startswith("ad-") else "default attack"


def frontier_points(runs: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Per attacked run of Table 9 whose stealth was measured: ``key``, ``scene``, ``variant`` (the
    legend's name, :func:`_variant`), ``v_illusory`` and ``after`` (V-illusory left by the strongest
    post-hoc defence at <= 0.5 dB of V-test, dB; None when no cut qualifies), ``stealthy``."""
    points = []
    for key, entry in runs.items():
        metrics = entry.get("metrics")
        stealth = metrics.get("stealth") if isinstance(metrics, dict) else None
        if entry.get("clean") or FRONTIER_TABLE not in [str(t) for t in entry.get("tables", [])]:
            continue
        if (
            not isinstance(stealth, dict)
            or stealth.get("unavailable")
            or metrics.get("v_illusory_psnr") is None
        ):
            continue
        points.append(
            {
                "key": key,
                "scene": entry.get("scene", key.split("/")[0]),
                "variant": _variant(key.split("/", 1)[1], entry.get("label")),
                "v_illusory": metrics["v_illusory_psnr"],
                "after": stealth.get("v_illusory_after_strongest"),
                "stealthy": bool(metrics.get("stealthy_success")),
            }
        )
    return points


def plot_frontier(runs: dict[str, dict[str, Any]], path: Path) -> Path | None:
    """Write ``path``: each Table 9 run's V-illusory against what the strongest post-hoc defence leaves
    of it (a run no cut of <= 0.5 dB reaches is drawn at its own V-illusory), one colour per scene,
    one marker per variant. The upper right quadrant (a success no defence defeats) is the stealthy
    success; None (nothing written) without such runs."""
    points = frontier_points(runs)
    if not points:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    colours = plt.get_cmap("tab10")
    scenes = list(dict.fromkeys(p["scene"] for p in points))
    variants = list(dict.fromkeys(p["variant"] for p in points))
    markers = "o^sDvP*Xh<>"
    for p in points:
        after = p["after"] if p["after"] is not None else p["v_illusory"]
        colour = colours(scenes.index(p["scene"]) % 10)
        ax.scatter(
            after,
            p["v_illusory"],
            color=colour,
            facecolors=colour if p["stealthy"] else "none",
            marker=markers[variants.index(p["variant"]) % len(markers)],
        )
    for i, scene in enumerate(scenes):
        ax.scatter([], [], color=colours(i % 10), marker="o", label=scene)
    for i, variant in enumerate(variants):
        ax.scatter([], [], color="black", facecolors="none", marker=markers[i % len(markers)], label=variant)
    ax.axhline(SUCCESS_V_ILLUSORY, color="grey", linestyle="--", linewidth=0.8)
    ax.axvline(DEFEAT_V_ILLUSORY, color="grey", linestyle=":", linewidth=0.8)
    right = max(DEFEAT_V_ILLUSORY + 5, ax.get_xlim()[1])
    top = max(max(p["v_illusory"] for p in points) + 2, SUCCESS_V_ILLUSORY + 5)
    ax.fill_between([DEFEAT_V_ILLUSORY, right], SUCCESS_V_ILLUSORY, top, color="green", alpha=0.06)
    ax.set_xlim(right=right)
    ax.set_ylim(top=top)
    ax.text(DEFEAT_V_ILLUSORY + 0.3, SUCCESS_V_ILLUSORY + 0.5, "stealthy success", fontsize=8, color="green")
    save_plot(
        fig,
        ax,
        path,
        f"V-illusory after the strongest post-hoc defence at <= {DEFEAT_V_TEST_COST:g} dB of V-test (dB)",
        "V-illusory PSNR (dB)",
        f"Adaptive attacks: upper right = stealthy success (> {SUCCESS_V_ILLUSORY:g} dB, not cut below "
        f"{DEFEAT_V_ILLUSORY:g} dB)",
    )
    return path
