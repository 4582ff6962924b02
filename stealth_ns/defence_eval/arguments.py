"""``stealth-ns defend``'s inputs checked before anything slow: before torch and nerfstudio load (the
command calls :func:`check_arguments` first) and again by
:func:`~stealth_ns.defence_eval.command.run_defend`."""

from __future__ import annotations

from pathlib import Path

from stealth_ns.defences.config import DefendConfig
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import check_outside, check_writable
from stealth_ns.runs.paths import run_file, same_run


def check_arguments(run: Path, output: Path, cfg: DefendConfig, clean: Path | None) -> None:
    """One-line StealthNSError for bad settings, an output that is not writable or lies inside a run
    folder, or ``clean`` that is the attacked run itself."""
    try:
        cfg.validate()
    except ValueError as err:
        raise StealthNSError(str(err)) from None
    check_writable(output, "defence results")
    for given in (run, clean):
        if given is not None:
            check_outside(output, run_file(given).parent, "the run folder")
    if clean is not None and same_run(clean, run):
        # as `report` requires
        raise StealthNSError(f"--clean {clean} is the attacked run itself: give a clean run of its scene")
