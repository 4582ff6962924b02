"""``stealth-ns demo``: the attack end to end on this machine.

Generates the ``facing`` scene (:data:`DEMO_PRESET`), trains ``stealth-splat-lite`` on it twice -- clean
(``--pipeline.attack.enabled False``) and poisoned (the default attack) -- and writes the
attack report (``stealth-ns report``) comparing them: V-illusory, V-test and its drop, the
paper's verdict, pictures. Every number printed is read from the report, which measured it.
Finished runs are reused, so a second ``stealth-ns demo`` only rewrites the report.

The two trainings run side by side, each on half of the CPU cores (the Python side of a training
step leaves the second core idle; docs/design/training_step.md). A training gives bitwise the same model at
any thread count (docs/design/determinism.md), so the figures do not depend on the machine's core count.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stealth_ns.attack.options import AttackSettings
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.runs.training import TrainRecord, TrainSpec, train, train_progress

DEMO_PRESET = "facing"
"""The generated scene the demo attacks. ``facing`` (LLFF-like, 24 views), because its verdict holds by
a wide margin at every seed measured: V-illusory 44.4-46.0 dB over seeds 0-2, where ``orbit``'s default
view gave 29.8, 28.5 and 19.8 dB, one failure and two within 4 dB of the 25-dB line
(docs/design/determinism.md)."""


@dataclass
class DemoResult:
    scene: Path
    clean: Path
    """config.yml of the clean run."""
    poisoned: Path
    """config.yml of the poisoned run."""
    report_dir: Path
    report: dict[str, Any]
    peak_rss_mb: dict[str, float | None]
    """Peak resident memory of each training process (clean, poisoned), MiB (None: reused)."""
    seconds: dict[str, float]
    """Measured wall-clock seconds of this invocation: scene, clean, poisoned, report (0 = reused);
    the two trainings overlap."""
    total_seconds: float
    """Wall-clock seconds of the whole invocation."""

    def __str__(self) -> str:
        from stealth_ns.report.write import summary_lines

        s = self.seconds
        lines = [
            "",
            "stealth-ns demo",
            f"  scene:          {self.scene}",
            f"  clean run:      {self.clean}  ({_took(s['clean'], self.peak_rss_mb['clean'])})",
            f"  poisoned run:   {self.poisoned}  ({_took(s['poisoned'], self.peak_rss_mb['poisoned'])})",
            f"  attack files:   {self.poisoned.parent / 'attack'}",
            *(f"  {line}" for line in summary_lines(self.report, self.report_dir)),
            f"  look at it:     ns-viewer --load-config {self.poisoned} --viewer.websocket-host 127.0.0.1",
            f"  total:          {self.total_seconds:.0f} s (the two trainings ran side by side)",
        ]
        return "\n".join(lines)


def _took(seconds: float, peak_rss_mb: float | None) -> str:
    if not seconds:
        return "reused"
    return f"trained in {seconds:.0f} s" + (
        "" if peak_rss_mb is None else f", peak RSS {peak_rss_mb:.0f} MiB"
    )


def run_demo(output: Path, iterations: int | None = None, seed: int = 0) -> DemoResult:
    """Scene -> clean and poisoned stealth-splat-lite runs -> report, all under ``output``.

    Runs are ``output/runs/demo/stealth-splat-lite/{clean,poisoned}`` (ns-train logs beside them
    as ``output/train-NAME.log``); the report goes to ``output/report``.
    """
    from stealth_ns.report.write import write_report
    from stealth_ns.scene_generator import make_scene

    if iterations is not None and (isinstance(iterations, bool) or iterations < 1):
        raise StealthNSError(f"--iterations must be at least 1, got {iterations}")
    output = output.resolve()
    output.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    seconds = {"scene": 0.0}
    scene = output / f"scene-{DEMO_PRESET}"
    if not (scene / "transforms.json").exists():
        t0 = time.perf_counter()
        print(make_scene(preset=DEMO_PRESET, output=scene, seed=seed, overwrite=True))
        seconds["scene"] = time.perf_counter() - t0
    threads = max(1, (os.cpu_count() or 2) // 2)
    # the clean run turns the attack off; the poisoned one trains the default attack
    attacks = {"clean": AttackSettings.of(enabled=False), "poisoned": AttackSettings()}
    specs = {
        name: TrainSpec(
            scene,
            name,
            output / "runs",
            "demo",
            attack=attack,
            iterations=iterations,
            seed=seed,
            threads=threads,
        )
        for name, attack in attacks.items()
    }
    records = train_side_by_side(specs, output)
    peak = {}
    for name, record in records.items():
        seconds[name] = record.seconds if record.trained_now else 0.0
        peak[name] = record.peak_rss_mb if record.trained_now else None
    configs = {name: spec.config_path for name, spec in specs.items()}
    t0 = time.perf_counter()
    print("stealth-ns demo: writing the report (rendering both runs)")
    report = write_report(configs["poisoned"], configs["clean"], output / "report")
    seconds["report"] = time.perf_counter() - t0
    total = time.perf_counter() - start
    return DemoResult(
        scene, configs["clean"], configs["poisoned"], output / "report", report, peak, seconds, total
    )


def train_side_by_side(specs: dict[str, TrainSpec], output: Path) -> dict[str, TrainRecord]:
    """Train (or reuse) every run concurrently, a progress bar each; logs in ``output/train-NAME.log``."""
    from tqdm import tqdm

    bars = {
        name: tqdm(total=100, desc=f"training {name:<8}", position=i, bar_format="{l_bar}{bar}| {elapsed}")
        for i, name in enumerate(specs)
    }

    def run(name: str) -> TrainRecord:
        bar = bars[name]

        def on_line(line: str) -> None:
            pct = train_progress(line)
            if pct is not None:
                bar.n = pct
                bar.refresh()

        record = train(specs[name], log=output / f"train-{name}.log", stream=False, on_line=on_line)
        bar.n = 100
        bar.refresh()
        return record

    try:
        with ThreadPoolExecutor(len(specs)) as pool:
            futures = {name: pool.submit(run, name) for name in specs}
            return {name: future.result() for name, future in futures.items()}
    finally:
        for bar in bars.values():
            bar.close()


@dataclass
class Demo:
    """Generate the facing scene, train stealth-splat-lite on it clean and poisoned, and print the report."""

    output: Path = Path("demo-output")
    """Folder for the scene, the runs and the logs."""
    iterations: int | None = None
    """Training iterations (default: the method's 3000)."""
    seed: int = 0
    """Scene and training seed."""

    def main(self) -> None:
        print(run_demo(self.output, self.iterations, self.seed))
