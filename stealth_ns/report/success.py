"""The paper's success rule (section 4) and its appendix's thresholds: pure functions of two numbers."""

from __future__ import annotations

#: (V-illusory PSNR above, V-test drop at most) pairs: the paper's rule first, then its appendix's.
SUCCESS_THRESHOLDS: tuple[tuple[float, float], ...] = ((25.0, 3.0), (25.0, 8.0), (20.0, 9.0), (15.0, 10.0))


def attack_success(
    v_illusory_psnr: float, v_test_drop: float, psnr_min: float = 25.0, drop_max: float = 3.0
) -> bool:
    """The paper's rule (section 4): V-illusory PSNR > ``psnr_min`` and V-test drop <= ``drop_max`` (dB)."""
    return v_illusory_psnr > psnr_min and v_test_drop <= drop_max


def success_verdicts(v_illusory_psnr: float, v_test_drop: float) -> dict[str, bool]:
    """``{"25/3": ..., "25/8": ..., "20/9": ..., "15/10": ...}`` for every pair in SUCCESS_THRESHOLDS."""
    return {f"{p:g}/{d:g}": attack_success(v_illusory_psnr, v_test_drop, p, d) for p, d in SUCCESS_THRESHOLDS}
