"""``stealth-ns scan``'s inputs checked before anything slow: before torch and nerfstudio load (the
command calls :func:`check_arguments` first) and again by :func:`~stealth_ns.scan.command.run_scan`;
and the files it writes into ``--output``, under the rules of
:func:`~stealth_ns.foundation.output_folder.claim_output` (never through a link, never over an input or a file
it did not write, recorded in :data:`RECORD`)."""

from __future__ import annotations

from pathlib import Path

from stealth_ns.datasets.official_output import is_official_output, photo_source, read_official_output
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import (
    check_no_links,
    check_output_plan,
    check_outside,
    check_writable,
)
from stealth_ns.gaussians.model_files import is_model_file, model_file_name
from stealth_ns.runs.paths import run_file
from stealth_ns.scan.config import ScanConfig
from stealth_ns.scan.photos import PhotoUse, photo_signals_refused

SCAN_FILE = "scan.json"
HTML_FILE = "scan.html"
#: The cleaned model of a run or an official 3DGS output (a model file's is in its own format:
#: :func:`cleaned_model_name`).
CLEANED_PLY = "cleaned.ply"
#: The cleaned nerfstudio run (a run input only), a folder the scan owns whole.
CLEANED_RUN = "cleaned"
IMAGES_DIR = "images"
#: The scan's record of the files it wrote into --output (:mod:`stealth_ns.foundation.file_manifest`).
RECORD = ".stealth-ns-scan.json"
WRITTEN_BY = "stealth-ns scan"


def cleaned_model_name(model: Path) -> str:
    """The cleaned model's file name: ``cleaned`` in a model file's own format (``cleaned.spz``,
    ``cleaned.compressed.ply``...), :data:`CLEANED_PLY` for a run or an official 3DGS output."""
    return model_file_name("cleaned", model) if is_model_file(model) else CLEANED_PLY


def model_input(model: Path) -> Path:
    """What the scan reads of ``model``: the PLY file, the whole folder of a run (config, checkpoint)
    or of an official 3DGS output; what was given, when it is none of these."""
    model = Path(model)
    if is_official_output(model):
        return model
    return run_file(model).parent if not is_model_file(model) and run_file(model).is_file() else model


def output_plan(model: Path) -> tuple[list[str], list[str]]:
    """The files (other than the pictures, named once the views are known) and the folders owned whole
    that a scan of ``model`` writes into ``--output`` (a cleaned run for a nerfstudio run only)."""
    run = not is_model_file(model) and not is_official_output(model)
    return [SCAN_FILE, HTML_FILE, cleaned_model_name(model)], ([CLEANED_RUN] if run else [])


def check_arguments(model: Path, data: Path | None, output: Path, cfg: ScanConfig) -> None:
    """One-line StealthNSError for bad settings, or an output that is not writable, lies inside the
    run folder or the dataset, or where the scan's files would go through a link, over the model or
    over files an earlier scan did not write."""
    try:
        cfg.validate()
    except ValueError as err:
        raise StealthNSError(str(err)) from None
    check_writable(output, "scan")
    if is_official_output(model):
        check_outside(output, model, "the 3DGS output folder")
        data = _official_photos(Path(model), data, cfg)
    elif Path(model).is_dir() or (Path(model).is_file() and not is_model_file(model)):
        # a run (folder or config.yml): never into its folder (a PLY's folder may be anything)
        check_outside(output, run_file(model).parent, "the run folder")
    if data is not None:
        check_outside(output, data, "the dataset")
    files, folders = output_plan(model)
    check_no_links(output, [IMAGES_DIR])
    check_output_plan(output, RECORD, files, folders, {"--model": model_input(model), "--data": data})


def _official_photos(model: Path, data: Path | None, cfg: ScanConfig) -> Path | None:
    """The official output ``model`` read and checked, and the dataset with its photos (None without:
    then no signal that needs them may be asked for)."""
    source = photo_source(read_official_output(model), data)
    refused = photo_signals_refused(
        PhotoUse(source.dataset is not None, source.origin, source.note), cfg.signals
    )
    if refused:
        raise StealthNSError(refused)
    return source.dataset
