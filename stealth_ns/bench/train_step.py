"""``stealth-ns bench train``: where the time of a training step goes.

Trains a method (default ``stealth-splat-lite`` with the attack on, as ``ns-train`` runs it) on a
scene (default: the generated ``orbit`` scene, seed 0) in this process with nerfstudio's own
``Trainer``, and times every step after ``warmup`` steps, split into phases:

==========================  ===========================================================
data                        the datamanager's ``next_train`` (image, attack target, noise)
projection+SH               EWA projection and SH colours (forward)
tile sort                   tile intersection and depth sort
rasterize forward           the rasterize-to-pixels kernel (forward); with gsplat (CUDA) its
                            whole rasterization: projection, tile sort and kernel
forward: other              the rest of the model's ``get_outputs`` (activations, background)
loss                        the model's loss and metrics dicts (L1 + SSIM, PSNR)
pipeline: other             the rest of the pipeline's ``get_train_loss_dict``
backward: rasterize         the rasterize-to-pixels backward kernel
backward: projection+SH     the compiled projection and SH backward kernels
backward: other             the rest of ``loss.backward()`` (loss and SSIM, activations; with
                            gsplat all of its backward)
optimizer                   the optimizers' and schedulers' steps
densification               gsplat's strategy before and after the backward pass
callbacks/logging           everything else of the step: the other training callbacks (the
                            attack's), nerfstudio's writer, evaluation images, checkpoints
==========================  ===========================================================

The phases add up to the step's wall-clock time (``step``). Each figure is the median over the
timed steps (the mean is kept beside it: evaluation and checkpoint steps are rare but long).
On CUDA every phase waits for the GPU at both ends (``StepTimer.sync``), so each is charged its own
kernels and the steps lose the overlap of CPU and GPU work they have in ``ns-train``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import resource
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.step_timing import TIMER, StepTimer

#: Leaf phases in the order printed; they add up to the step.
PHASES = (
    "data",
    "projection+SH",
    "tile sort",
    "rasterize forward",
    "forward: other",
    "loss",
    "pipeline: other",
    "backward: rasterize",
    "backward: projection+SH",
    "backward: other",
    "optimizer",
    "densification",
    "callbacks/logging",
)


def leaf_phases(raw: dict[str, float]) -> dict[str, float]:
    """One step's raw timings (seconds; nested: ``forward`` holds the renderer's phases) -> the
    :data:`PHASES`, which do not overlap and add up to ``raw["step"]``."""

    def get(name: str) -> float:
        return raw.get(name, 0.0)

    backward = get("train iteration") - get("loss dict") - get("optimizer")
    return {
        "data": get("data"),
        "projection+SH": get("projection+SH"),
        "tile sort": get("tile sort"),
        "rasterize forward": get("rasterize forward"),
        "forward: other": get("forward")
        - get("projection+SH")
        - get("tile sort")
        - get("rasterize forward")
        - get("densification: pre"),
        "loss": get("loss"),
        "pipeline: other": get("loss dict") - get("data") - get("forward") - get("loss"),
        "backward: rasterize": get("backward: rasterize"),
        "backward: projection+SH": get("backward: projection+SH"),
        "backward: other": backward - get("backward: rasterize") - get("backward: projection+SH"),
        "optimizer": get("optimizer"),
        "densification": get("densification: pre") + get("densification: post"),
        "callbacks/logging": get("step") - get("train iteration") - get("densification: post"),
    }


@dataclass
class TrainBenchResult:
    """What ``stealth-ns bench train`` measured (milliseconds unless named otherwise)."""

    scene: str
    method: str
    backend: str
    threads: int
    warmup: int
    steps: int
    median_step_ms: float
    mean_step_ms: float
    phases_ms: dict[str, float]
    """Median over the timed steps of each phase."""
    phases_mean_ms: dict[str, float]
    gaussians: int
    """Median number of Gaussians over the timed steps."""
    pairs: int
    """Median number of (Gaussian, tile) pairs the training render sorted and blended."""
    peak_rss_mb: float
    """Peak resident memory of this process (setup and training), MiB."""
    rss_growth_mb: float
    """Resident memory at the end of the timed steps minus at their start, MiB."""
    seconds: float
    step_ms: list[float] = field(repr=False)

    def table(self) -> str:
        lines = [
            f"stealth-ns bench train: {self.method} on {self.scene}, backend {self.backend}, "
            f"{self.threads} thread(s); {self.steps} steps timed after {self.warmup}",
            f"  median step {self.median_step_ms:.1f} ms (mean {self.mean_step_ms:.1f} ms, "
            f"{sum(self.step_ms) / 1000:.1f} s in all); {self.gaussians} Gaussians, {self.pairs} tile pairs"
            + ("; CUDA synchronised at each phase's ends" if self.backend == "gsplat" else ""),
            f"  {'phase':<25}{'median ms':>11}{'mean ms':>10}{'share':>8}",
        ]
        total = sum(self.phases_mean_ms.values()) or 1.0
        for name in PHASES:
            mean = self.phases_mean_ms[name]
            lines.append(f"  {name:<25}{self.phases_ms[name]:>11.2f}{mean:>10.2f}{mean / total:>8.1%}")
        lines.append(
            f"  peak RSS {self.peak_rss_mb:.0f} MiB; "
            f"RSS change over the timed steps {self.rss_growth_mb:+.0f} MiB"
        )
        return "\n".join(lines)


def _rss_mb() -> float:
    """Current resident memory of this process, MiB (Linux /proc; 0 where it cannot be read)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):
        return 0.0
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def _instrument(trainer: Any, timer: StepTimer) -> None:
    """Time the phases of ``trainer``'s steps into ``timer`` (instance attributes wrap the methods)."""
    pipeline, model = trainer.pipeline, trainer.pipeline.model
    datamanager, strategy, optimizers = pipeline.datamanager, model.strategy, trainer.optimizers
    datamanager.next_train = timer.wrap("data", datamanager.next_train)
    model.get_loss_dict = timer.wrap("loss", model.get_loss_dict)
    model.get_metrics_dict = timer.wrap("loss", model.get_metrics_dict)
    pipeline.get_train_loss_dict = timer.wrap("loss dict", pipeline.get_train_loss_dict)
    strategy.step_pre_backward = timer.wrap("densification: pre", strategy.step_pre_backward)
    strategy.step_post_backward = timer.wrap("densification: post", strategy.step_post_backward)
    optimizers.optimizer_scaler_step_some = timer.wrap("optimizer", optimizers.optimizer_scaler_step_some)
    optimizers.scheduler_step_all = timer.wrap("optimizer", optimizers.scheduler_step_all)
    trainer.train_iteration = timer.wrap("train iteration", trainer.train_iteration)
    trainer.eval_iteration = timer.excluded(trainer.eval_iteration)  # its renders are not training phases

    get_outputs = model.get_outputs

    def forward(camera: Any) -> Any:
        with timer.phase("forward"):
            outputs = get_outputs(camera)
        if model.training:
            ids = getattr(model, "info", {}).get("flatten_ids")
            timer.current["gaussians"] = float(model.num_points)
            timer.current["pairs"] = float(ids.numel()) if ids is not None else 0.0
        return outputs

    model.get_outputs = forward


