"""Two trainings, one run folder (issue 57, class 6): a second ns-train with the same ``--output-dir``,
``--experiment-name`` and ``--timestamp`` is refused with one line -- while the first runs (a lock held
for the run's lifetime) and after it (the folder holds its config and checkpoints) -- instead of
mixing one's config with the other's checkpoint; a resume whose model has another shape
(``--pipeline.model.sh-degree`` changed) is refused naming the option, leaving the run as it was."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import run_cli

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method.checkpoints import (
    LOCK_FILE,
    claim_run_folder,
    lock_run_folder,
    option_changes,
    run_folder_conflict,
    shape_mismatch,
)

HOLD = "import sys, time; from stealth_ns.method.checkpoints import lock_run_folder; "
HOLD += "lock_run_folder(sys.argv[1]); "
HOLD += "print('locked', flush=True); time.sleep(120)"


def _holder(folder: Path) -> subprocess.Popen:
    """Another process holding ``folder``'s lock (as a running ns-train does) until it is killed."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
    return proc


def _hashes(folder: Path, lock: bool = True) -> dict[str, str]:
    """sha256 of every file of ``folder`` (without ``lock``: but its lock file)."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and (lock or p.name != LOCK_FILE)
    }


# ---------------------------------------------------------------------------------- the lock
def test_a_run_folder_is_locked_while_a_training_holds_it(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    holder = _holder(folder)
    try:
        with pytest.raises(StealthNSError) as err:
            lock_run_folder(folder)
        assert str(err.value) == (
            f"the run folder {folder} is in use by another training (process {holder.pid}): give this one "
            "another --timestamp (or --experiment-name, --output-dir)"
        )
    finally:
        holder.kill()
        holder.wait()
    lock_run_folder(folder)  # released when its process ended
    lock_run_folder(folder)  # and this process may take it again (ns-train claims it twice on a resume)
    other = tmp_path / "other"
    other.mkdir()
    lock_run_folder(other)
    assert (other / LOCK_FILE).read_text() == str(os.getpid())


def test_a_folder_holding_a_run_is_refused_unless_it_is_resumed(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "events.out.tfevents.1").write_text("x")
    assert run_folder_conflict(folder, None) is None  # nothing of a run's yet
    (folder / "config.yml").write_text("x")
    (folder / "nerfstudio_models").mkdir()
    (folder / "nerfstudio_models" / "step-000000059.ckpt").write_bytes(b"x")
    why = run_folder_conflict(folder, None)
    assert why is not None and "\n" not in why
    assert why.startswith(
        f"the run folder {folder} already holds a run (config.yml, nerfstudio_models/step-000000059.ckpt)"
    )
    assert f"--load-dir {folder / 'nerfstudio_models'}" in why
    assert run_folder_conflict(folder, folder / "nerfstudio_models") is None  # resumed in place
    assert run_folder_conflict(folder, folder / "nerfstudio_models" / "step-000000059.ckpt") is None
    assert run_folder_conflict(folder, tmp_path / "elsewhere" / "nerfstudio_models") == why


def test_claiming_a_folder_holding_a_run_writes_nothing_there(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "config.yml").write_text("x")
    with pytest.raises(StealthNSError, match="already holds a run"):
        claim_run_folder(folder, None)
    assert sorted(p.name for p in folder.iterdir()) == ["config.yml"]
    (folder / "config.yml").unlink()
    holder = _holder(folder)  # a training that has not written its config yet
    try:
        with pytest.raises(StealthNSError, match=f"in use by another training \\(process {holder.pid}\\)"):
            claim_run_folder(folder, None)
        (folder / "config.yml").write_text("x")  # it has now
        with pytest.raises(StealthNSError, match=f"in use by another training \\(process {holder.pid}\\)"):
            claim_run_folder(folder, None)
    finally:
        holder.kill()
        holder.wait()
    (folder / "config.yml").unlink()
    claim_run_folder(folder, None)
    assert (folder / LOCK_FILE).read_text() == str(os.getpid())


# ---------------------------------------------------------------------------------- another model's shape
def test_shape_mismatch_ignores_the_number_of_gaussians():
    ours = {
        "_model.gauss_params.means": torch.zeros(10, 3),
        "_model.gauss_params.features_rest": torch.zeros(10, 3, 3),
    }
    assert shape_mismatch({k: torch.zeros(7, *v.shape[1:]) for k, v in ours.items()}, ours) is None
    theirs = {**ours, "_model.gauss_params.features_rest": torch.zeros(7, 15, 3), "_extra_state": {}}
    assert (
        shape_mismatch(theirs, ours) == "its gauss_params.features_rest is [N, 15, 3], this run's [N, 3, 3]"
    )
    assert shape_mismatch(
        {"_model.data_background": torch.zeros(4)}, {"_model.data_background": torch.zeros(3)}
    ) == ("its data_background is [4], this run's [3]")


@dataclasses.dataclass
class _Inner:
    mode: str = "off"


@dataclasses.dataclass
class _Model:
    sh_degree: int = 3
    inner: _Inner = dataclasses.field(default_factory=_Inner)
    _target: str = "x"


def test_option_changes_are_spelled_as_flags():
    assert option_changes(_Model(), _Model(), "--pipeline.model") == []
    changed = _Model(sh_degree=1, inner=_Inner("SO3xR3"), _target="y")
    assert option_changes(_Model(), changed, "--pipeline.model") == [
        "--pipeline.model.sh-degree 3 (now 1)",
        "--pipeline.model.inner.mode 'off' (now 'SO3xR3')",
    ]


# ---------------------------------------------------------------------------------- ns-train
def _copy_run(config: Path, out: Path) -> Path:
    """The run folder of ``config`` copied to where ``--output-dir out --experiment-name tiny
    --timestamp NAME`` puts it."""
    run = out / "tiny" / "stealth-splat-lite" / config.parent.name
    shutil.copytree(config.parent, run)
    return run


def _setup(scene: Path, out: Path, name: str, **options):
    """nerfstudio's trainer set up as ns-train does (its config saved first) for run ``name``."""
    from stealth_ns.attack.config import AttackConfig
    from stealth_ns.poisoned_datasets.dataset_copy import open_source
    from stealth_ns.poisoned_datasets.setup import setup_trainer, trainer_config

    config = trainer_config(open_source(scene), AttackConfig(enabled=False))
    config.output_dir, config.experiment_name, config.timestamp = out, "tiny", name
    config.max_num_iterations = 70
    for key, value in options.items():
        setattr(config, key, value)
    return config, setup_trainer


