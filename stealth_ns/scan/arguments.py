"""``stealth-ns scan``'s inputs checked before anything slow: before torch and nerfstudio load (the
command calls :func:`check_arguments` first) and again by :func:`~stealth_ns.scan.command.run_scan`;
and the files it writes into ``--output``, under the rules of
:func:`~stealth_ns.foundation.output_folder.claim_output` (never through a link, never over an input or a file
it did not write, recorded in :data:`RECORD`)."""

from __future__ import annotations

from pathlib import Path

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import (
    check_no_links,
    check_output_plan,
    check_outside,
    check_writable,
)
from stealth_ns.runs.paths import run_file
from stealth_ns.scan.config import ScanConfig

SCAN_FILE = "scan.json"
HTML_FILE = "scan.html"
CLEANED_PLY = "cleaned.ply"
#: The cleaned nerfstudio run (a run input only), a folder the scan owns whole.
CLEANED_RUN = "cleaned"
IMAGES_DIR = "images"
#: The scan's record of the files it wrote into --output (:mod:`stealth_ns.foundation.file_manifest`).
RECORD = ".stealth-ns-scan.json"
WRITTEN_BY = "stealth-ns scan"


def is_ply(model: Path) -> bool:
    return Path(model).suffix.lower() == ".ply"


def model_input(model: Path) -> Path:
    """What the scan reads of ``model``: the PLY file, or the whole folder of a run (config,
    checkpoint); what was given, when it is neither."""
    model = Path(model)
    return run_file(model).parent if not is_ply(model) and run_file(model).is_file() else model


def output_plan(model: Path) -> tuple[list[str], list[str]]:
    """The files (other than the pictures, named once the views are known) and the folders owned whole
    that a scan of ``model`` writes into ``--output``."""
    return [SCAN_FILE, HTML_FILE, CLEANED_PLY], ([] if is_ply(model) else [CLEANED_RUN])


def check_arguments(model: Path, data: Path | None, output: Path, cfg: ScanConfig) -> None:
    """One-line StealthNSError for bad settings, or an output that is not writable, lies inside the
    run folder or the dataset, or where the scan's files would go through a link, over the model or
    over files an earlier scan did not write."""
    try:
        cfg.validate()
    except ValueError as err:
        raise StealthNSError(str(err)) from None
    check_writable(output, "scan")
    if Path(model).is_dir() or (Path(model).is_file() and not is_ply(model)):
        # a run (folder or config.yml): never into its folder (a PLY's folder may be anything)
        check_outside(output, run_file(model).parent, "the run folder")
    if data is not None:
        check_outside(output, data, "the dataset")
    files, folders = output_plan(model)
    check_no_links(output, [IMAGES_DIR])
    check_output_plan(output, RECORD, files, folders, {"--model": model_input(model), "--data": data})
