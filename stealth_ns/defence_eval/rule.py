"""When a defence defeats the attack: the rule every defence is judged by, and the cut a defender
would pick within its V-test budget (plain numbers and dicts, no imports)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

#: A defence defeats the attack when V-illusory falls below this (dB) ...
DEFEAT_V_ILLUSORY = 15.0
#: ... for at most this much held-out PSNR (dB).
DEFEAT_V_TEST_COST = 0.5
DEFEAT_RULE = f"V-illusory < {DEFEAT_V_ILLUSORY:g} dB for a V-test cost <= {DEFEAT_V_TEST_COST:g} dB"


def lowest_within_cost(points: Iterable[dict[str, Any]], max_cost: float = DEFEAT_V_TEST_COST) -> dict | None:
    """Of some cuts (defend.json points: ``v_illusory_psnr``, ``v_test_cost``), the one with the lowest
    V-illusory among those measured and costing at most ``max_cost`` dB of V-test; None when none does."""
    ok = [
        p
        for p in points
        if p.get("v_test_cost") is not None
        and p["v_test_cost"] <= max_cost
        and p.get("v_illusory_psnr") is not None
    ]
    return min(ok, key=lambda p: p["v_illusory_psnr"]) if ok else None