class _StepBoundaries:
    """A before-iteration callback: closes the previous step (its wall-clock time as ``step``), switches
    the timer on for the ``steps`` steps after ``warmup`` and notes the RSS at both ends of them."""

    def __init__(self, timer: StepTimer, warmup: int, steps: int, bar: Any) -> None:
        self.timer, self.warmup, self.steps, self.bar = timer, warmup, steps, bar
        self.last = timer.now()
        self.rss: dict[str, float] = {}

    def __call__(self, step: int) -> None:
        timer = self.timer
        if timer.active:
            timer.current["step"] = timer.now() - self.last
            timer.end_step()
        timer.current = {}
        timer.active = self.warmup <= step < self.warmup + self.steps
        if step == self.warmup:
            self.rss["start"] = _rss_mb()
        if step == self.warmup + self.steps:
            self.rss["end"] = _rss_mb()
        self.last = timer.now()
        self.bar.update(1)


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else 0.0


def summarise(steps: list[dict[str, float]]) -> tuple[dict[str, float], dict[str, float], list[float]]:
    """Per-step raw timings -> (median ms per phase, mean ms per phase, step ms)."""
    leaves = [leaf_phases(s) for s in steps]
    median = {name: 1000 * _median([leaf[name] for leaf in leaves]) for name in PHASES}
    mean = {name: 1000 * statistics.fmean([leaf[name] for leaf in leaves]) for name in PHASES}
    return median, mean, [1000 * s["step"] for s in steps]


def _bench_config(data: Path, output: Path, method: str, seed: int, iterations: int, attack: bool) -> Any:
    from stealth_ns.attack.config import AttackConfig
    from stealth_ns.poisoned_datasets.dataset_copy import open_source
    from stealth_ns.poisoned_datasets.setup import trainer_config

    config = trainer_config(open_source(data), AttackConfig(enabled=attack), method, seed)
    config.max_num_iterations = iterations
    config.output_dir = output
    config.experiment_name, config.timestamp = "bench-train", "run"
    config.logging.local_writer.enable = False  # the progress bar instead of nerfstudio's table
    return config


