"""The attack report: a poisoned run against a clean run of the same scene.

``compare_runs`` loads both runs (nerfstudio's ``eval_setup`` with a safe YAML loader,
:mod:`stealth_ns.safe_config`), checks they were trained on the same dataset, renders them and returns the
paper's numbers: V-illusory (masked metrics of the poisoned view against the illusion target
I_ILL), V-test (held-out views against the clean images) for both runs and its drop, the
success verdicts (paper: V-illusory PSNR > 25 dB and drop <= 3 dB; appendix: 25/8, 20/9,
15/10). ``write_report`` adds the pictures: the poisoned views (target, poisoned render,
clean render, poisoned render with the poison Gaussians hidden), a strip of held-out views
(clean vs poisoned), and the neighbour-view curve of the paper's Fig. 8 (PSNR between the
clean and poisoned renders of cameras orbited up to +-20 degrees from each poisoned view), as
``report.json``, PNGs, and a self-contained ``report.html`` that references them.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from stealth_ns.attack.record import AttackRecord, PoisonView
from stealth_ns.attack.views import rotate_pose, scene_center, scene_up
from stealth_ns.errors import StealthNSError, StealthNSExit
from stealth_ns.fingerprint import dataset_fingerprint, fingerprint_differences, recorded_fingerprint
from stealth_ns.image_io import save_png
from stealth_ns.json_io import json_safe
from stealth_ns.metrics import LazyLPIPS, illusion_metrics, psnr, v_illusory
from stealth_ns.model import render_camera
from stealth_ns.pipeline import rgb_float
from stealth_ns.provenance import software_and_hardware

#: (V-illusory PSNR above, V-test drop at most) pairs: the paper's rule first, then its appendix's.
SUCCESS_THRESHOLDS: tuple[tuple[float, float], ...] = ((25.0, 3.0), (25.0, 8.0), (20.0, 9.0), (15.0, 10.0))
#: Neighbour-view angles (degrees) about the scene's vertical axis, as the paper's Fig. 8.
NEIGHBOUR_ANGLES: tuple[float, ...] = tuple(float(a) for a in np.arange(-20.0, 20.01, 2.5))
#: Held-out views shown in the report's strip.
STRIP_VIEWS = 6


def attack_success(
    v_illusory_psnr: float, v_test_drop: float, psnr_min: float = 25.0, drop_max: float = 3.0
) -> bool:
    """The paper's rule (section 4): V-illusory PSNR > ``psnr_min`` and V-test drop <= ``drop_max`` (dB)."""
    return v_illusory_psnr > psnr_min and v_test_drop <= drop_max


def success_verdicts(v_illusory_psnr: float, v_test_drop: float) -> dict[str, bool]:
    """``{"25/3": ..., "25/8": ..., "20/9": ..., "15/10": ...}`` for every pair in SUCCESS_THRESHOLDS."""
    return {f"{p:g}/{d:g}": attack_success(v_illusory_psnr, v_test_drop, p, d) for p, d in SUCCESS_THRESHOLDS}


# ---------------------------------------------------------------------------- loading runs
@dataclass
class LoadedRun:
    """A trained run loaded for evaluation."""

    config_path: Path
    pipeline: Any  # a nerfstudio Pipeline (a StealthPipeline for the poisoned run)
    step: int
    config: Any = None  # the run's TrainerConfig, as loaded
    checkpoint: Path | None = None  # the checkpoint nerfstudio loaded (the latest)

    @property
    def model(self) -> Any:
        return self.pipeline.model

    @property
    def attack_enabled(self) -> bool:
        attack = getattr(self.pipeline.config, "attack", None)
        return bool(attack is not None and attack.enabled)

    @property
    def data(self) -> Path:
        """The dataset the run was loaded with."""
        dm = self.pipeline.datamanager.config
        return Path(dm.data or dm.dataparser.data)

    def fingerprints(self) -> dict[str, dict[str, Any]]:
        """``{"train": ..., "held-out": ...}`` (:mod:`stealth_ns.fingerprint`): the training split's as
        recorded when the run was trained (recomputed for runs that lack the record), the held-out
        split's from the dataset as loaded."""
        dm = self.pipeline.datamanager
        train = recorded_fingerprint(self.config_path.parent)
        if train is None:
            train = dataset_fingerprint(dm.train_dataparser_outputs)
        return {"train": train, "held-out": dataset_fingerprint(dm.eval_dataset._dataparser_outputs)}


