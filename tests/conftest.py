"""Shared fixtures: console scripts of this venv and small generated scenes (built once per session)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent


def run_cli(*args: str, timeout: float = 600, check: bool = True) -> subprocess.CompletedProcess:
    """Run one of the venv's console scripts (``stealth-ns``, ``ns-train``, ...) and capture its output."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run(
        [str(BIN / args[0]), *args[1:]], capture_output=True, text=True, timeout=timeout, env=env
    )
    if check and proc.returncode != 0:
        raise AssertionError(
            f"{' '.join(args)} exited {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


@pytest.fixture(scope="session")
def tiny_orbit_scene(tmp_path_factory) -> Path:
    """16 views at 64x48 of the orbit preset (2 held out)."""
    out = tmp_path_factory.mktemp("scenes") / "orbit_tiny"
    from stealth_ns.scenes import make_scene

    make_scene(preset="orbit", output=out, resolution="64x48", views=16, seed=0)
    return out


def train_tiny(
    scene: Path, out: Path, name: str, *extra: str, iterations: int = 60, vis: str = "tensorboard"
) -> Path:
    """ns-train stealth-splat-lite on a tiny scene (CPU, a few minutes at most); returns its config.yml."""
    proc = run_cli(
        "ns-train", "stealth-splat-lite", "--vis", vis, "--output-dir", str(out),
        "--experiment-name", "tiny", "--timestamp", name, "--max-num-iterations", str(iterations),
        "--steps-per-eval-all-images", "100000", "--machine.seed", "0", *extra,
        "nerfstudio-data", "--data", str(scene),
    )  # fmt: skip
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return out / "tiny" / "stealth-splat-lite" / name / "config.yml"


@pytest.fixture(scope="session")
def tiny_run_pair(tiny_orbit_scene, tmp_path_factory) -> tuple[Path, Path]:
    """(poisoned, clean) config.yml of two 60-iteration runs on ``tiny_orbit_scene``."""
    out = tmp_path_factory.mktemp("runs")
    poisoned = train_tiny(tiny_orbit_scene, out, "poisoned", "--pipeline.attack.injection-step", "20")
    clean = train_tiny(tiny_orbit_scene, out, "clean", "--pipeline.attack.enabled", "False")
    return poisoned, clean
