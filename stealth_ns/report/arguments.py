"""``stealth-ns report``'s inputs checked before anything slow: before torch and nerfstudio load (the
command calls :func:`check_arguments` first), and again by :func:`~stealth_ns.report.write.write_report`
before it loads the two runs or clears an earlier report from the output folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stealth_ns.defence_eval.result_file import read_defend_result
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import check_writable
from stealth_ns.runs.paths import run_file, same_run


def check_arguments(poisoned: Path, clean: Path, output: Path, defend: Path | None) -> dict[str, Any] | None:
    """One-line StealthNSError for a run that is not there, an output that cannot be written, ``clean``
    that is the poisoned run itself, or a ``defend`` folder without a defend.json made for ``poisoned``;
    returns that defend.json (None without ``defend``)."""
    for flag, given in (("--poisoned", poisoned), ("--clean", clean)):
        if not run_file(given).is_file():
            raise StealthNSError(
                f"{flag} {given}: no run config at {run_file(given)} (give a run's config.yml or folder, "
                "or a 3DGS PLY)"
            )
    check_writable(output)
    if same_run(clean, poisoned):
        raise StealthNSError(f"--clean {clean} is the poisoned run itself: give a clean run of its scene")
    return None if defend is None else read_defend_result(defend, poisoned)
