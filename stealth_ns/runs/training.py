"""Training runs on disk: one ``ns-train`` run per :class:`TrainSpec`, reused once finished.

A run lives where nerfstudio puts it, ``OUTPUT_DIR/EXPERIMENT/METHOD/NAME`` (``--output-dir``,
``--experiment-name``, ``--timestamp``). It counts as *finished* only when all of these hold:

* ``ns-train`` exited 0 and :func:`train` then wrote the marker file :data:`MARKER`;
* the final checkpoint ``nerfstudio_models/step-{N-1}.ckpt`` named in the marker exists
  (``ns-train`` exits 0 after Ctrl-C too, without it);
* the marker records the same method, scene, options (:attr:`TrainSpec.options`), dataparser (when not
  plain ``nerfstudio-data``) and seed as the spec (and the same iteration count when the spec sets one).

Anything else found in the run folder -- an interrupted run, or one trained with other settings
under the same name -- is deleted by :func:`train` before it trains again.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from stealth_ns.attack.normal_draw import NOISE_GENERATOR
from stealth_ns.attack.options import NS_TRAIN, AttackSettings, command_options, draws_view_noise
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.method_configs.registry import METHODS

#: Written into the run folder after a successful ``ns-train``; its presence (with the final
#: checkpoint) is what "finished" means.
MARKER = "stealth-ns-finished.json"
#: Default log of ``ns-train`` inside the run folder.
TRAIN_LOG = "ns-train.log"

RunStatus = Literal["finished", "partial", "missing"]


def bin_path(name: str) -> str:
    """Path of a console script (``ns-train``, ``ns-eval``) of the running Python environment."""
    return str(Path(sys.executable).parent / name)


#: ns-train's progress lines: "STEP (PERCENT%)".
_PROGRESS = re.compile(r"(\d+) \((\d+(?:\.\d+)?)%\)")


def train_progress(line: str) -> float | None:
    """The percentage done in one line of ns-train's output, or None for other lines."""
    match = _PROGRESS.search(line)
    return float(match.group(2)) if match else None


def run_command(
    cmd: list[str],
    log: Path,
    stream: bool = True,
    on_line: Callable[[str], None] | None = None,
    env: dict[str, str] | None = None,
) -> float | None:
    """Run ``cmd`` with its output written to ``log`` (and to the terminal when ``stream``); returns
    the child's peak resident memory in MiB (None where the OS does not report it).

    ``on_line`` sees every output line (e.g. to follow progress); ``env`` is added to the
    environment. A non-zero exit raises :class:`StealthNSError` naming the log; Ctrl-C stops
    the child before it propagates.
    """
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as fh:
        fh.write(f"$ {shlex.join(cmd)}\n")
        fh.flush()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                if stream:
                    sys.stdout.write(line)
                fh.write(line)
                if on_line is not None:
                    on_line(line)
            code, peak_mb = _wait_with_peak_rss(proc)
        except BaseException:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            raise
    if code != 0:
        raise StealthNSError(f"{Path(cmd[0]).name} failed (exit {code}); see {log}")
    return peak_mb


def _wait_with_peak_rss(proc: subprocess.Popen) -> tuple[int, float | None]:
    """Wait for ``proc``; (exit code, its peak RSS in MiB from ``wait4``'s resource usage)."""
    if not hasattr(os, "wait4"):  # not on Windows
        return proc.wait(), None
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)  # Popen must not wait for it again
    return proc.returncode, usage.ru_maxrss / 1024  # KiB on Linux


