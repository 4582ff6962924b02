"""A checkpoint that does not belong to the run loading it is refused with one line (issue 32, classes 4
and 5): resuming (``ns-train --load-dir``) a clean run with the attack on, an attacked run with the attack
off or with other attack options, a run of other images; a missing, truncated or stray checkpoint; and
when a run is loaded for evaluation (report, defend, scan), a run folder holding another run's checkpoint.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from conftest import run_cli

from stealth_ns.attack.config import AttackConfig
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image, save_image
from stealth_ns.method.checkpoints import checkpoint_mismatch, find_checkpoint, read_checkpoint
from stealth_ns.method.safe_config import load_config
from stealth_ns.poisoned_datasets.dataset_copy import open_source
from stealth_ns.poisoned_datasets.setup import setup_trainer, trainer_config
from stealth_ns.runs.loaded import load_run

INJECT = ("--pipeline.attack.injection-step", "20")


def _resume(scene: Path, out: Path, *options: str) -> str:
    """ns-train resumed with ``options``; returns the one line it failed with (exit 1, no traceback)."""
    proc = run_cli(
        "ns-train", "stealth-splat-lite", "--vis", "tensorboard", "--output-dir", str(out),
        "--max-num-iterations", "70", *options, "nerfstudio-data", "--data", str(scene), check=False,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    (line,) = [ln for ln in proc.stderr.splitlines() if ln.startswith("stealth-ns: error:")]
    assert not (out / "unnamed").exists() or not list((out / "unnamed").rglob("*.ckpt"))  # nothing trained
    return line


def _changed_copy(scene: Path, folder: Path) -> Path:
    """``scene`` with one pixel of one training image changed."""
    copy = folder / "changed_scene"
    shutil.copytree(scene, copy)
    image = read_image(copy / "images" / "frame_00001.png", "image")
    image[0, 0] = 255 - image[0, 0]
    save_image(copy / "images" / "frame_00001.png", image)
    return copy


def _resume_in_process(scene: Path, out: Path, attack: AttackConfig, **trainer: object) -> str:
    """The one line with which nerfstudio's trainer, set up as ns-train does, refuses to resume."""
    config = trainer_config(open_source(scene), attack)
    config.output_dir, config.max_num_iterations = out, 70
    for key, value in trainer.items():
        setattr(config, key, value)
    with pytest.raises(StealthNSError) as err:
        setup_trainer(config)
    return str(err.value)


@pytest.mark.slow
def test_resume_refuses_a_checkpoint_of_another_run(tiny_run_pair, tiny_orbit_scene, tmp_path):
    poisoned, clean = (p.parent / "nerfstudio_models" for p in tiny_run_pair)
    attack, changed = AttackConfig(injection_step=20), _changed_copy(tiny_orbit_scene, tmp_path)
    cases = {
        "a clean run's (no attack record); resuming cannot add the attack": (tiny_orbit_scene, attack, clean),
        "an attacked run's; this run has the attack off": (
            tiny_orbit_scene, AttackConfig(enabled=False), poisoned,
        ),
        "--pipeline.attack.illusion 'astronaut' (now 'horse')": (
            tiny_orbit_scene, AttackConfig(injection_step=20, illusion="horse"), poisoned,
        ),
        "other images (14) than the dataset's training split (14 images)": (changed, attack, poisoned),
        "no such folder": (tiny_orbit_scene, attack, tmp_path / "missing"),
    }  # fmt: skip
    for expected, (scene, options, load_dir) in cases.items():
        assert expected in _resume_in_process(scene, tmp_path / "out", options, load_dir=load_dir), expected
    step = _resume_in_process(tiny_orbit_scene, tmp_path / "out", attack, load_dir=poisoned, load_step=5)
    assert "has no checkpoint of step 5 (it has steps 59)" in step

    # a truncated checkpoint beside a stray file (nerfstudio parsed every name: ValueError); ns-train's line
    broken = tmp_path / "broken"
    shutil.copytree(poisoned, broken)
    (checkpoint,) = broken.glob("*.ckpt")
    checkpoint.write_bytes(checkpoint.read_bytes()[:4000])
    (broken / "notes.txt").write_text("mine")
    line = _resume(tiny_orbit_scene, tmp_path / "out", "--load-dir", str(broken), *INJECT)
    assert f"cannot read checkpoint {checkpoint}" in line and "truncated" in line
    line = _resume_in_process(tiny_orbit_scene, tmp_path / "out", attack, load_checkpoint=checkpoint)
    assert f"cannot read checkpoint {checkpoint}" in line


