"""The attack report: a poisoned run against a clean run of the same scene.

:func:`stealth_ns.report.numbers.compare_runs` loads both runs (:mod:`stealth_ns.runs`: nerfstudio's
``eval_setup`` with a safe YAML loader), checks they were trained on the same dataset, renders them
and returns the paper's numbers: V-illusory (masked metrics of the poisoned view against the
illusion target I_ILL), V-test (held-out views against the clean images) for both runs and its
drop, the success verdicts (paper: V-illusory PSNR > 25 dB and drop <= 3 dB; appendix: 25/8, 20/9,
15/10). :func:`write_report` adds the pictures: the poisoned views (target, poisoned render,
clean render, poisoned render with the poison Gaussians hidden), a strip of held-out views
(clean vs poisoned), and the neighbour-view curve of the paper's Fig. 8 (PSNR between the
clean and poisoned renders of cameras orbited up to +-20 degrees from each poisoned view), as
``report.json``, PNGs, and a self-contained ``report.html`` that references them.
"""

from __future__ import annotations

import datetime as _dt
import re
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.attack.coverage import OPEN_BELOW
from stealth_ns.defence_eval.stealth import stealth_line
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.figures import figure_grid, save_plot
from stealth_ns.foundation.json_io import json_safe, write_json_atomic, write_text_atomic
from stealth_ns.foundation.output_folder import unfinished
from stealth_ns.foundation.provenance import software_and_hardware
from stealth_ns.images.io import rgb_float, save_png
from stealth_ns.images.metrics import psnr
from stealth_ns.report.arguments import check_arguments
from stealth_ns.report.html import fmt, render_html
from stealth_ns.report.numbers import neighbour_curve, pair_metrics
from stealth_ns.runs.loaded import poison_coverage, render
from stealth_ns.runs.pair import RunPair

#: Held-out views shown in the report's strip.
STRIP_VIEWS = 6


def _plot_neighbour_curve(path: Path, curve: dict[str, Any]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.4))
    angles = curve["angles_deg"]
    for name, values in curve["per_view"].items():
        if len(curve["per_view"]) > 1:
            ax.plot(angles, values, lw=1, alpha=0.5, label=name)
    ax.plot(angles, curve["psnr_mean"], "o-", color="C3", lw=2, label="mean over poisoned views")
    ax.axvspan(-5, 5, color="0.9", zorder=0)
    save_plot(
        fig,
        ax,
        path,
        "rotation from the poisoned view (degrees)",
        "PSNR clean vs poisoned (dB)",
        "Effect on neighbouring views",
    )
    return path


def _innocent_strip(pair: RunPair, images: Path) -> list[dict[str, Any]]:
    """Up to STRIP_VIEWS held-out views, evenly spaced: ground truth, clean and poisoned renders."""
    dm = pair.poisoned.pipeline.datamanager
    cameras, n = dm.eval_dataset.cameras, len(dm.eval_dataset)
    names = [Path(p).name for p in dm.eval_dataset.image_filenames]
    picks = sorted({int(round(i)) for i in np.linspace(0, n - 1, min(STRIP_VIEWS, n))}) if n else []
    strip = []
    for i in picks:
        gt = rgb_float(dm.cached_eval[i]["image"]).numpy()
        clean, poisoned = render(pair.clean, cameras, i), render(pair.poisoned, cameras, i)
        files = {}
        for kind, image in (("gt", gt), ("clean", clean), ("poisoned", poisoned)):
            files[kind] = f"images/heldout{i:03d}_{kind}.png"
            save_png(images.parent / files[kind], image)
        strip.append(
            {
                "name": names[i],
                "psnr_clean": psnr(clean, gt),
                "psnr_poisoned": psnr(poisoned, gt),
                "psnr_clean_vs_poisoned": psnr(poisoned, clean),
                "images": files,
                "arrays": (gt, clean, poisoned),
            }
        )
    return strip


