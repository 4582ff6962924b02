"""Stealth as a measured property of an attack: what the post-hoc defences find, and what they leave.

An attacked run is *stealthy* when no post-hoc defence of :mod:`stealth_ns.defences.posthoc` defeats
it (:data:`~stealth_ns.defence_eval.evaluate.DEFEAT_RULE`: V-illusory below 15 dB for a V-test cost of at
most 0.5 dB) at any cut it offers a defender: its own rule, or pruning a fixed share of the most
suspicious Gaussians (the fractions of :func:`stealth_ns.defences.detection.sweep_fractions`, the same
for every scene, so choosing one needs no ground truth). A *stealthy success* is the paper's success
(V-illusory > 25 dB, drop <= 3 dB) that is also stealthy.

The numbers come from ``stealth-ns defend``'s own scoring
(:func:`stealth_ns.defence_eval.command.score_posthoc`), nothing is written; the summary itself
(:func:`stealth_summary`) is a pure function of defend.json's ``defences`` entries, so a ``defend.json``
gives the same summary.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from stealth_ns.defence_eval.rule import (
    DEFEAT_RULE,
    DEFEAT_V_ILLUSORY,
    DEFEAT_V_TEST_COST,
    lowest_within_cost,
)
from stealth_ns.defences.config import POSTHOC, DefendConfig

if TYPE_CHECKING:
    from stealth_ns.attack.record import AttackRecord
    from stealth_ns.runs.loaded import LoadedRun

#: The detectors whose AUROC the report and the bench show first (the concentration scores: the ones
#: that found the default attack at AUROC near 1).
KEY_DETECTORS: tuple[str, ...] = ("view-support", "grad-concentration")


def cuts(entry: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """Every cut a defence offers, as ``(label, numbers)``: its rule's operating point, then each
    sweep fraction above 0 (``"prune 1.0%"``). ``numbers`` as in defend.json (``v_illusory_psnr``,
    ``v_test_cost``, ``poison_removed``, ...)."""
    out = []
    if entry.get("operating_point"):
        out.append((f"rule ({entry.get('rule', '')})", entry["operating_point"]))
    for point in entry.get("curve") or []:
        if point.get("fraction"):
            out.append((f"prune {100 * point['fraction']:.1f}%", point))
    return out


def strongest_cut(entry: dict[str, Any], max_cost: float = DEFEAT_V_TEST_COST) -> dict[str, Any] | None:
    """The cut of one defence with the lowest V-illusory among those costing at most ``max_cost`` dB of
    V-test: ``{"cut", "v_illusory_psnr", "v_test_cost", "poison_removed"}``; None when no cut qualifies
    (or none was measured)."""
    p = lowest_within_cost(({**point, "cut": label} for label, point in cuts(entry)), max_cost)
    if p is None:
        return None
    return {
        "cut": p["cut"],
        "v_illusory_psnr": p["v_illusory_psnr"],
        "v_test_cost": p["v_test_cost"],
        "poison_removed": p.get("poison_removed"),
    }


def stealth_summary(defences: dict[str, dict[str, Any]], attack_success: bool) -> dict[str, Any]:
    """The stealth of an attacked run from its post-hoc defences' entries (defend.json's ``defences``;
    training-time defences, which have no cuts, are left out).

    Returns ``auroc`` (per defence; None without poison tags, e.g. a victim of a poisoned dataset),
    ``strongest_cut`` (per defence, :func:`strongest_cut`), ``strongest_defence`` and
    ``v_illusory_after_strongest`` (the lowest V-illusory any defence leaves at <= 0.5 dB of V-test;
    None when no cut qualifies), ``defeated_by`` (the defences with a cut that meets the defeat rule),
    ``stealthy`` (no defence defeats it) and ``stealthy_success`` (``attack_success`` and ``stealthy``).
    """
    posthoc = {name: e for name, e in defences.items() if e.get("kind", "post-hoc") == "post-hoc"}
    best = {name: strongest_cut(e) for name, e in posthoc.items()}
    measured = {name: b for name, b in best.items() if b is not None}
    strongest = min(measured, key=lambda n: measured[n]["v_illusory_psnr"]) if measured else None
    defeated = [n for n, b in measured.items() if b["v_illusory_psnr"] < DEFEAT_V_ILLUSORY]
    return {
        "defeat_rule": DEFEAT_RULE,
        "auroc": {name: e.get("auroc") for name, e in posthoc.items()},
        "strongest_cut": best,
        "strongest_defence": strongest,
        "v_illusory_after_strongest": measured[strongest]["v_illusory_psnr"] if strongest else None,
        "defeated_by": defeated,
        "stealthy": not defeated,
        "stealthy_success": bool(attack_success) and not defeated,
    }


def stealth_line(stealth: dict[str, Any]) -> str:
    """One line for the terminal: the key detectors' AUROC, the strongest defence, the verdict."""
    if stealth.get("unavailable"):
        return f"stealth: not measured ({stealth['unavailable']})"
    auroc = stealth["auroc"]
    shown = [f"{n} {auroc[n]:.3f}" for n in KEY_DETECTORS if auroc.get(n) is not None]
    after = stealth["v_illusory_after_strongest"]
    strongest = (
        f"{stealth['strongest_defence']} leaves V-illusory {after:.2f} dB at <= {DEFEAT_V_TEST_COST:g} dB"
        if after is not None
        else f"no defence cut costs <= {DEFEAT_V_TEST_COST:g} dB"
    )
    if stealth["defeated_by"]:
        verdict = f"defeated by {', '.join(stealth['defeated_by'])}"
    else:
        verdict = "not defeated"
    verdict += f"; stealthy success: {'yes' if stealth['stealthy_success'] else 'no'}"
    return f"stealth: AUROC {', '.join(shown) or 'n/a'}; {strongest}; {verdict}"


def measure_stealth(
    run: LoadedRun, record: AttackRecord, attack_success: bool, cfg: DefendConfig | None = None
) -> dict[str, Any]:
    """:func:`stealth_summary` of a loaded attacked run (or a victim of a poisoned dataset) under the
    post-hoc defences of ``cfg`` (default: every post-hoc defence with ``stealth-ns defend``'s
    defaults), with each defence's scoring time; the model is left as it was. A model other than a
    stealth-splat one (which the defences' signals need) gives ``{"unavailable": reason}``."""
    from stealth_ns.defence_eval.command import score_posthoc
    from stealth_ns.defence_eval.evaluate import target_of
    from stealth_ns.method.model import StealthSplatModel

    if not isinstance(run.model, StealthSplatModel):
        return {
            "unavailable": f"the post-hoc defences need a stealth-splat model, not {type(run.model).__name__}"
        }
    cfg = cfg or DefendConfig(defences=POSTHOC)
    _, _, entries = score_posthoc(target_of(run, record), cfg, echo=None)
    summary = stealth_summary(entries, attack_success)
    summary["score_seconds"] = {name: e.get("score_seconds") for name, e in entries.items()}
    return summary
