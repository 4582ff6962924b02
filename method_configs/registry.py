"""The stealth-ns methods as nerfstudio registers them (its ``nerfstudio.method_configs`` entry points)."""

from __future__ import annotations

from typing import Any

from stealth_ns.foundation.errors import StealthNSError

#: Methods with the attack pipeline (``--pipeline.attack.*``).
METHODS: tuple[str, ...] = ("stealth-splat-lite", "stealth-splat")


def method_config(method: str) -> Any:
    """The ``TrainerConfig`` a stealth-ns method is registered with (its nerfstudio entry point; shared:
    copy it before changing it)."""
    from importlib.metadata import entry_points

    if method not in METHODS:
        raise StealthNSError(f"unknown method {method!r}; methods: {', '.join(METHODS)}")
    for ep in entry_points(group="nerfstudio.method_configs"):
        if ep.name == method:
            return ep.load().config
    raise StealthNSError(f"method {method!r} is not registered with nerfstudio (is stealth-ns installed?)")


def method_iterations(method: str) -> int:
    """The default ``max_num_iterations`` of a stealth-ns method."""
    return int(method_config(method).max_num_iterations)