#: Files a report writes (relative to its folder): removed from a reused folder before writing, so
#: that no picture of an earlier report stays behind; any other file is left alone.
REPORT_FILES = re.compile(
    r"(report\.json|report\.html|poisoned_views\.png|heldout_views\.png|neighbour_curve\.png"
    r"|images/view\d{4,}_(target|poisoned|clean|poison_hidden|mask)\.png"
    r"|images/heldout\d{3,}_(gt|clean|poisoned)\.png"
    r"|defences/(roc|curves|poisoned_view)\.png)"
)


def clear_previous_report(output: Path) -> list[Path]:
    """Delete the files an earlier report wrote into ``output`` (:data:`REPORT_FILES`); returns them."""
    if not output.is_dir():
        return []
    candidates = [*output.glob("*"), *(output / "images").glob("*"), *(output / "defences").glob("*")]
    removed = []
    for path in candidates:
        rel = path.relative_to(output).as_posix()
        if path.is_file() and not path.is_symlink() and REPORT_FILES.fullmatch(rel):
            try:
                path.unlink()
            except OSError as err:
                raise StealthNSError(
                    f"cannot replace {path} of an earlier report: {err.strerror or err}"
                ) from None
            removed.append(path)
    return removed


def write_report(
    poisoned_config: Path,
    clean_config: Path,
    output: Path,
    defend: Path | None = None,
    stealth: bool = True,
    poisoned_data: Path | None = None,
    clean_data: Path | None = None,
) -> dict[str, Any]:
    """Compare the runs and write ``report.json``, ``report.html`` and PNGs into ``output``; with
    ``defend`` (a ``stealth-ns defend`` folder of the poisoned run) also a "Defences" section;
    ``stealth``: measure the poisoned run's stealth under the post-hoc defences (a "Stealth" section).
    Either run may be a 3DGS PLY from another trainer with its dataset (``*_data``: a victim of
    ``poison-dataset`` with the poisoned copy it was trained on).

    Every file is written whole (a temporary file renamed), report.json and report.html last; a write
    that fails (a full disk) removes what the report wrote so far, so no unfinished report is left
    looking complete, and is a one-line StealthNSError naming the file and the reason."""
    output = Path(output)
    defend_result = check_arguments(poisoned_config, clean_config, output, defend)  # before the slow part
    pair = RunPair.load(Path(poisoned_config), Path(clean_config), poisoned_data, clean_data)
    report = pair_metrics(pair, stealth=stealth)
    report["poisoned_run"] = str(pair.poisoned.config_path.resolve())
    report["clean_run"] = str(pair.clean.config_path.resolve())
    report["created"] = _dt.datetime.now().isoformat(timespec="seconds")
    report["defences"] = None
    # an earlier report in the folder is replaced only now: a refusal or a failure above leaves it as it was
    clear_previous_report(output)
    try:
        if defend_result is not None:
            from stealth_ns.report.defences_section import report_section

            report["defences"] = report_section(defend_result, Path(defend), output)
        return _write_files(pair, report, output)
    except (OSError, StealthNSError) as err:
        raise unfinished(err, output, "report", lambda: clear_previous_report(output)) from None


def _write_files(pair: RunPair, report: dict[str, Any], output: Path) -> dict[str, Any]:
    """The pictures, the figures, report.json and report.html of ``report`` into ``output``."""
    images = output / "images"
    images.mkdir(parents=True, exist_ok=True)
    view_files = _poisoned_views(pair, report, output)
    strip = _innocent_strip(pair, images)
    if strip:
        kinds = ("ground truth", "clean", "poisoned")
        rows = [[(f"{s['name']} {kind}", s["arrays"][k]) for s in strip] for k, kind in enumerate(kinds)]
        figure_grid(output / "heldout_views.png", rows)
    for s in strip:
        del s["arrays"]
    curve = neighbour_curve(pair)
    _plot_neighbour_curve(output / "neighbour_curve.png", curve)

    report["neighbour_views"] = curve
    report["environment"] = software_and_hardware()
    report["heldout_strip"] = strip
    report["images"] = {
        "poisoned_views": view_files,
        "figures": {
            "poisoned_views": "poisoned_views.png",
            "heldout_views": "heldout_views.png" if strip else None,
            "neighbour_curve": "neighbour_curve.png",
        },
    }
    report = json_safe(report)
    write_json_atomic(output / "report.json", report)
    write_text_atomic(output / "report.html", render_html(report))
    return report