def load_run(config_path: Path) -> LoadedRun:
    """``eval_setup`` for a run folder's ``config.yml``, with one-line errors for the usual mistakes.

    The config is read with :func:`stealth_ns.safe_config.load_config` (a YAML loader that executes
    nothing). The checkpoint is looked up next to the config file, so a run folder that was moved
    (or a relative ``--output-dir``) still loads.
    """
    from stealth_ns.safe_config import safe_eval_setup

    config_path = Path(config_path)
    if config_path.is_dir():
        config_path = config_path / "config.yml"
    if not config_path.is_file():
        raise StealthNSError(f"no run config at {config_path} (give the config.yml of a training run)")
    models = config_path.parent / "nerfstudio_models"
    if not models.is_dir() or not any(models.glob("*.ckpt")):
        raise StealthNSError(
            f"{config_path.parent} has no checkpoint (nerfstudio_models/*.ckpt): not trained?"
        )

    def relocate(config: Any) -> Any:
        config.output_dir = config_path.parent.resolve()
        config.experiment_name, config.method_name, config.timestamp = ".", ".", "."
        data = Path(config.pipeline.datamanager.data or config.pipeline.datamanager.dataparser.data)
        if not data.exists():
            raise StealthNSError(
                f"the scene of {config_path} is not at {data} (was the run trained from another folder?)"
            )
        return config

    try:
        config, pipeline, checkpoint, step = safe_eval_setup(
            config_path, test_mode="test", update_config_callback=relocate
        )
    except StealthNSExit as err:  # the pipeline's own one-line errors, as raised
        raise err.error from None
    # nerfstudio undistorts the training images, and their cameras in place, when it first caches them
    # (lazily); a run without the attack never did: cache them, so the training cameras are the ones
    # the run trained with and its attack record uses (a lens-distorted capture trains on cropped images)
    if hasattr(type(pipeline.datamanager), "cached_train"):
        pipeline.datamanager.cached_train  # noqa: B018 - the access does the work
    return LoadedRun(config_path, pipeline, step, config, Path(checkpoint))


def attack_record(run: LoadedRun, given: Path) -> AttackRecord:
    """The attack record of an attacked run, or of the poisoned dataset a plain run (a victim) trained on
    (``stealth-ns poison-dataset`` / ``ipa-poison``); ``given``: the run's path as the user gave it."""
    from stealth_ns.poisoning.dataset_copy import RECORD_DIR, is_poisoned_copy

    attack_dir = run.config_path.parent / "attack"
    if not run.attack_enabled and is_poisoned_copy(run.data):
        return AttackRecord.read(run.data / RECORD_DIR, run.pipeline.datamanager.train_dataset.cameras)
    if not run.attack_enabled or not AttackRecord.exists(attack_dir):
        raise StealthNSError(
            f"{given} is not an attacked run (trained with the attack disabled, not on a poisoned dataset)"
        )
    return AttackRecord.read(
        attack_dir, run.pipeline.datamanager.train_dataset.cameras, run.pipeline.poison_views
    )


