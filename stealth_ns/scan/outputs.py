"""The files of ``stealth-ns scan``: scan.json, scan.html with its images, the cleaned model.

* ``scan.json``: the verdict, the targeted views (region share, pixels, box, Gaussians), every
  rendered group, each signal's rule and count, the model (kind, frame and how each frame matched),
  which steps read the photos and which the cameras alone (``photos``), timings; and, when the model
  carries stealth-ns's poison tag (our runs, their ``ns-export`` PLYs), how the scan compares with it
  (``ground_truth``: never used by the verdict); the broken rows the model file's reader left out
  (``rows_left_out``: :mod:`~stealth_ns.gaussians.broken_rows`; null when none);
* ``images/VIEW_{full,without,flagged,effect}.png`` per targeted view, and ``scan.html``;
* the cleaned model without the targeted groups (and without the broken rows left out on reading), in
  the input's own frame: in the format of an input model file (``cleaned.ply``, ``cleaned.compressed.ply``,
  ``cleaned.splat``, ``cleaned.spz``), ``cleaned.ply`` for a run or an official 3DGS output; and for a
  nerfstudio run also ``cleaned/`` (a nerfstudio run: ``ns-eval``, ``ns-viewer``);
* ``.stealth-ns-scan.json``: the record of every file written, with its hash. A later scan into the
  same folder replaces those files (unchanged ones only) and refuses to write over any other, through
  a symbolic link, or over its own input (:func:`~stealth_ns.foundation.output_folder.claim_output`).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
from pathlib import Path
from typing import Any

import numpy as np
import torch

from stealth_ns.defences import detection
from stealth_ns.defences.pruned_run import write_pruned_run
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.html_page import render_page
from stealth_ns.foundation.json_io import atomic_path, json_safe, write_json_atomic, write_text_atomic
from stealth_ns.foundation.output_folder import claim_output, record_output, remove_tree, unfinished
from stealth_ns.foundation.provenance import software_and_hardware
from stealth_ns.gaussians.model_files import is_model_file, write_model_file
from stealth_ns.gaussians.ply import write_gaussian_ply
from stealth_ns.images.io import save_png
from stealth_ns.scan.arguments import (
    CLEANED_PLY,
    CLEANED_RUN,
    HTML_FILE,
    IMAGES_DIR,
    RECORD,
    SCAN_FILE,
    WRITTEN_BY,
    cleaned_model_name,
    model_input,
    output_plan,
)
from stealth_ns.scan.photos import photo_record
from stealth_ns.scan.scanner import Group, ScanResult

IMAGES = ("full", "without", "flagged", "effect")
__all__ = ["CLEANED_PLY", "CLEANED_RUN", "HTML_FILE", "SCAN_FILE", "write_outputs"]


def _slug(name: str) -> str:
    """A view's name (``images/frame_00030.png``) as a file-name stem (``images_frame_00030``)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in str(Path(name).with_suffix("")))


def image_file(name: str, kind: str) -> str:
    """The picture ``kind`` of the view ``name``, relative to the output folder."""
    return f"{IMAGES_DIR}/{_slug(name)}_{kind}.png"


def group_entry(group: Group) -> dict[str, Any]:
    r = group.region
    return {
        "view": group.view,
        "name": group.name,
        "gaussians": int(group.members.sum()),
        "region_share": round(r.share, 5),
        "region_pixels": r.pixels,
        "region_box": list(r.box),
        "pixels_per_gaussian": round(r.pixels / max(int(group.members.sum()), 1), 3),
        "targeted": group.targeted,
    }


def ground_truth(result: ScanResult) -> dict[str, Any] | None:
    """How the scan compares with the poison tag the model carries, or None without one."""
    poison = result.model.cloud.poison_mask()
    if poison is None or len(poison) != len(result.flagged):
        return None
    removed = result.removed
    return {
        "n_poison": int(poison.sum()),
        "flagged_poison": int((result.flagged & poison).sum()),
        "flagged_clean": int((result.flagged & ~poison).sum()),
        "removed_poison": int((removed & poison).sum()),
        "removed_clean": int((removed & ~poison).sum()),
        "auroc": {
            n: detection.detection_metrics(s.scores, poison)["auroc"] for n, s in result.scored.items()
        },
    }


def rows_left_out(result: ScanResult) -> dict[str, Any] | None:
    """The broken rows the model file's reader left out (count, total, reasons, first rows), or None."""
    record = result.model.cloud.left_out
    if record is None:
        return None
    return {
        **record.record(),
        "note": "left out on reading: not scanned, and not in the cleaned model (the input without these "
        "rows and without the targeted groups)",
    }


