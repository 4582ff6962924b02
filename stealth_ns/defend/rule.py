"""When a defence defeats the attack: the rule every defence is judged by (plain numbers, no imports)."""

from __future__ import annotations

#: A defence defeats the attack when V-illusory falls below this (dB) ...
DEFEAT_V_ILLUSORY = 15.0
#: ... for at most this much held-out PSNR (dB).
DEFEAT_V_TEST_COST = 0.5
DEFEAT_RULE = f"V-illusory < {DEFEAT_V_ILLUSORY:g} dB for a V-test cost <= {DEFEAT_V_TEST_COST:g} dB"
