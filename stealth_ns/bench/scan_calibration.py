"""The scan's verdict rule chosen on some scenes and judged on the others (held-out calibration).

Pure functions over ``bench scan`` rows. A row carries every rendered group of flagged Gaussians
(``groups``: the view's name and index, the share of that view its connected effect covers and,
from rows written since it was recorded, its number of Gaussians) and the views the run's poison was
meant for (``tampered``: training indices of the poisoned views and of their support views; empty
for a clean run). The rule has two numbers: a region threshold ``t`` and a group size ``m`` (the
scan's ``--min-group``). A group *counts* when it has at least ``m`` Gaussians (a group whose size was
not recorded always does), is detailed enough to hold a picture (the scan's fixed
``--max-pixels-per-gaussian``, recorded per group) and covers at least ``t`` of its view. The scan
calls a model suspicious when some group counts, and it is *right* on

* a clean model when no group counts;
* a poisoned model (attack succeeded) when some group in a tampered view counts and every group that
  counts is *on target* (:func:`on_target`): in a tampered view, or mostly poison by the run's tag (the
  attack's poison drawn into a view it was not aimed at: naming that view removes poison, not the
  scene). Rows without the groups' poison shares (written before they were recorded) fall back on
  the views alone.

Runs whose attack failed are neither fitted nor scored (there may be no illusion to find).

The scenes are split in two halves. The rule is chosen on one half and the confusion counted on the
other; then the halves swap. For each candidate group size (the scan's own minimum, and the
geometric middles between the sizes seen) the threshold is the one that gets the most rows right
(among equally good ones, the middle, on a log scale, of the widest gap between the shares around
it); the rule is the size whose threshold gets the most right, the smallest among equals (a larger
size is taken only where it gets more right). Margins say how far each model is from the threshold
of its fold, as a factor: above 1 on the right side, below 1 on the wrong one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from stealth_ns.scan.config import ScanConfig

Row = dict[str, Any]
#: The counts of a confusion table at one threshold; ``leaked`` counts the ``found`` models that also
#: name a view off the tampered ones for a group of their poison.
COUNTS: tuple[str, ...] = ("clean_clean", "clean_suspicious", "found", "leaked", "wrong_view", "missed")
#: A group at least this share of whose Gaussians carry the run's poison tag is poison, wherever it is.
POISON_MAJORITY = 0.5


def on_target(group: dict[str, Any], tampered: set[int]) -> bool:
    """Whether naming ``group``'s view is right on a poisoned run: the view is one of ``tampered`` (training
    indices of the poisoned and support views), or the group is poison (its recorded ``poison`` share
    reaches :data:`POISON_MAJORITY`)."""
    return group["index"] in tampered or (group.get("poison") or 0.0) >= POISON_MAJORITY


def scored(rows: Sequence[Row]) -> list[Row]:
    """The rows calibration uses: clean models and poisoned models whose attack succeeded."""
    return [r for r in rows if not r.get("attack_failed")]


def _groups(row: Row, size: float) -> list[dict[str, Any]]:
    """The groups of ``row`` with at least ``size`` Gaussians (those of unrecorded size too) that are
    detailed enough to hold a picture (the scan's ``--max-pixels-per-gaussian``, not fitted here)."""
    return [g for g in row["groups"] if g.get("gaussians", math.inf) >= size and g.get("detailed", True)]


def _shares(row: Row, size: float = 0) -> tuple[float, float, float]:
    """``(hit, leaked, wrong)``: the largest region share among the groups (of at least ``size``
    Gaussians) in tampered views, among the poison groups in other views and among the groups off
    target (:func:`on_target`; on a clean run every group is); 0 where there is none."""
    tampered = set(row.get("tampered") or [])
    groups = _groups(row, size)
    if not row["poisoned"]:
        return 0.0, 0.0, max((g["share"] for g in groups), default=0.0)
    hit = max((g["share"] for g in groups if g["index"] in tampered), default=0.0)
    leaked = max((g["share"] for g in groups if g["index"] not in tampered and on_target(g, tampered)),
                 default=0.0)  # fmt: skip
    wrong = max((g["share"] for g in groups if not on_target(g, tampered)), default=0.0)
    return hit, leaked, wrong


def right_at(row: Row, threshold: float, size: float = 0) -> bool:
    """Whether the scan at region threshold ``threshold`` and group size ``size`` is right on ``row``
    (module docstring)."""
    hit, _, wrong = _shares(row, size)
    if not row["poisoned"]:
        return wrong < threshold
    return hit >= threshold > wrong


def verdict_at(row: Row, threshold: float, size: float = 0) -> str:
    return "suspicious" if any(g["share"] >= threshold for g in _groups(row, size)) else "clean"


def margin(row: Row, threshold: float, size: float = 0) -> float:
    """How far ``row`` is from ``threshold``, as a factor (> 1: right with room, < 1: wrong).

    Clean: the threshold over its largest share. Poisoned: the smaller of its tampered share over
    the threshold and the threshold over its largest share off target (groups of at least ``size``)."""
    hit, _, wrong = _shares(row, size)
    below = threshold / wrong if wrong > 0 else math.inf
    if not row["poisoned"]:
        return below
    return min(hit / threshold, below)


def _best_threshold(rows: Sequence[Row], size: float) -> tuple[int, float, float]:
    """``(rows right, log width of its gap, threshold)`` of the best threshold at group size ``size``."""
    values = sorted({s for r in rows for s in _shares(r, size)[::2] if s > 0})
    if not values:  # no group anywhere: every threshold is as good as the scan's own
        t = ScanConfig.region_threshold
        return sum(right_at(r, t, size) for r in rows), math.inf, t
    # candidate intervals between consecutive shares, with open ends a decade beyond them
    bounds = [values[0] / 10, *values, min(1.0, values[-1] * 10)]
    best: tuple[int, float, float] | None = None
    for low, high in zip(bounds[:-1], bounds[1:], strict=True):
        if high <= low:
            continue
        t = math.sqrt(low * high)
        key = (sum(right_at(r, t, size) for r in rows), math.log(high / low), t)
        if best is None or key[:2] > best[:2]:
            best = key
    assert best is not None
    return best


def choose_threshold(rows: Sequence[Row], size: float = 0) -> float:
    """The region threshold that gets the most of ``rows`` right at group size ``size`` (ties: the
    log-middle of the widest gap between shares); ValueError for no rows."""
    if not rows:
        raise ValueError("no rows to choose a threshold on")
    return _best_threshold(rows, size)[2]


def size_candidates(rows: Sequence[Row]) -> list[float]:
    """The group sizes tried: the scan's minimum, and the geometric middles between the recorded sizes
    above it."""
    least = ScanConfig.min_group
    sizes = sorted({g["gaussians"] for r in rows for g in r["groups"] if g.get("gaussians", 0) > least})
    floor = [least, *sizes]
    return [float(least)] + [math.sqrt(a * b) for a, b in zip(floor[:-1], floor[1:], strict=True) if b > a]


def choose_rule(rows: Sequence[Row]) -> tuple[float, float]:
    """``(threshold, group size)`` that gets the most of ``rows`` right (ties: the smallest size, which
    drops the fewest groups); ValueError for no rows."""
    if not rows:
        raise ValueError("no rows to choose a rule on")
    best: tuple[tuple[int, float], float, float] | None = None
    for size in size_candidates(rows):
        right, _, t = _best_threshold(rows, size)
        key = (right, -size)
        if best is None or key > best[0]:
            best = (key, t, size)
    assert best is not None
    return best[1], best[2]


def split_scenes(scenes: Sequence[str], first: Sequence[str] = ()) -> tuple[list[str], list[str]]:
    """The two halves: ``first`` (default: every other scene, from the first) and the rest."""
    half = [s for s in scenes if s in set(first)] if first else list(scenes[::2])
    return half, [s for s in scenes if s not in half]


def confusion_at(rows: Sequence[Row], threshold: float, size: float = 0) -> dict[str, int]:
    """Counts at ``threshold`` and group size ``size``: clean models called clean / suspicious;
    poisoned models found with the right views (and of them, those also naming a view their poison
    leaked into) / suspicious but naming a wrong view / called clean."""
    out = dict.fromkeys(COUNTS, 0)
    for r in rows:
        suspicious = verdict_at(r, threshold, size) == "suspicious"
        if not r["poisoned"]:
            out["clean_suspicious" if suspicious else "clean_clean"] += 1
        elif right_at(r, threshold, size):
            out["found"] += 1
            out["leaked"] += _shares(r, size)[1] >= threshold
        else:
            out["wrong_view" if suspicious else "missed"] += 1
    return out


def held_out(rows: Sequence[Row], first: Sequence[str] = ()) -> dict[str, Any]:
    """Two folds: the rule chosen on each half of the scenes, judged on the other half.

    Returns ``{"folds": [{fit, held_out, threshold, min_group, confusion}], "confusion": both held-out
    halves summed, "margins": [{run, scene, poisoned, threshold, min_group, margin, right}]}``."""
    kept = scored(rows)
    scenes = list(dict.fromkeys(r["scene"] for r in kept))
    a, b = split_scenes(scenes, first)
    folds, margins = [], []
    total = dict.fromkeys(COUNTS, 0)
    for fit, test in ((a, b), (b, a)):
        fit_rows = [r for r in kept if r["scene"] in fit]
        test_rows = [r for r in kept if r["scene"] in test]
        if not fit_rows or not test_rows:
            continue
        t, m = choose_rule(fit_rows)
        counts = confusion_at(test_rows, t, m)
        total = {k: total[k] + counts[k] for k in total}
        folds.append({"fit": fit, "held_out": test, "threshold": t, "min_group": m, "confusion": counts})
        margins += [
            {"run": r["run"], "scene": r["scene"], "poisoned": r["poisoned"], "threshold": t, "min_group": m,
             "margin": margin(r, t, m), "right": right_at(r, t, m)}
            for r in test_rows
        ]  # fmt: skip
    return {"folds": folds, "confusion": total, "margins": margins}


def calibration_lines(result: dict[str, Any]) -> list[str]:
    """scan.md's section: each fold's threshold and held-out confusion, then every model's margin."""
    if not result["folds"]:
        return ["## Held-out calibration", "", "Needs runs of at least two scenes.", ""]
    lines = [
        "## Held-out calibration of the verdict's rule",
        "",
        "The region threshold and the group size (--min-group) are chosen on one half of the scenes and "
        "judged on the other, then the halves swap (failed attacks left out; docs/design/scan.md).",
        "",
        "| fitted on | threshold | min group | judged on | clean → clean | clean → suspicious | "
        "found (right views) | of them, also naming a view their poison leaked into | wrong view | missed |",
        "|---|--:|--:|---|--:|--:|--:|--:|--:|--:|",
    ]
    for f in [*result["folds"], None]:
        c = result["confusion"] if f is None else f["confusion"]
        head = (
            ["both folds", "–", "–", "every scene"]
            if f is None
            else [
                ", ".join(f["fit"]),
                f"{100 * f['threshold']:.2f}%",
                f"{f.get('min_group', ScanConfig.min_group):.0f}",
                ", ".join(f["held_out"]),
            ]
        )
        cells = [c[k] for k in COUNTS]
        lines.append("| " + " | ".join([*head, *map(str, cells)]) + " |")
    lines += ["", "| run | truth | threshold | margin | right |", "|---|---|--:|--:|:-:|"]
    for m in result["margins"]:
        factor = "∞" if math.isinf(m["margin"]) else f"{m['margin']:.2f}x"
        truth = "poisoned" if m["poisoned"] else "clean"
        row = [m["run"], truth, f"{100 * m['threshold']:.2f}%", factor, "yes" if m["right"] else "no"]
        lines.append("| " + " | ".join(row) + " |")
    return [*lines, ""]