def test_a_second_training_into_a_run_folder_is_refused(tiny_run_pair, tiny_orbit_scene, tmp_path):
    """Before: both exited 0, the second's config.yml beside the first's checkpoint (then its own)."""
    run = _copy_run(tiny_run_pair[1], tmp_path / "out")
    before = _hashes(run)
    config, setup = _setup(tiny_orbit_scene, tmp_path / "out", "clean")
    with pytest.raises(StealthNSError, match=r"^the run folder .*clean already holds a run \(config.yml, "):
        setup(config)
    assert _hashes(run) == before


def test_a_resume_of_another_model_shape_names_the_option(tiny_run_pair, tiny_orbit_scene, tmp_path):
    """Before: a size-mismatch traceback, after config.yml had been overwritten with the new options."""
    run = _copy_run(tiny_run_pair[1], tmp_path / "out")
    before = _hashes(run, lock=False)  # resumed in place, this process holds its lock
    config, setup = _setup(tiny_orbit_scene, tmp_path / "out", "clean", load_dir=run / "nerfstudio_models")
    config.pipeline.model.sh_degree = 1
    with pytest.raises(StealthNSError) as err:
        setup(config)
    assert str(err.value) == (
        f"cannot resume from {run / 'nerfstudio_models' / 'step-000000059.ckpt'}: its "
        "gauss_params.features_rest is [N, 15, 3], this run's [N, 3, 3]; its run was trained with "
        "--pipeline.model.sh-degree 3 (now 1): resume with the options it was trained with"
    )
    assert _hashes(run, lock=False) == before  # config.yml too: a resume writes it once it has loaded


@pytest.mark.slow
def test_ns_train_into_a_busy_or_used_run_folder_says_one_line(tiny_run_pair, tiny_orbit_scene, tmp_path):
    """ns-train itself, as a user runs it twice: refused before anything is written."""
    run = _copy_run(tiny_run_pair[1], tmp_path / "out")
    before = _hashes(run)
    args = [
        "ns-train", "stealth-splat-lite", "--vis", "tensorboard", "--output-dir", str(tmp_path / "out"),
        "--experiment-name", "tiny", "--max-num-iterations", "60", "--pipeline.attack.enabled", "False",
    ]  # fmt: skip
    data = ["nerfstudio-data", "--data", str(tiny_orbit_scene)]
    for timestamp, expected in (("clean", "already holds a run"), ("busy", "is in use by another training")):
        (tmp_path / "out" / "tiny" / "stealth-splat-lite" / "busy").mkdir(exist_ok=True)
        holder = _holder(tmp_path / "out" / "tiny" / "stealth-splat-lite" / "busy")
        try:
            proc = run_cli(*args, "--timestamp", timestamp, *data, check=False, timeout=300)
        finally:
            holder.kill()
            holder.wait()
        assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
        lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("stealth-ns:")]
        assert len(lines) == 1 and expected in lines[0], proc.stderr[-3000:]
    assert _hashes(run) == before
    assert not (tmp_path / "out" / "tiny" / "stealth-splat-lite" / "busy" / "config.yml").exists()