@torch.no_grad()
def render(
    run: LoadedRun, cameras: Any, index: int, c2w: np.ndarray | None = None, render_filter: str = "all"
) -> np.ndarray:
    """Render camera ``index`` of ``cameras`` (optionally moved to ``c2w`` [3, 4]) -> [H, W, 3] in [0, 1].

    ``render_filter``: "all", "hide_poison" or "only_poison" (a StealthSplatModel's filter).
    """
    camera = cameras[index : index + 1].to("cpu")
    if c2w is not None:
        camera.camera_to_worlds = torch.as_tensor(c2w, dtype=torch.float32)[None]
    rgb = render_camera(run.model, camera, render_filter)["rgb"]
    return rgb.float().clamp(0, 1).cpu().numpy()


# ---------------------------------------------------------------------------- the numbers
@dataclass
class RunPair:
    """A poisoned run and a clean run of the same scene, loaded."""

    poisoned: LoadedRun
    clean: LoadedRun
    record: AttackRecord  # the poisoned run's

    @classmethod
    def load(cls, poisoned: Path, clean: Path) -> RunPair:
        ours, theirs = load_run(poisoned), load_run(clean)
        pair = cls(ours, theirs, attack_record(ours, poisoned))
        if pair.clean.attack_enabled:
            raise StealthNSError(
                f"{clean} was trained with the attack on; train the clean run with "
                "--pipeline.attack.enabled False (or any other splatting method)"
            )
        pair.check_same_dataset()
        return pair

    def check_same_dataset(self) -> None:
        """StealthNSError (one line, naming both runs and what differs) unless both runs were trained
        on the same images with the same poses, and are evaluated on the same held-out views."""
        ours, theirs = self.poisoned.fingerprints(), self.clean.fingerprints()
        copied = (self.record.poisoned_dataset or {}).get("source_train_fingerprint")
        if copied:  # a victim of a poisoned copy: its images differ by design; the source's must match
            ours["train"] = {**ours["train"], "images": copied["images"]}
        differ = []
        for split, label in (("train", "training"), ("held-out", "held-out")):
            for what in fingerprint_differences(ours[split], theirs[split]):
                differ.append(f"{label} {'images' if what == 'images' else 'camera poses'}")
        if differ:
            raise StealthNSError(
                f"the runs were not trained on the same dataset: their {_listing(differ)} differ "
                f"(poisoned run {self.poisoned.config_path}, data {self.poisoned.data}, "
                f"{ours['train']['n_images']} training images; clean run {self.clean.config_path}, "
                f"data {self.clean.data}, {theirs['train']['n_images']} training images)"
            )

    @property
    def views(self) -> list[PoisonView]:
        """The poisoned views, as the run's attack record has them."""
        return self.record.views

    @property
    def cameras(self) -> Any:
        return self.poisoned.pipeline.datamanager.train_dataset.cameras


def _held_out_metrics(run: LoadedRun) -> dict[str, float | None]:
    """nerfstudio's V-test metrics (held-out split) of one run, LPIPS None when unavailable."""
    from nerfstudio.pipelines.base_pipeline import VanillaPipeline

    metrics = VanillaPipeline.get_average_eval_image_metrics(run.pipeline)
    return {k: (float(metrics[k]) if k in metrics else None) for k in ("psnr", "ssim", "lpips")}


