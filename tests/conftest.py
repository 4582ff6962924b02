"""Shared fixtures: console scripts of this venv and small generated scenes (built once per session;
under pytest-xdist, once for all of the session's workers)."""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import subprocess
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock

BIN = Path(sys.executable).parent


#: ``stealth-ns`` commands that :func:`run_cli` runs in the test's own process, where torch, nerfstudio
#: and stealth-ns are imported already (a fresh console script imports them first:
#: docs/design/testing.md). The console script itself runs as a user runs it in tests/test_cli.py and in
#: one test of each of these commands (``in_process=False``); the benchmarks (threads, allocator settings,
#: Ray) run in their own.
IN_PROCESS_COMMANDS = ("report", "defend", "scan", "poison-dataset")


def run_cli(
    *args: str, timeout: float = 600, check: bool = True, in_process: bool | None = None
) -> subprocess.CompletedProcess:
    """Run one of the venv's console scripts (``stealth-ns``, ``ns-train``, ...) and capture its output.
    ``in_process`` (default: for :data:`IN_PROCESS_COMMANDS`) runs ``stealth-ns`` here instead, with its
    exit status, stdout and stderr as the console script gives them (``timeout`` does not apply)."""
    if in_process is None:
        in_process = args[0] == "stealth-ns" and len(args) > 1 and args[1] in IN_PROCESS_COMMANDS
    if in_process:
        assert args[0] == "stealth-ns", f"only stealth-ns runs in the test's process, not {args[0]}"
        proc = _run_here(list(args[1:]))
    else:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        proc = subprocess.run(
            [str(BIN / args[0]), *args[1:]], capture_output=True, text=True, timeout=timeout, env=env
        )
    if check and proc.returncode != 0:
        raise AssertionError(
            f"{' '.join(args)} exited {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


def _run_here(argv: list[str]) -> subprocess.CompletedProcess:
    """``stealth-ns ARGV`` as :func:`stealth_ns.cli.entrypoint` runs it, in this process: an exception
    the console script would show as a traceback goes to the captured stderr, exit status 1."""
    from stealth_ns import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = cli.run(argv)
        except SystemExit as exit_:  # tyro's --help and option errors
            code = exit_.code
            if code is not None and not isinstance(code, int):
                print(code, file=sys.stderr)
            status = code if isinstance(code, int) else int(code is not None)
        except Exception:
            traceback.print_exc()
            status = 1
    return subprocess.CompletedProcess(["stealth-ns", *argv], status, out.getvalue(), err.getvalue())


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process(proc: subprocess.Popen, timeout: float = 15) -> None:
    """Terminate ``proc`` and wait for it; kill it when it has not stopped within ``timeout`` seconds."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=timeout)


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``name`` filled by ``build(folder)`` once per test session. Under pytest-xdist the
    workers share it: the first to ask builds it under a file lock, the others wait and reuse it (the
    shared folder's users must only read it)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the session's folder, above each worker's own
    out = base / f"shared-{name}"
    done = out / ".built"
    with FileLock(f"{out}.lock"):
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir(parents=True)
            build(out)
            done.touch()
    return out


@pytest.fixture(scope="session")
def tiny_orbit_scene(tmp_path_factory) -> Path:
    """16 views at 64x48 of the orbit preset (2 held out)."""
    from stealth_ns.scene_generator import make_scene

    def build(folder: Path) -> None:
        make_scene(preset="orbit", output=folder / "orbit_tiny", resolution="64x48", views=16, seed=0)

    return built_once(tmp_path_factory, "scenes", build) / "orbit_tiny"


def tiny_config(out: Path, name: str) -> Path:
    """The config.yml that :func:`train_tiny` writes for run ``name`` under ``out``."""
    return out / "tiny" / "stealth-splat-lite" / name / "config.yml"


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
    return tiny_config(out, name)


@pytest.fixture(scope="session")
def tiny_run_pair(tiny_orbit_scene, tmp_path_factory) -> tuple[Path, Path]:
    """(poisoned, clean) config.yml of two 60-iteration runs on ``tiny_orbit_scene``."""

    def build(out: Path) -> None:
        train_tiny(tiny_orbit_scene, out, "poisoned", "--pipeline.attack.injection-step", "20")
        train_tiny(tiny_orbit_scene, out, "clean", "--pipeline.attack.enabled", "False")

    out = built_once(tmp_path_factory, "runs", build)
    return tiny_config(out, "poisoned"), tiny_config(out, "clean")


@pytest.fixture(scope="session")
def tiny_poisoned_run(tiny_orbit_scene, tmp_path_factory) -> Path:
    """config.yml of a poisoned run of ``tiny_orbit_scene`` trained long enough (300 steps) for its
    illusion to show: the scan names its poisoned view."""

    def build(out: Path) -> None:
        train_tiny(
            tiny_orbit_scene, out, "poisoned", "--pipeline.attack.injection-step", "20", iterations=300
        )

    return tiny_config(built_once(tmp_path_factory, "poisoned-300", build), "poisoned")


#: Files in the report folder before ``tiny_report`` runs: pictures of an earlier report (removed) and
#: the user's own files (kept).
STALE_REPORT_FILES = ("images/view9999_target.png", "images/heldout999_gt.png")
USER_REPORT_FILES = ("notes.txt", "images/my_picture.png", "report.json.bak")


@pytest.fixture(scope="session")
def tiny_report(tiny_run_pair, tmp_path_factory) -> tuple[Path, str]:
    """(folder, stdout) of ``stealth-ns report`` on ``tiny_run_pair``, written into a folder that already
    held :data:`STALE_REPORT_FILES` and :data:`USER_REPORT_FILES` (each holding "x")."""
    poisoned, clean = tiny_run_pair

    def build(folder: Path) -> None:
        out = folder / "report"
        for name in STALE_REPORT_FILES + USER_REPORT_FILES:
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            (out / name).write_text("x")
        proc = run_cli("stealth-ns", "report", "--poisoned", str(poisoned), "--clean", str(clean),
                       "--output", str(out), in_process=False)  # fmt: skip
        (folder / "stdout.txt").write_text(proc.stdout)

    folder = built_once(tmp_path_factory, "report", build)
    return folder / "report", (folder / "stdout.txt").read_text()