@dataclass(frozen=True)
class TrainSpec:
    """One ``ns-train`` run: which scene, under which name, with which options and attack settings."""

    scene: Path
    """The dataset (``--data`` of the dataparser): a nerfstudio-data folder or transforms JSON, or a
    COLMAP folder."""
    name: str
    """Run name (``--timestamp``): the run folder's name."""
    output_dir: Path
    """``--output-dir`` of ns-train (the root of all runs)."""
    experiment: str = "runs"
    """``--experiment-name``: a sub-folder of ``output_dir``."""
    extra: tuple[str, ...] = ()
    """Other ns-train options before the dataparser, e.g. ``("--pipeline.model.background-color",
    "white")``; the attack's go in :attr:`attack`."""
    attack: AttackSettings = AttackSettings()
    """The attack's settings (written after :attr:`extra` as ``--pipeline.attack.*``); none: the
    method's defaults."""
    method: str = "stealth-splat-lite"
    """The nerfstudio method."""
    iterations: int | None = None
    """``--max-num-iterations``; None = the method's default."""
    seed: int = 0
    """``--machine.seed``."""
    threads: int | None = None
    """CPU threads of the training (OMP_NUM_THREADS); None = all cores. Not part of the run's identity."""
    dataparser: str = "nerfstudio-data"
    """The nerfstudio dataparser subcommand (``nerfstudio-data``, ``colmap``)."""
    dataparser_args: tuple[str, ...] = ()
    """Dataparser options after ``--data``, e.g. ``("--colmap-path", "sparse/0")``."""
    scene_id: str | None = None
    """The scene in the run's identity; None = the dataset folder's name. (The bench gives a dataset
    folder ``NAME:CONTENT-HASH``, so a run is not reused on other data under the same name.)"""

    def __post_init__(self) -> None:
        parts = {"run name": self.name, "experiment": self.experiment, "method": self.method}
        for label, part in parts.items():
            if not part or part in (".", "..") or "/" in part or "\\" in part or part != part.strip():
                raise StealthNSError(f"invalid {label} {part!r}: it must be a plain folder name")
        if self.iterations is not None and self.iterations < 1:
            raise StealthNSError(f"iterations must be at least 1, got {self.iterations}")
        if any(word.startswith(NS_TRAIN.prefix) for word in self.extra):
            raise ValueError(f"the attack's options go in TrainSpec.attack, not extra: {self.extra}")

    @property
    def run_dir(self) -> Path:
        """The run folder nerfstudio writes: ``output_dir/experiment/method/name``."""
        return self.output_dir / self.experiment / self.method / self.name

    @property
    def config_path(self) -> Path:
        """The run's ``config.yml`` (what ``ns-eval``/``ns-viewer --load-config`` take)."""
        return self.run_dir / "config.yml"

    @property
    def marker_path(self) -> Path:
        return self.run_dir / MARKER

    @property
    def options(self) -> tuple[str, ...]:
        """The ns-train options before the dataparser: :attr:`extra`, then :attr:`attack`'s."""
        return (*self.extra, *command_options(self.attack, NS_TRAIN))

    def command(self) -> list[str]:
        """The full ``ns-train`` command line."""
        cmd = [bin_path("ns-train"), self.method, "--vis", "tensorboard"]
        cmd += ["--output-dir", str(self.output_dir), "--experiment-name", self.experiment]
        cmd += ["--timestamp", self.name, "--machine.seed", str(self.seed)]
        if self.iterations is not None:
            cmd += ["--max-num-iterations", str(self.iterations)]
        cmd += [*self.options, self.dataparser, "--data", str(self.scene), *self.dataparser_args]
        return cmd

    def display_command(self) -> str:
        """:meth:`command` as a shell line, with ``ns-train`` instead of its full path."""
        return shlex.join(["ns-train", *self.command()[1:]])

    def identity(self) -> dict[str, Any]:
        """What a finished run must match to be reused (paths excluded, so a moved folder still counts)."""
        identity: dict[str, Any] = {
            "method": self.method,
            "scene": self.scene_id or Path(self.scene).name,
            "extra": list(self.options),
            "seed": self.seed,
        }
        if self.dataparser != "nerfstudio-data" or self.dataparser_args:  # old markers have no such key
            identity["dataparser"] = [self.dataparser, *self.dataparser_args]
        if self.draws_view_noise():  # runs of versions with another noise generator are retrained
            identity["view_noise"] = NOISE_GENERATOR
        return identity

    def draws_view_noise(self) -> bool:
        """Whether the training draws the attack's view noise: a stealth-splat method whose attack
        settings keep the attack, its view noise and the noise's strength on."""
        return self.method in METHODS and draws_view_noise(self.attack.config())


@dataclass(frozen=True)
class TrainRecord:
    """A finished run, as its marker file records it."""

    run_id: str
    seconds: float
    """Wall-clock seconds of ``ns-train`` when the run was trained."""
    finished_at: str
    iterations: int
    final_checkpoint: str
    command: list[str]
    trained_now: bool = False
    """True when this call trained it, False when an earlier run was reused."""
    peak_rss_mb: float | None = None
    """Peak resident memory of the ns-train process, MiB (None: not measured)."""

    @classmethod
    def from_marker(cls, data: dict[str, Any]) -> TrainRecord:
        return cls(
            run_id=str(data["run_id"]),
            seconds=float(data["seconds"]),
            finished_at=str(data["finished_at"]),
            iterations=int(data["iterations"]),
            final_checkpoint=str(data["final_checkpoint"]),
            command=[str(c) for c in data["command"]],
            peak_rss_mb=data.get("peak_rss_mb"),
        )


