"""``stealth-ns scan --model PLY_OR_RUN --data DATASET``: load, scan, write, summarise (docs/design/scan.md).

An official 3DGS output folder is scanned on the dataset with its photos (``--data``, or its cfg_args'
``source_path``) or, with none at hand, on its cameras.json alone: loaded on a dataset of those cameras
written into a temporary folder (removed after the scan) and scanned by the steps that need no photos
(:mod:`stealth_ns.scan.photos`)."""

from __future__ import annotations

import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from stealth_ns.datasets.official_output import is_official_output, photo_source, read_official_output
from stealth_ns.runs.imported import ImportedModel, load_model
from stealth_ns.runs.official_output import load_on_cameras
from stealth_ns.scan.arguments import check_arguments
from stealth_ns.scan.config import ScanConfig
from stealth_ns.scan.outputs import HTML_FILE, SCAN_FILE, write_outputs
from stealth_ns.scan.photos import PhotoUse
from stealth_ns.scan.scanner import scan_model


def run_scan(model: Path, data: Path | None, output: Path, cfg: ScanConfig) -> dict[str, Any]:
    """Scan ``model`` on the cameras of ``data`` and write every output into ``output``; returns
    scan.json's content. StealthNSError with one line on bad input, before any slow work."""
    check_arguments(Path(model), data, Path(output), cfg)
    t0 = time.perf_counter()
    with ExitStack() as stack:  # an official output without photos: its cameras' dataset, removed after
        imported, photos, shown = _load(Path(model), None if data is None else Path(data), cfg, stack)
        loaded = time.perf_counter() - t0
        result = scan_model(imported, cfg, echo=print, photos=photos)
        result.seconds["load"] = round(loaded, 2)
        result.seconds["total"] = round(time.perf_counter() - t0, 2)
        return write_outputs(result, output, Path(model), shown)


def _load(
    model: Path, data: Path | None, cfg: ScanConfig, stack: ExitStack
) -> tuple[ImportedModel, PhotoUse, Path]:
    """The model loaded, what the scan has of the photos, and the dataset scan.json names (an official
    output without photos: its cameras.json)."""
    if not is_official_output(model):
        print(f"loading {model}" + (f" on {data}" if data is not None else ""))
        imported = load_model(model, data, cfg.frame)
        if imported.frame_match:
            tried = ", ".join(f"{k} {v['psnr']:.1f} dB" for k, v in imported.frame_match.items())
            print(f"  frame: {imported.frame} (training views rendered in each frame tried: {tried})")
        origin = "--data" if data is not None else "the run's dataset"
        return imported, PhotoUse(True, origin, f"the photos of {imported.run.data}"), imported.run.data
    official = read_official_output(model)
    source = photo_source(official, data)
    if source.dataset is not None:
        print(f"loading {official.ply} on {source.dataset} ({source.origin})")
        imported = load_model(model, source.dataset, cfg.frame)
        why = (
            "the official 3DGS code trains in the frame of the dataset's poses"
            if cfg.frame == "auto"
            else "--frame"
        )
        print(f"  frame: {imported.frame} ({why})")
        return imported, PhotoUse(True, source.origin, source.note), imported.run.data
    print(f"loading {official.ply} on the cameras of {official.cameras_file} ({source.note})")
    workspace = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="stealth-ns-scan-cameras-")))
    imported, split = load_on_cameras(official, workspace, cfg.frame, load_model)
    print(f"  training views: {split.note}")
    return (
        imported,
        PhotoUse(False, "", f"{source.note}; training views: {split.note}"),
        official.cameras_file,
    )


def summary_lines(doc: dict[str, Any], output: Path) -> list[str]:
    """What the command prints at the end."""
    lines = [f"verdict: {doc['verdict']}"]
    if not doc["photos"]["used"]:
        lines[0] += " (scanned without photos: on the model and its cameras alone)"
    for t in doc["targeted_views"]:
        lines.append(
            f"  targeted view {t['name']}: {t['gaussians']} flagged Gaussians cover "
            f"{100 * t['region_share']:.1f}% of it"
        )
    if not doc["targeted_views"]:
        best = doc["groups"][0] if doc["groups"] else {"region_share": 0.0}
        cfg = doc["config"]
        share = best["region_share"]
        if share >= cfg["region_threshold"]:
            lines.append(
                f"  no targeted view: the largest region ({100 * share:.2f}% of {best['name']}) is drawn "
                f"by {best['gaussians']} Gaussians at {best['pixels_per_gaussian']:g} pixels each, a blob "
                f"rather than a picture (--max-pixels-per-gaussian {cfg['max_pixels_per_gaussian']:g})"
            )
        else:
            lines.append(
                f"  no group covers {100 * cfg['region_threshold']:.1f}% of its view "
                f"(largest {100 * share:.2f}%)"
            )
    left_out = doc.get("rows_left_out")
    broken = f", {left_out['count']} broken rows left out on reading" if left_out else ""
    lines.append(
        f"wrote {output / SCAN_FILE}, {output / HTML_FILE} and the cleaned model ({doc['removed']} Gaussians "
        f"removed{broken}) in {doc['seconds']['total']:.0f} s"
    )
    return lines
