"""``stealth-ns demo``: what the project can do today, end to end, on this machine.

Generates the default ``orbit`` scene, trains ``stealth-splat-lite`` on it (CPU unless CUDA
is present), evaluates the held-out views with ``ns-eval`` and prints where everything is
and the measured numbers. It says plainly which parts of the attack are not built yet.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from stealth_ns.errors import StealthNSError

NOT_YET = (
    "Not implemented yet: the StealthAttack itself (illusion targets, density-guided poison "
    "Gaussians, view-consistency noise) and the attack report. This demo trains and evaluates "
    "the clean CPU/CUDA splatting model that the attack will live in."
)


@dataclass
class DemoResult:
    scene: Path
    config: Path
    eval_json: Path
    results: dict
    train_seconds: float

    def __str__(self) -> str:
        r = self.results
        lines = [
            "",
            "stealth-ns demo",
            f"  scene:        {self.scene}",
            f"  trained run:  {self.config}",
            f"  evaluation:   {self.eval_json}",
            f"  training:     {self.train_seconds:.0f} s",
            f"  held-out PSNR {r['psnr']:.2f} dB, SSIM {r['ssim']:.3f}"
            + (f", LPIPS {r['lpips']:.3f}" if "lpips" in r else " (LPIPS unavailable offline)"),
            f"  look at it:   ns-viewer --load-config {self.config} --viewer.websocket-host 127.0.0.1",
            "",
            NOT_YET,
        ]
        return "\n".join(lines)


def _bin(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def _run(cmd: list[str], log: Path) -> None:
    """Run a console script, streaming its output to the terminal and to ``log``."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with log.open("w") as fh:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        assert proc.stdout is not None
        for line in proc.stdout:
            sys.stdout.write(line)
            fh.write(line)
        if proc.wait() != 0:
            raise StealthNSError(f"{Path(cmd[0]).name} failed (exit {proc.returncode}); see {log}")


def run_demo(output: Path, iterations: int | None = None, seed: int = 0) -> DemoResult:
    """Scene -> ns-train stealth-splat-lite -> ns-eval, all under ``output``."""
    from stealth_ns.scenes import make_scene

    output = output.resolve()
    scene = output / "scene-orbit"
    if not (scene / "transforms.json").exists():
        print(make_scene(preset="orbit", output=scene, seed=seed, overwrite=True))
    runs = output / "runs"
    cmd = [
        _bin("ns-train"),
        "stealth-splat-lite",
        "--vis",
        "tensorboard",
        "--output-dir",
        str(runs),
        "--experiment-name",
        "demo",
        "--timestamp",
        "clean",
        "--machine.seed",
        str(seed),
    ]
    if iterations is not None:
        cmd += ["--max-num-iterations", str(iterations)]
    cmd += ["nerfstudio-data", "--data", str(scene)]
    t0 = time.perf_counter()
    _run(cmd, output / "train.log")
    train_seconds = time.perf_counter() - t0
    config = runs / "demo" / "stealth-splat-lite" / "clean" / "config.yml"
    eval_json = output / "eval-clean.json"
    eval_cmd = [_bin("ns-eval"), "--load-config", str(config), "--output-path", str(eval_json)]
    _run(eval_cmd, output / "eval.log")
    results = json.loads(eval_json.read_text())["results"]
    return DemoResult(scene, config, eval_json, results, train_seconds)
