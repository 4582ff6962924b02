"""``stealth-ns scan --model PLY_OR_RUN --data DATASET``: load, scan, write, summarise (docs/scan.md)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from stealth_ns.runs.imported import load_model
from stealth_ns.scan.arguments import check_arguments
from stealth_ns.scan.config import ScanConfig
from stealth_ns.scan.outputs import HTML_FILE, SCAN_FILE, write_outputs
from stealth_ns.scan.scanner import scan_model


def run_scan(model: Path, data: Path | None, output: Path, cfg: ScanConfig) -> dict[str, Any]:
    """Scan ``model`` on the cameras of ``data`` and write every output into ``output``; returns
    scan.json's content. StealthNSError with one line on bad input, before any slow work."""
    check_arguments(Path(model), data, Path(output), cfg)
    t0 = time.perf_counter()
    print(f"loading {model}" + (f" on {data}" if data is not None else ""))
    imported = load_model(Path(model), None if data is None else Path(data), cfg.frame)
    if imported.frame_match:
        tried = ", ".join(f"{k} {v['psnr']:.1f} dB" for k, v in imported.frame_match.items())
        print(f"  frame: {imported.frame} (training views rendered in each frame tried: {tried})")
    loaded = time.perf_counter() - t0
    result = scan_model(imported, cfg, echo=print)
    result.seconds["load"] = round(loaded, 2)
    result.seconds["total"] = round(time.perf_counter() - t0, 2)
    return write_outputs(result, output, Path(model), imported.run.data)


def summary_lines(doc: dict[str, Any], output: Path) -> list[str]:
    """What the command prints at the end."""
    lines = [f"verdict: {doc['verdict']}"]
    for t in doc["targeted_views"]:
        lines.append(
            f"  targeted view {t['name']}: {t['gaussians']} flagged Gaussians cover "
            f"{100 * t['region_share']:.1f}% of it"
        )
    if not doc["targeted_views"]:
        best = doc["groups"][0]["region_share"] if doc["groups"] else 0.0
        lines.append(
            f"  no group covers {100 * doc['config']['region_threshold']:.1f}% of its view "
            f"(largest {100 * best:.2f}%)"
        )
    lines.append(
        f"wrote {output / SCAN_FILE}, {output / HTML_FILE} and the cleaned model ({doc['removed']} Gaussians "
        f"removed) in {doc['seconds']['total']:.0f} s"
    )
    return lines