def read_marker(spec: TrainSpec) -> dict[str, Any] | None:
    """The marker's contents, or None if absent or unreadable."""
    try:
        data = json.loads(spec.marker_path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def finished_record(spec: TrainSpec) -> TrainRecord | None:
    """The run's record if it is finished for this spec (see the module docstring), else None."""
    data = read_marker(spec)
    if data is None or data.get("identity") != spec.identity():
        return None
    try:
        record = TrainRecord.from_marker(data)
    except (KeyError, TypeError, ValueError):
        return None
    if spec.iterations is not None and record.iterations != spec.iterations:
        return None
    if not spec.config_path.is_file() or not (spec.run_dir / record.final_checkpoint).is_file():
        return None
    return record


def is_finished(spec: TrainSpec) -> bool:
    """True when the run completed with these settings and can be reused."""
    return finished_record(spec) is not None


def run_status(spec: TrainSpec) -> RunStatus:
    """``finished`` (reusable), ``partial`` (a folder that :func:`train` would delete) or ``missing``."""
    if is_finished(spec):
        return "finished"
    return "partial" if spec.run_dir.exists() else "missing"


def configured_iterations(config_path: Path) -> int:
    """``max_num_iterations`` from a run's ``config.yml`` (a top-level key of nerfstudio's YAML dump)."""
    match = re.search(r"^max_num_iterations:\s*(\d+)\s*$", config_path.read_text(), flags=re.MULTILINE)
    if match is None:
        raise StealthNSError(f"no max_num_iterations in {config_path}")
    return int(match.group(1))


def train(
    spec: TrainSpec,
    log: Path | None = None,
    stream: bool = True,
    on_line: Callable[[str], None] | None = None,
) -> TrainRecord:
    """Train ``spec`` unless it is finished; returns its record (``trained_now`` tells which).

    A run folder that is not finished is deleted first, so an interrupted run starts over.
    The ns-train output goes to ``log`` (default ``RUN_DIR/ns-train.log``), and to the terminal
    when ``stream``. Raises :class:`StealthNSError` (naming the log) when ns-train fails or
    ends without its final checkpoint.
    """
    record = finished_record(spec)
    if record is not None:
        return record
    run_dir = spec.run_dir
    if run_dir.is_symlink() or run_dir.is_file():
        run_dir.unlink()
    elif run_dir.exists():
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True)
    log = run_dir / TRAIN_LOG if log is None else log
    cmd = spec.command()
    t0 = time.perf_counter()
    threads = None if spec.threads is None else {"OMP_NUM_THREADS": str(spec.threads)}
    peak_mb = run_command(cmd, log, stream=stream, on_line=on_line, env=threads)
    seconds = time.perf_counter() - t0
    if not spec.config_path.is_file():
        raise StealthNSError(f"ns-train exited without writing {spec.config_path}; see {log}")
    iterations = configured_iterations(spec.config_path)
    final = Path("nerfstudio_models") / f"step-{iterations - 1:09d}.ckpt"
    if not (run_dir / final).is_file():
        raise StealthNSError(
            f"ns-train ended without its final checkpoint {run_dir / final} (interrupted?); see {log}"
        )
    record = TrainRecord(
        run_id=uuid.uuid4().hex,
        seconds=round(seconds, 2),
        finished_at=_dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        iterations=iterations,
        final_checkpoint=final.as_posix(),
        command=cmd,
        trained_now=True,
        peak_rss_mb=None if peak_mb is None else round(peak_mb, 1),
    )
    data = {
        "identity": spec.identity(),
        "run_id": record.run_id,
        "seconds": record.seconds,
        "finished_at": record.finished_at,
        "iterations": record.iterations,
        "final_checkpoint": record.final_checkpoint,
        "command": record.command,
        "peak_rss_mb": record.peak_rss_mb,
        "log": str(log),
    }
    write_json_atomic(spec.marker_path, data)
    return record
