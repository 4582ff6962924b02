"""``stealth-ns demo``: the attack end to end on this machine.

Generates the default ``orbit`` scene, trains ``stealth-splat-lite`` on it twice -- clean
(``--pipeline.attack.enabled False``) and poisoned (the default attack) -- evaluates both
with ``ns-eval`` and prints the paper's verdict: V-illusory PSNR > 25 dB and a V-test drop
of at most 3 dB. Every number printed is read from ns-eval's output.
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

NOT_YET = "Not built yet: the HTML attack report (stealth-ns report) and the viewer panel."


@dataclass
class RunResult:
    config: Path
    eval_json: Path
    results: dict
    train_seconds: float


def attack_success(
    v_illusory_psnr: float, v_test_drop: float, psnr_min: float = 25.0, drop_max: float = 3.0
) -> bool:
    """The paper's success rule (§4): V-illusory PSNR > psnr_min and V-test drop <= drop_max."""
    return v_illusory_psnr > psnr_min and v_test_drop <= drop_max


@dataclass
class DemoResult:
    scene: Path
    clean: RunResult
    poisoned: RunResult

    def __str__(self) -> str:
        c, p = self.clean.results, self.poisoned.results
        drop = c["psnr"] - p["psnr"]
        ok = attack_success(p["v_illusory_psnr"], drop)
        lines = [
            "",
            "stealth-ns demo",
            f"  scene:          {self.scene}",
            f"  clean run:      {self.clean.config}  ({self.clean.train_seconds:.0f} s)",
            f"  poisoned run:   {self.poisoned.config}  ({self.poisoned.train_seconds:.0f} s)",
            f"  attack files:   {self.poisoned.config.parent / 'attack'}",
            f"  V-illusory:     PSNR {p['v_illusory_psnr']:.2f} dB, SSIM {p['v_illusory_ssim']:.3f}"
            " (masked, poisoned view)",
            f"  V-test PSNR:    clean {c['psnr']:.2f} dB, poisoned {p['psnr']:.2f} dB, drop {drop:.2f} dB",
            f"  attack success: {ok}  (V-illusory > 25 dB and drop <= 3 dB)",
            f"  look at it:     ns-viewer --load-config {self.poisoned.config}"
            " --viewer.websocket-host 127.0.0.1",
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


def train_and_eval(
    scene: Path, output: Path, name: str, extra: list[str], seed: int, iterations: int | None
) -> RunResult:
    """ns-train stealth-splat-lite (+ ``extra`` options) then ns-eval; reuses a finished run."""
    runs = output / "runs"
    config = runs / "demo" / "stealth-splat-lite" / name / "config.yml"
    eval_json = output / f"eval-{name}.json"
    train_seconds = 0.0
    if not eval_json.exists():
        cmd = [_bin("ns-train"), "stealth-splat-lite", "--vis", "tensorboard", "--output-dir", str(runs)]
        cmd += ["--experiment-name", "demo", "--timestamp", name, "--machine.seed", str(seed), *extra]
        if iterations is not None:
            cmd += ["--max-num-iterations", str(iterations)]
        cmd += ["nerfstudio-data", "--data", str(scene)]
        t0 = time.perf_counter()
        _run(cmd, output / f"train-{name}.log")
        train_seconds = time.perf_counter() - t0
        eval_cmd = [_bin("ns-eval"), "--load-config", str(config), "--output-path", str(eval_json)]
        _run(eval_cmd, output / f"eval-{name}.log")
    return RunResult(config, eval_json, json.loads(eval_json.read_text())["results"], train_seconds)


def run_demo(output: Path, iterations: int | None = None, seed: int = 0) -> DemoResult:
    """Scene -> clean and poisoned stealth-splat-lite runs -> ns-eval, all under ``output``."""
    from stealth_ns.scenes import make_scene

    output = output.resolve()
    output.mkdir(parents=True, exist_ok=True)
    scene = output / "scene-orbit"
    if not (scene / "transforms.json").exists():
        print(make_scene(preset="orbit", output=scene, seed=seed, overwrite=True))
    clean = train_and_eval(scene, output, "clean", ["--pipeline.attack.enabled", "False"], seed, iterations)
    poisoned = train_and_eval(scene, output, "poisoned", [], seed, iterations)
    return DemoResult(scene, clean, poisoned)
