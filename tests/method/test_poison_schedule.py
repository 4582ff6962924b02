"""stealth_ns.method.poison_schedule: a run's noise schedule and the checks of its injection step."""

from __future__ import annotations

import pytest

from stealth_ns.attack.config import AttackConfig
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method.datamanager import NoiseSpec
from stealth_ns.method.poison_schedule import poison_schedule


def test_a_new_run_gets_its_own_length_and_a_resumed_one_the_original():
    cfg = AttackConfig(noise_sigma0=30.0, seed=4)
    assert poison_schedule(cfg, 10, 100, None) == NoiseSpec(30.0, cfg.noise_decay, 100, 4)
    restored = {"noise": {"total_steps": 80}}
    assert poison_schedule(cfg, 500, 100, restored) == NoiseSpec(30.0, cfg.noise_decay, 80, 4)
    assert poison_schedule(AttackConfig(view_noise=False), 10, 100, None) is None


def test_an_injection_past_the_end_and_a_resumed_run_of_support_views_are_refused():
    with pytest.raises(StealthNSError, match=r"must be None or a step in \[0, 5\).*got 5 \(None: "):
        poison_schedule(AttackConfig(injection_step=None), 5, 5, None)  # the warm-up ends at 5
    poison_schedule(AttackConfig(density_guided=False), 5, 5, None)  # injects nothing anyway
    with pytest.raises(StealthNSError, match="resuming a run of --pipeline.attack.support-views"):
        poison_schedule(AttackConfig(support_views=2), 5, 100, {"noise": None})