def pair_metrics(pair: RunPair, lpips: LazyLPIPS | None = None) -> dict[str, Any]:
    """The report's numbers (see the module docstring); keys documented in docs/evaluation.md."""
    lpips = lpips if lpips is not None else LazyLPIPS()
    ours, naive = {}, {}
    for v in pair.views:
        ours[v.name] = illusion_metrics(render(pair.poisoned, pair.cameras, v.index), v.target, v.mask, lpips)
        naive[v.name] = illusion_metrics(render(pair.clean, pair.cameras, v.index), v.target, v.mask, lpips)
    per_view = {name: {**ours[name], **{f"clean_{k}": x for k, x in naive[name].items()}} for name in ours}
    out: dict[str, Any] = {}
    for (key, value), clean in zip(v_illusory(ours).items(), v_illusory(naive).values(), strict=True):
        out[f"v_illusory_{key}"], out[f"v_illusory_clean_{key}"] = value, clean
    test, test_clean = _held_out_metrics(pair.poisoned), _held_out_metrics(pair.clean)
    for key in ("psnr", "ssim", "lpips"):
        out[f"v_test_{key}"] = test[key]
        out[f"v_test_{key}_clean"] = test_clean[key]
    out["v_test_drop"] = out["v_test_psnr_clean"] - out["v_test_psnr"]
    out["attack_success"] = attack_success(out["v_illusory_psnr"], out["v_test_drop"])
    out["success_thresholds"] = success_verdicts(out["v_illusory_psnr"], out["v_test_drop"])
    out["lpips_unavailable"] = None if lpips.available else lpips.reason
    model = pair.poisoned.model
    out["n_gaussians"] = int(model.num_points)
    out["n_gaussians_clean"] = int(pair.clean.model.num_points)
    out["n_poison_gaussians"] = int(model.poison_mask.sum()) if hasattr(model, "poison_mask") else 0
    out["poisoned_views"] = list(per_view)
    out["v_illusory_per_view"] = per_view
    out["step"], out["step_clean"] = pair.poisoned.step, pair.clean.step
    return out


def compare_runs(poisoned_config: Path, clean_config: Path) -> dict[str, Any]:
    """Load a poisoned and a clean run of the same scene and return :func:`pair_metrics` (no files)."""
    return pair_metrics(RunPair.load(Path(poisoned_config), Path(clean_config)))


def neighbour_curve(pair: RunPair, angles: tuple[float, ...] = NEIGHBOUR_ANGLES) -> dict[str, Any]:
    """PSNR (dB) between the clean and the poisoned render of each poisoned view orbited by ``angles``
    (degrees) about the vertical axis through the scene centre; mean over poisoned views per angle."""
    c2ws = pair.cameras.camera_to_worlds
    center, up = scene_center(c2ws), scene_up(c2ws)
    per_view = {}
    for v in pair.views:
        base = c2ws[v.index].double().numpy()
        values = []
        for angle in angles:
            pose = rotate_pose(base, center, up, angle)
            values.append(
                psnr(
                    render(pair.poisoned, pair.cameras, v.index, pose),
                    render(pair.clean, pair.cameras, v.index, pose),
                )
            )
        per_view[v.name] = values
    mean = [float(np.mean([vals[i] for vals in per_view.values()])) for i in range(len(angles))]
    return {"angles_deg": list(angles), "psnr_mean": mean, "per_view": per_view}


# ---------------------------------------------------------------------------- the report
def figure_grid(path: Path, rows: list[list[tuple[str, np.ndarray]]]) -> Path:
    """A PNG of images in a grid with a title above each (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows, n_cols = len(rows), max(len(r) for r in rows)
    h, w = rows[0][0][1].shape[:2]
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(2.6 * n_cols, 2.6 * n_rows * h / w + 0.4), squeeze=False
    )
    for ax in axes.flat:
        ax.axis("off")
    for r, row in enumerate(rows):
        for c, (title, image) in enumerate(row):
            axes[r][c].imshow(image, interpolation="nearest")
            axes[r][c].set_title(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


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


def save_plot(fig: Any, ax: Any, path: Path, xlabel: str, ylabel: str, title: str) -> None:
    """Label a one-axes matplotlib figure (grid, legend), write it to ``path`` (PNG) and close it."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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


