"""When a run's poisoning happens: the noise schedule it trains under and the checks of its injection
step against the run's length, for a run that starts poisoning or resumes (the original schedule)."""

from __future__ import annotations

from typing import Any

from stealth_ns.attack.config import AttackConfig
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method.datamanager import NoiseSpec


def poison_schedule(
    cfg: AttackConfig, injection_step: int, max_steps: int, restored: dict[str, Any] | None
) -> NoiseSpec | None:
    """The view noise of a run of ``max_steps`` steps (a resumed run, ``restored`` its attack record: the
    original one), None without view noise. StealthNSError when the injection step lies past the run's
    end, or when a run of support views resumes."""
    if restored is not None and restored.get("noise"):
        max_steps = int(restored["noise"]["total_steps"])
    if restored is None and cfg.density_guided and injection_step >= max_steps:  # injects nothing
        given = "" if cfg.injection_step is not None else " (None: the end of the model's warm-up)"
        raise StealthNSError(
            f"--pipeline.attack.injection-step must be None or a step in [0, {max_steps}) "
            f"(the run's --max-num-iterations), got {injection_step}{given}: "
            "no poison Gaussian would be injected"
        )
    if restored is not None and cfg.support_views:
        raise StealthNSError(
            "resuming a run of --pipeline.attack.support-views is not supported (its support views' "
            "images are rendered at the injection): train it again"
        )
    return NoiseSpec(cfg.noise_sigma0, cfg.noise_decay, max_steps, cfg.seed) if cfg.view_noise else None
