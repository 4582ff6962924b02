"""``stealth-ns scan``'s inputs checked before anything slow: before torch and nerfstudio load (the
command calls :func:`check_arguments` first) and again by :func:`~stealth_ns.scan.command.run_scan`."""

from __future__ import annotations

from pathlib import Path

from stealth_ns.errors import StealthNSError
from stealth_ns.output_folder import check_outside, check_writable
from stealth_ns.runs.paths import run_file
from stealth_ns.scan.config import ScanConfig


def check_arguments(model: Path, data: Path | None, output: Path, cfg: ScanConfig) -> None:
    """One-line StealthNSError for bad settings, or an output that is not writable or lies inside the
    run folder or the dataset."""
    try:
        cfg.validate()
    except ValueError as err:
        raise StealthNSError(str(err)) from None
    check_writable(output, "scan")
    if Path(model).is_dir() or (Path(model).is_file() and Path(model).suffix.lower() != ".ply"):
        # a run (folder or config.yml): never into its folder (a PLY's folder may be anything)
        check_outside(output, run_file(model).parent, "the run folder")
    if data is not None:
        check_outside(output, data, "the dataset")