def check_writable(output: Path) -> None:
    """StealthNSError unless the report folder ``output`` (existing or to be created) can be written."""
    if output.exists() and not output.is_dir():
        raise StealthNSError(f"--output {output} is a file, not a folder")
    if (output / "images").exists() and not (output / "images").is_dir():
        raise StealthNSError(f"--output {output}: {output / 'images'} is a file, not a folder")
    existing = output
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise StealthNSError(f"cannot write the report to {output}: {existing} is a file, not a folder")
    try:  # a real write: permissions, read-only file systems, root
        with tempfile.TemporaryDirectory(dir=existing, prefix=".stealth-ns-write-test-"):
            pass
    except OSError as err:
        raise StealthNSError(
            f"cannot write the report to {output}: {err.strerror or err} ({existing})"
        ) from None


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
    poisoned_config: Path, clean_config: Path, output: Path, defend: Path | None = None
) -> dict[str, Any]:
    """Compare the runs and write ``report.json``, ``report.html`` and PNGs into ``output``; with
    ``defend`` (a ``stealth-ns defend`` folder of the poisoned run) also a "Defences" section."""
    output = Path(output)
    check_writable(output)  # before loading two runs (the slow part)
    pair = RunPair.load(Path(poisoned_config), Path(clean_config))
    images = output / "images"
    clear_previous_report(output)
    images.mkdir(parents=True, exist_ok=True)
    report = pair_metrics(pair)
    report["poisoned_run"] = str(pair.poisoned.config_path.resolve())
    report["clean_run"] = str(pair.clean.config_path.resolve())
    report["created"] = _dt.datetime.now().isoformat(timespec="seconds")
    report["defences"] = None
    if defend is not None:
        from stealth_ns.evaluation.defend_outputs import report_section

        report["defences"] = report_section(Path(defend), output, report["poisoned_run"])

    view_rows, view_files = [], {}
    for v in pair.views:
        panels = {
            "target": v.target.numpy(),
            "poisoned": render(pair.poisoned, pair.cameras, v.index),
            "clean": render(pair.clean, pair.cameras, v.index),
            "poison_hidden": render(pair.poisoned, pair.cameras, v.index, render_filter="hide_poison"),
            "mask": np.repeat(v.mask.numpy()[..., None].astype(np.float32), 3, -1),
        }
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
            ]
        )
    figure_grid(output / "poisoned_views.png", view_rows)

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
    (output / "report.json").write_text(json.dumps(report, indent=2))
    (output / "report.html").write_text(render_html(report))
    return report


def summary_lines(report: dict[str, Any], output: Path) -> list[str]:
    """The headline numbers of a report, for the terminal."""
    r = report
    lines = [
        f"V-illusory:  PSNR {_fmt(r['v_illusory_psnr'])} dB, SSIM {_fmt(r['v_illusory_ssim'], 3)}, "
        f"LPIPS {_fmt(r['v_illusory_lpips'], 3)}  (clean run: {_fmt(r['v_illusory_clean_psnr'])} dB)",
        f"V-test PSNR: clean {_fmt(r['v_test_psnr_clean'])} dB, poisoned {_fmt(r['v_test_psnr'])} dB, "
        f"drop {_fmt(r['v_test_drop'])} dB",
        f"attack success: {r['attack_success']}  (V-illusory > 25 dB and drop <= 3 dB); "
        + ", ".join(f"{k}: {v}" for k, v in r["success_thresholds"].items() if k != "25/3"),
    ]
    if r.get("lpips_unavailable"):
        lines.append(f"LPIPS unavailable: {r['lpips_unavailable']}")
    lines.append(f"report: {Path(output).resolve() / 'report.html'}")
    return lines


# ---------------------------------------------------------------------------- HTML
def _fmt(value: Any, digits: int = 2) -> str:
    """A table cell or inline number: ``–`` for a missing value, yes/no, floats to ``digits``."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def render_html(report: dict[str, Any]) -> str:
    """``report.html``: ``templates/report.html.j2`` filled from the report (autoescaped; inline CSS,
    images referenced relative to the report folder)."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("stealth_ns.evaluation", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["fmt"] = _fmt
    env.filters["fmt_angle"] = lambda angle: f"{angle:g}"
    env.filters["threshold_row"] = lambda item: [*item[0].split("/"), item[1]]
    return env.get_template("report.html.j2").render(r=report)


def _listing(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]