@pytest.mark.slow
def test_a_run_folder_holding_another_runs_checkpoint_is_refused(tiny_run_pair, tiny_orbit_scene, tmp_path):
    poisoned, clean = (p.parent for p in tiny_run_pair)
    changed = _changed_copy(tiny_orbit_scene, tmp_path)
    swapped = tmp_path / "swapped"
    shutil.copytree(poisoned, swapped)
    for old in (swapped / "nerfstudio_models").glob("*.ckpt"):
        old.unlink()
    for new in (clean / "nerfstudio_models").glob("*.ckpt"):
        shutil.copy2(new, swapped / "nerfstudio_models" / new.name)
    with pytest.raises(StealthNSError, match="clean run's .*another run's checkpoint"):
        load_run(swapped / "config.yml")
    # a clean run folder whose dataset is not the one its checkpoint was trained on
    moved = tmp_path / "moved"
    shutil.copytree(clean, moved)
    config = load_config(moved / "config.yml")
    assert Path(config.pipeline.datamanager.dataparser.data).resolve() == tiny_orbit_scene.resolve()
    config.pipeline.datamanager.dataparser.data = changed
    (moved / "config.yml").write_text(yaml.dump(config))
    with pytest.raises(StealthNSError, match="trained on other images .*the dataset changed since"):
        load_run(moved / "config.yml")

    # defend (and report, scan: the same loader) with a truncated checkpoint: one line
    (checkpoint,) = (swapped / "nerfstudio_models").glob("*.ckpt")
    checkpoint.write_bytes(checkpoint.read_bytes()[:3000])
    proc = run_cli(
        "stealth-ns", "defend", "--run", str(swapped), "--clean", str(clean), "--output",
        str(tmp_path / "defended"), check=False,
    )  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]  # stealth-ns: 2
    assert f"cannot read checkpoint {checkpoint}" in proc.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "defended").exists()


def test_checkpoint_lookup_and_reading(tmp_path):
    folder = tmp_path / "nerfstudio_models"
    folder.mkdir()
    with pytest.raises(StealthNSError, match="holds no checkpoint"):
        find_checkpoint(folder)
    import torch

    for step in (9, 19):
        torch.save({"step": step, "pipeline": {}}, folder / f"step-{step:09d}.ckpt")
    (folder / "README").write_text("a stray file")
    assert find_checkpoint(folder).name == "step-000000019.ckpt"
    assert find_checkpoint(folder, 9).name == "step-000000009.ckpt"
    assert read_checkpoint(folder / "step-000000009.ckpt")["step"] == 9
    with pytest.raises(StealthNSError, match="not a checkpoint training can resume from .*optimizers"):
        read_checkpoint(folder / "step-000000009.ckpt", ("step", "pipeline", "optimizers"))
    with pytest.raises(StealthNSError, match="cannot read checkpoint .*README"):
        read_checkpoint(folder / "README")


def test_checkpoint_mismatch_rules():
    images = {"n_images": 3, "images": "abc"}
    clean = {"attack_record": "{}", "train_images": '{"n_images": 3, "images": "abc"}'}
    attacked = {**clean, "attack_record": '{"config": {"illusion": "astronaut", "seed": 0}}'}
    attack = {"illusion": "astronaut", "seed": 0, "new_option": 1}
    assert checkpoint_mismatch(clean, None, images, True) is None
    assert checkpoint_mismatch(attacked, attack, images, True) is None  # an option added since: ignored
    assert checkpoint_mismatch({}, attack, images, True) is None  # a checkpoint from before: unchecked
    assert "other images" in checkpoint_mismatch(clean, None, {**images, "images": "abd"}, False)
    assert "resuming cannot add" in checkpoint_mismatch(clean, attack, images, True)
    assert "another run's checkpoint" in checkpoint_mismatch(clean, attack, images, False)
    assert "attack off" in checkpoint_mismatch(attacked, None, images, True)
    assert "--pipeline.attack.seed 0 (now 2)" in checkpoint_mismatch(
        attacked, {**attack, "seed": 2}, images, True
    )