def _with_seed_points(data: Path, output: Path) -> Path:
    """``data``, or for a folder without seed points (a Blender scene such as the ``object`` preset) its
    copy with points triangulated from its images and poses, made as ``bench attack`` makes it."""
    from stealth_ns.datasets.seeded import ensure_seed_points
    from stealth_ns.datasets.source import inspect_folder

    source = inspect_folder(data.name, str(data))
    if not source.triangulated:
        return data
    return Path(ensure_seed_points(output, source)["dataset"])


def _close_event_writers() -> None:
    """Close nerfstudio's TensorBoard writers (module-global, never closed by the trainer) and forget
    them. Their background thread flushes the event file after training returns: removing the run
    folder under it failed once in CI with "Directory not empty" (the event file reappeared)."""
    from nerfstudio.utils import writer

    for event_writer in writer.EVENT_WRITERS:
        summary = getattr(event_writer, "tb_writer", None)
        if summary is not None:
            summary.close()
    writer.EVENT_WRITERS.clear()


def run_train_benchmark(
    data: Path | None = None,
    method: str = "stealth-splat-lite",
    warmup: int = 1000,
    steps: int = 200,
    seed: int = 0,
    threads: int | None = None,
    json_path: Path | None = None,
    preset: str = "orbit",
    resolution: str | None = None,
    attack: bool = True,
) -> TrainBenchResult:
    """Train ``method`` on ``data`` (None: the generated scene ``preset`` at ``resolution``, its default
    when None) with its default attack (``attack`` False: the clean run) and time ``steps`` steps after
    ``warmup``; prints progress, returns (and writes as JSON) the measurements."""
    from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackLocation
    from tqdm import tqdm

    if warmup < 0 or steps < 1:
        raise StealthNSError(f"--warmup must be >= 0 and --steps >= 1 (got {warmup} and {steps})")
    if threads is not None:
        if threads < 1:
            raise StealthNSError(f"--threads must be at least 1, got {threads}")
        torch.set_num_threads(threads)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="stealth-ns-bench-train-") as tmp:
        if data is None:
            from stealth_ns.scene_generator import make_scene

            data = Path(tmp) / preset
            made = make_scene(preset=preset, output=data, seed=seed, resolution=resolution)
            scene = f"generated {preset} {made.width}x{made.height} (seed {seed})"
        else:
            scene = str(data)
        data = _with_seed_points(data, Path(tmp) / "seeded")
        scene += "" if attack else ", clean run"
        from stealth_ns.poisoned_datasets.setup import setup_trainer

        config = _bench_config(data, Path(tmp) / "runs", method, seed, warmup + steps + 1, attack)
        trainer = setup_trainer(config)
        _instrument(trainer, TIMER)
        TIMER.steps = []
        on_cuda = trainer.pipeline.model.device.type == "cuda"
        TIMER.sync = torch.cuda.synchronize if on_cuda else None
        with tqdm(total=config.max_num_iterations, desc="bench train", unit="step") as bar:
            boundaries = _StepBoundaries(TIMER, warmup, steps, bar)
            trainer.callbacks.insert(
                0, TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], boundaries)
            )
            try:
                trainer.train()
            finally:
                TIMER.active, TIMER.sync = False, None
                _close_event_writers()  # before the temporary folder is removed under them
        model = trainer.pipeline.model
        backend = model.rasterizer_backend
    timed = TIMER.steps[:steps]
    if len(timed) < steps:
        raise StealthNSError(f"bench train: only {len(timed)} of {steps} steps were timed")
    median, mean, step_ms = summarise(timed)
    rss = boundaries.rss
    result = TrainBenchResult(
        scene=scene,
        method=method,
        backend=backend,
        threads=torch.get_num_threads(),
        warmup=warmup,
        steps=steps,
        median_step_ms=_median(step_ms),
        mean_step_ms=statistics.fmean(step_ms),
        phases_ms=median,
        phases_mean_ms=mean,
        gaussians=int(_median([s.get("gaussians", 0.0) for s in timed])),
        pairs=int(_median([s.get("pairs", 0.0) for s in timed])),
        peak_rss_mb=_peak_rss_mb(),
        rss_growth_mb=rss.get("end", 0.0) - rss.get("start", 0.0),
        seconds=time.perf_counter() - t0,
        step_ms=step_ms,
    )
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(dataclasses.asdict(result), indent=2) + "\n", encoding="utf-8")
    return result
