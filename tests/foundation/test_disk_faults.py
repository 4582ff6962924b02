"""The environment's faults: a full disk or a read-only output folder gives one line naming the file and
the reason (``cannot write PATH: No space left on device``), never a traceback, and nothing cut short is
left looking complete (a checkpoint, a picture, a report, defend.json).

The faults are real where we can make them: a tiny tmpfs fills up (ENOSPC) and can be remounted
read-only (EROFS). That needs root (CI runs the tests as root; chmod does not stop root, mount does);
elsewhere those tests are skipped with the reason, and the write helpers are tested with a write that
fails as a full disk does (monkeypatched).
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from stealth_ns.foundation.errors import StealthNSError, environment_error

NO_SPACE = os.strerror(errno.ENOSPC)  # "No space left on device"


# ------------------------------------------------------------------ the faults
@pytest.fixture
def small_disk(tmp_path) -> Iterator[Callable[[str], Path]]:
    """``small_disk(size)``: a tmpfs of ``size`` (``"1m"``, ``"64k"``) mounted at a new folder of
    ``tmp_path``; every one is unmounted after the test. Skips when we are not root or cannot mount."""
    mounted: list[Path] = []

    def mount(size: str) -> Path:
        if os.geteuid() != 0:
            pytest.skip("a small disk is a tmpfs mount, which needs root (CI runs the tests as root)")
        where = tmp_path / f"disk{len(mounted)}"
        where.mkdir()
        proc = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip() or proc.returncode}")
        mounted.append(where)
        return where

    yield mount
    for where in reversed(mounted):
        if subprocess.run(["umount", str(where)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(where)], capture_output=True)  # still busy: detach it


def read_only(where: Path) -> Path:
    """Remount the tmpfs at ``where`` read-only (EROFS for every write, root's included)."""
    subprocess.run(["mount", "-o", "remount,ro", str(where)], check=True, capture_output=True)
    return where


def fill(where: Path) -> None:
    """Fill the disk of ``where`` up to its last byte (a file ``filler``)."""
    with open(where / "filler", "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError as err:
            assert err.errno == errno.ENOSPC


def leftovers(folder: Path) -> list[str]:
    """Temporary files of an atomic write left under ``folder`` (there should be none)."""
    return sorted(p.name for p in folder.rglob(".*.tmp-*"))


def _disk_full_after(monkeypatch, n_bytes: int) -> None:
    """Every ``Path.write_bytes`` writes ``n_bytes`` and then fails as a full disk does."""

    def write_bytes(self: Path, data: bytes) -> int:
        with self.open("wb") as f:
            f.write(bytes(data)[:n_bytes])
        raise OSError(errno.ENOSPC, NO_SPACE)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)


# ------------------------------------------------------------------ the write helpers
def test_a_write_cut_short_leaves_the_old_file_or_none(tmp_path, monkeypatch):
    """JSON, PNG, NPZ: a write that fails half-way keeps the earlier file whole (or leaves no file),
    removes its temporary file and says which file could not be written, and why."""
    from stealth_ns.foundation.json_io import write_json_atomic, write_npz_atomic
    from stealth_ns.images.io import save_png

    old = tmp_path / "result.json"
    old.write_text('{"earlier": true}\n')
    _disk_full_after(monkeypatch, 5)
    writes = {
        old: lambda: write_json_atomic(old, {"new": list(range(100))}),
        tmp_path / "view.png": lambda: save_png(tmp_path / "view.png", np.zeros((8, 8, 3))),
        tmp_path / "grid.npz": lambda: write_npz_atomic(tmp_path / "grid.npz", {"values": np.zeros(9)}),
    }
    for path, write in writes.items():
        with pytest.raises(StealthNSError) as info:
            write()
        assert str(info.value) == f"cannot write {path}: {NO_SPACE}"
    assert json.loads(old.read_text()) == {"earlier": True}
    assert not (tmp_path / "view.png").exists() and not (tmp_path / "grid.npz").exists()
    assert leftovers(tmp_path) == []


def test_json_on_a_full_disk_keeps_the_earlier_file(small_disk):
    disk = small_disk("64k")
    path = disk / "result.json"
    path.write_text('{"earlier": true}\n')
    fill(disk)
    from stealth_ns.foundation.json_io import write_json_atomic

    with pytest.raises(StealthNSError, match=f"^cannot write {path}: {NO_SPACE}$"):
        write_json_atomic(path, {"new": "x" * 100_000})
    assert json.loads(path.read_text()) == {"earlier": True}
    assert leftovers(disk) == []


def test_a_checkpoint_cut_short_is_removed(small_disk):
    """torch.save says a full disk as a RuntimeError of its zip writer; the checkpoint writer says
    which file and why, and leaves no step-N.ckpt behind, only the complete ones there were before."""
    import torch

    from stealth_ns.method.checkpoints import checkpoint_steps, read_checkpoint, save_checkpoint

    models = small_disk("1m") / "nerfstudio_models"
    models.mkdir()
    save_checkpoint(models / "step-000000010.ckpt", {"step": 10, "pipeline": {"w": torch.ones(10)}})
    big = models / "step-000000020.ckpt"
    with pytest.raises(StealthNSError) as info:
        save_checkpoint(big, {"step": 20, "pipeline": {"w": torch.ones(1_000_000)}})
    assert str(info.value) == f"cannot write {big}: {NO_SPACE}"
    assert list(checkpoint_steps(models)) == [10]  # no step-20 file, whole or cut short
    assert read_checkpoint(models / "step-000000010.ckpt")["step"] == 10
    assert sorted(p.name for p in models.iterdir()) == ["step-000000010.ckpt"]


def test_environment_errors_are_named_one_line():
    full = OSError(errno.ENOSPC, NO_SPACE)
    assert str(environment_error(full, "/out")) == f"cannot write /out: {NO_SPACE}"
    read_only_fs = OSError(errno.EROFS, os.strerror(errno.EROFS), "/out/report.json")
    assert (
        str(environment_error(read_only_fs, "/out")) == "cannot write /out/report.json: Read-only file system"
    )
    denied = PermissionError(errno.EACCES, os.strerror(errno.EACCES), "/out/a.png")
    assert str(environment_error(denied)) == "/out/a.png: Permission denied"
    assert environment_error(FileNotFoundError(errno.ENOENT, "No such file or directory", "/x")) is None


def test_the_cli_says_a_refused_write_in_one_line(monkeypatch, capsys):
    """An OSError of a write no command turned into a StealthNSError is still one line, exit status 2;
    any other OSError is a bug and shows as one."""
    import stealth_ns.cli as cli

    def full_disk(argv: list[str] | None = None) -> None:
        raise OSError(errno.ENOSPC, NO_SPACE, "/out/figure.png")

    monkeypatch.setattr(cli, "main", full_disk)
    with pytest.raises(SystemExit) as info:
        cli.entrypoint()
    assert info.value.code == 2
    assert capsys.readouterr().err == f"stealth-ns: error: cannot write /out/figure.png: {NO_SPACE}\n"

    def missing(argv: list[str] | None = None) -> None:
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", "/x")

    monkeypatch.setattr(cli, "main", missing)
    with pytest.raises(FileNotFoundError):
        cli.entrypoint()


# ------------------------------------------------------------------ the commands
def _ns_train(scene: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    """A clean 30-step ns-train of ``scene`` into ``out`` that saves a checkpoint every 10 steps."""
    return run_cli(
        "ns-train", "stealth-splat-lite", "--vis", "tensorboard", "--output-dir", str(out),
        "--experiment-name", "tiny", "--timestamp", "run", "--max-num-iterations", "30",
        "--steps-per-save", "10", "--steps-per-eval-all-images", "100000", "--machine.seed", "0",
        "--pipeline.attack.enabled", "False", *extra, "nerfstudio-data", "--data", str(scene),
        check=False,
    )  # fmt: skip


def _one_line(proc: subprocess.CompletedProcess) -> str:
    """The error line a command ended with, once checked that it failed without a traceback."""
    assert proc.returncode != 0, proc.stdout[-2000:]
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-3000:]
    return proc.stderr.strip().splitlines()[-1]


def test_ns_train_on_a_full_disk_stops_with_one_line_and_no_cut_checkpoint(tiny_orbit_scene, small_disk):
    """The first checkpoint (5.8 MB) does not fit on a 1 MB disk; before: a RuntimeError traceback of
    torch's zip writer and a truncated step-000000010.ckpt that looked like a checkpoint."""
    out = small_disk("1m")
    line = _one_line(_ns_train(tiny_orbit_scene, out))
    models = out / "tiny" / "stealth-splat-lite" / "run" / "nerfstudio_models"
    assert line == f"stealth-ns: error: cannot write {models / 'step-000000010.ckpt'}: {NO_SPACE}"
    assert list(models.iterdir()) == []


def test_ns_train_into_a_read_only_output_dir_is_one_line(tiny_orbit_scene, small_disk):
    out = read_only(small_disk("64k"))
    line = _one_line(_ns_train(tiny_orbit_scene, out))
    run = out / "tiny" / "stealth-splat-lite" / "run"
    assert line == f"stealth-ns: error: cannot write {run}: Read-only file system"


@pytest.mark.slow
def test_a_report_cut_short_by_a_full_disk_is_removed(tiny_run_pair, small_disk):
    """The pictures fill the 64 KB disk before report.json and report.html are written: one line, and
    nothing of the unfinished report is left (before: an OSError traceback and half the pictures)."""
    from stealth_ns.report.write import REPORT_FILES

    poisoned, clean = tiny_run_pair
    out = small_disk("64k") / "report"
    proc = run_cli("stealth-ns", "report", "--poisoned", str(poisoned), "--clean", str(clean),
                   "--output", str(out), "--no-stealth", check=False)  # fmt: skip
    line = _one_line(proc)
    assert proc.returncode == 2
    assert line.startswith(f"stealth-ns: error: cannot write {out}/"), line
    assert line.endswith(f": {NO_SPACE}; the unfinished report was removed"), line
    left = [p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()]
    assert not [p for p in left if REPORT_FILES.fullmatch(p)], left
    assert leftovers(out) == []


@pytest.mark.slow
def test_defend_cut_short_by_a_full_disk_leaves_no_defend_json(tiny_run_pair, small_disk):
    """The pruned run's checkpoint does not fit on a 1 MB disk: one line naming it, no checkpoint cut
    short, and the defend.json of an earlier result there (which would describe the pruned runs being
    replaced) is gone (before: a RuntimeError traceback, a truncated checkpoint, the old defend.json)."""
    poisoned, _ = tiny_run_pair
    out = small_disk("1m") / "defend"
    out.mkdir()
    (out / "defend.json").write_text('{"run": "an earlier result"}\n')
    (out / "notes.txt").write_text("mine")
    proc = run_cli("stealth-ns", "defend", "--run", str(poisoned), "--output", str(out),
                   "--defences", "zscore", check=False)  # fmt: skip
    line = _one_line(proc)
    assert line.startswith(f"stealth-ns: error: cannot write {out / 'pruned' / 'zscore'}/"), line
    assert line.endswith(f".ckpt: {NO_SPACE}"), line
    assert not (out / "defend.json").exists() and (out / "notes.txt").read_text() == "mine"
    assert not list(out.rglob("*.ckpt")) and leftovers(out) == []


@pytest.mark.slow
def test_a_scan_cut_short_by_a_full_disk_is_removed(tiny_run_pair, small_disk):
    """The cleaned run's checkpoint does not fit on a 1 MB disk: one line naming the file, and none of
    the scan's files is left (no scan.json that would look like a finished scan, no cut checkpoint)."""
    out = small_disk("1m") / "scan"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    proc = run_cli("stealth-ns", "scan", "--model", str(tiny_run_pair[0]), "--output", str(out), check=False)
    line = _one_line(proc)
    assert line.startswith(f"stealth-ns: error: cannot write {out}/"), line
    assert line.endswith(f"{NO_SPACE}; the unfinished scan was removed"), line
    # left: the user's file, and the scan's record of files it was about to write (no hashes: none done)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        ".stealth-ns-scan.json",
        "notes.txt",
    ]
    assert not any(json.loads((out / ".stealth-ns-scan.json").read_text())["files"].values())
    assert (out / "notes.txt").read_text() == "mine"