def _poisoned_views(pair: RunPair, report: dict[str, Any], output: Path) -> dict[str, dict[str, str]]:
    """Each poisoned view's pictures (target, renders, mask) and their grid ``poisoned_views.png``;
    returns the pictures' names by view."""
    view_rows, view_files = [], {}
    for v in pair.views:
        panels = {
            "target": v.target.numpy(),
            "poisoned": render(pair.poisoned, pair.cameras, v.index),
            "clean": render(pair.clean, pair.cameras, v.index),
            "poison_hidden": render(pair.poisoned, pair.cameras, v.index, render_filter="hide_poison"),
            "mask": np.repeat(v.mask.numpy()[..., None].astype(np.float32), 3, -1),
        }
        covered = poison_coverage(pair.poisoned, pair.cameras, v.index)
        if covered is not None:
            panels["poison_coverage"] = np.repeat(covered[..., None], 3, -1)
        files = {}
        for kind, image in panels.items():
            files[kind] = f"images/view{v.index:04d}_{kind}.png"
            save_png(output / files[kind], image)
        view_files[v.name] = files
        m = report["v_illusory_per_view"][v.name]
        view_rows.append(
            [
                (f"{v.name}: target I_ILL", panels["target"]),
                (f"poisoned render ({m['psnr']:.2f} dB)", panels["poisoned"]),
                (f"clean render ({m['clean_psnr']:.2f} dB)", panels["clean"]),
                ("poisoned, poison hidden", panels["poison_hidden"]),
                ("illusion mask", panels["mask"]),
                *([("poison alone: opacity", panels["poison_coverage"])] if covered is not None else []),
            ]
        )
    figure_grid(output / "poisoned_views.png", view_rows)
    return view_files


def summary_lines(report: dict[str, Any], output: Path) -> list[str]:
    """The headline numbers of a report, for the terminal."""
    r = report
    lines = [
        f"V-illusory:  PSNR {fmt(r['v_illusory_psnr'])} dB, SSIM {fmt(r['v_illusory_ssim'], 3)}, "
        f"LPIPS {fmt(r['v_illusory_lpips'], 3)}  (clean run: {fmt(r['v_illusory_clean_psnr'])} dB)",
        f"V-test PSNR: clean {fmt(r['v_test_psnr_clean'])} dB, poisoned {fmt(r['v_test_psnr'])} dB, "
        f"drop {fmt(r['v_test_drop'])} dB",
        f"attack success: {r['attack_success']}  (V-illusory > 25 dB and drop <= 3 dB); "
        + ", ".join(f"{k}: {v}" for k, v in r["success_thresholds"].items() if k != "25/3"),
    ]
    for name, m in r["v_illusory_per_view"].items():
        c = m.get("poison_coverage")
        if c and c["open_error_share"] is not None:
            lines.append(
                f"  {name}: poison covers {fmt(100 * c['coverage_mean'], 1)} % of the illusion; "
                f"{fmt(100 * c['open_share'], 1)} % of its pixels open (< {OPEN_BELOW}) hold "
                f"{fmt(100 * c['open_error_share'], 1)} % of the error ({fmt(c['open_psnr'])} dB there, "
                f"{fmt(c['covered_psnr'])} dB where covered)"
            )
    if r.get("stealth"):
        lines.append(stealth_line(r["stealth"]))
    if r.get("lpips_unavailable"):
        lines.append(f"LPIPS unavailable: {r['lpips_unavailable']}")
    lines.append(f"report: {Path(output).resolve() / 'report.html'}")
    return lines