def scan_document(result: ScanResult, model_path: Path, data: Path) -> dict[str, Any]:
    """scan.json's content."""
    imported, cfg = result.model, result.config
    return {
        "verdict": result.verdict,
        "targeted_views": [group_entry(g) for g in result.targeted],
        "rule": (
            f"suspicious when the flagged Gaussians one view sees most (or at least {cfg.group_share:.0%} as "
            f"much as the view that sees them most) cover, connected, at least "
            f"{cfg.region_threshold:.1%} of that view, floating in front of what the rest of the model shows "
            f"there (below {cfg.depth_ratio:g} of its depth and {cfg.near_ratio:g} x {result.near_share:.2f} "
            f"of the view's near depth, itself {result.near_share:.2f} of its median scene depth) and "
            f"changing its colour by more than {cfg.colour_change:g}, with at least one Gaussian per "
            f"{cfg.max_pixels_per_gaussian:g} pixels of the region"
        ),
        "near_depth_share": round(result.near_share, 4),
        "model": {
            "path": str(model_path),
            "kind": imported.kind,
            "gaussians": len(imported.cloud),
            "sh_degree": imported.cloud.sh_degree,
            "frame": imported.frame,
            "frame_match": imported.frame_match,
            "render_match_above_flat": round(result.render_match, 2),
        },
        "data": str(data),
        "photos": photo_record(result.photos, cfg.signals),
        "training_views": len(result.model.run.pipeline.datamanager.train_dataset),
        "signals": {
            n: {"rule": s.rule, "flagged": int(s.pruned.sum()), "seconds": s.seconds}
            for n, s in result.scored.items()
        },
        "flagged": int(result.flagged.sum()),
        "removed": int(result.removed.sum()),
        "groups": [group_entry(g) for g in result.groups],
        "ground_truth": ground_truth(result),
        "rows_left_out": rows_left_out(result),
        "config": dataclasses.asdict(cfg),
        "seconds": result.seconds,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "software": software_and_hardware(),
    }


def write_images(result: ScanResult, output: Path) -> dict[str, dict[str, str]]:
    """Each targeted view's renders -> ``images/``; returns view name -> kind -> path (relative)."""
    (output / IMAGES_DIR).mkdir(parents=True, exist_ok=True)
    files = {}
    for g in result.targeted:
        files[g.name] = {}
        for kind in IMAGES:
            rel = image_file(g.name, kind)
            image = g.renders[kind]
            save_png(output / rel, image.astype(np.float32) if image.dtype == bool else image)
            files[g.name][kind] = rel
    return files


def write_cleaned(result: ScanResult, output: Path, model_path: Path) -> dict[str, str]:
    """The model without the targeted groups (of the rows read: without the broken rows left out on
    reading), in the format of the model file ``model_path``
    (:func:`~stealth_ns.scan.arguments.cleaned_model_name`; cleaned.ply for a run or an official
    output), and a nerfstudio run for a run input."""
    keep = ~result.removed
    imported = result.model
    name = cleaned_model_name(model_path)
    written = {"ply": name}
    cleaned, comment = imported.cloud.subset(keep), "stealth-ns scan: cleaned"
    with atomic_path(output / name) as tmp:
        if is_model_file(model_path):
            write_model_file(tmp, cleaned, like=Path(model_path), comment=comment)
        else:
            write_gaussian_ply(tmp, cleaned, comment=comment)
    checkpoint = imported.run.checkpoint
    if checkpoint is not None:
        info = {
            "defence": "scan",
            "removed": int(result.removed.sum()),
            "views": [g.name for g in result.targeted],
        }
        config = write_pruned_run(
            imported.run.config_path, checkpoint, torch.from_numpy(keep), output, CLEANED_RUN, info
        )
        written["run"] = str(config.relative_to(output.resolve()))  # --output may be a link to a folder
    return written


def render_html(doc: dict[str, Any]) -> str:
    """``scan.html`` from scan.json's content (jinja2, autoescaped, images relative)."""
    return render_page("stealth_ns.scan", "scan.html.j2", s=doc)


def write_outputs(result: ScanResult, output: Path, model_path: Path, data: Path) -> dict[str, Any]:
    """Every file of the scan into ``output`` (checked again now that the pictures' names are known,
    an earlier scan's files replaced, all recorded); returns scan.json's content."""
    output = Path(output)
    files, folders = output_plan(model_path)
    files += [image_file(g.name, kind) for g in result.targeted for kind in IMAGES]
    if result.model.run.checkpoint is None:
        folders = []  # a cleaned run is written only for a run with a checkpoint
    inputs = {"--model": model_input(model_path), "--data": data}
    claim_output(output, RECORD, WRITTEN_BY, files, folders, inputs)
    doc = scan_document(result, model_path, data)
    try:
        doc["images"] = write_images(result, output)
        doc["cleaned"] = write_cleaned(result, output, model_path)
        write_json_atomic(output / SCAN_FILE, json_safe(doc))  # scan.json and scan.html last
        write_text_atomic(output / HTML_FILE, render_html(doc))
    except (OSError, StealthNSError) as err:
        raise unfinished(err, output, "scan", lambda: _remove_written(output, files, folders)) from None
    record_output(output, RECORD, WRITTEN_BY, files, folders)
    return doc


def _remove_written(output: Path, files: list[str], folders: list[str]) -> bool:
    """Remove the scan's ``files`` and ``folders`` from ``output`` (never through a link), and its
    pictures' folder once empty."""
    for name in [*files, *folders]:
        remove_tree(output / name, output)
    images = output / IMAGES_DIR
    if images.is_dir() and not images.is_symlink() and not any(images.iterdir()):
        images.rmdir()
    return True
