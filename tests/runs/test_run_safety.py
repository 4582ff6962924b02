"""Untrusted run folders and mismatched runs (issue 13, items 1, 3, 7, 9): safe config loading, the
dataset fingerprint of a run, the viewer's bind address, the report's output folder, demo and
rank-views input checks."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import BIN, STALE_REPORT_FILES, USER_REPORT_FILES, run_cli

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method.safe_config import SafeConfigLoader, load_config

EVIL = '!!python/object/apply:os.system ["touch PWNED"]\n'


def fake_run(folder: Path, config_text: str) -> Path:
    """A run folder with this config.yml and a (fake) checkpoint, as a downloaded run would be."""
    (folder / "nerfstudio_models").mkdir(parents=True)
    (folder / "nerfstudio_models" / "step-000000099.ckpt").write_bytes(b"not a checkpoint")
    (folder / "config.yml").write_text(config_text)
    return folder / "config.yml"


# ------------------------------------------------------------------ item 7: viewer bind address
def test_our_methods_bind_the_viewer_to_loopback():
    from nerfstudio.configs.method_configs import all_methods

    for name in ("stealth-splat", "stealth-splat-lite"):
        assert all_methods[name].viewer.websocket_host == "127.0.0.1", name


# ------------------------------------------------------------------ item 3: safe config loading
def test_safe_loader_loads_what_nerfstudio_writes():
    """Every installed method's config, dumped as ns-train dumps it, loads back equal."""
    from nerfstudio.configs.method_configs import all_methods

    for name, config in all_methods.items():
        text = yaml.dump(config)
        assert yaml.load(text, Loader=SafeConfigLoader) == config, name


@pytest.mark.parametrize(
    "text, tag",
    [
        (EVIL, "!!python/object/apply:os.system"),
        ('a: !!python/object/apply:subprocess.call [["touch", "PWNED"]]\n', "subprocess.call"),
        ("a: !!python/object/apply:builtins.exec [\"open('PWNED', 'w')\"]\n", "builtins.exec"),
        ('a: !!python/object/new:os.system ["touch PWNED"]\n', "!!python/object/new:os.system"),
        ('a: !!python/name:nerfstudio.utils.scripts.run_command ""\n', "nerfstudio.utils.scripts"),
        (
            'a: !!python/object/apply:stealth_ns.runs.training.run_command [["touch", "PWNED"], "x"]\n',
            "runs",
        ),
        ("a: !!python/object/apply:nerfstudio.engine.trainer.TrainerConfig []\n", "TrainerConfig"),
    ],
)
def test_safe_loader_refuses_code_and_runs_nothing(tmp_path, monkeypatch, text, tag):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "config.yml"
    path.write_text(text)
    with pytest.raises(StealthNSError, match="refusing to load") as err:
        load_config(path)
    message = str(err.value)
    assert str(path) in message and tag in message and "\n" not in message
    assert not (tmp_path / "PWNED").exists()


def test_report_on_a_booby_trapped_run_executes_nothing(tmp_path):
    """`stealth-ns report` on a run folder whose config.yml runs a command: refused, nothing run."""
    evil, other = fake_run(tmp_path / "evil", EVIL), fake_run(tmp_path / "other", EVIL)
    proc = subprocess.run(
        [str(BIN / "stealth-ns"), "report", "--poisoned", str(evil), "--clean", str(other),
         "--output", str(tmp_path / "report")],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert not (tmp_path / "PWNED").exists()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert f"refusing to load {evil}: tag !!python/object/apply:os.system" in proc.stderr


# ------------------------------------------------------------------ item 1: dataset fingerprint
def _train_outputs(scene: Path):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    return NerfstudioDataParserConfig(data=scene).setup().get_dataparser_outputs(split="train")


def test_fingerprint_tells_images_from_poses(tiny_orbit_scene, tmp_path):
    from stealth_ns.foundation.fingerprint import dataset_fingerprint, fingerprint_differences

    outputs = _train_outputs(tiny_orbit_scene)
    base = dataset_fingerprint(outputs)
    assert dataset_fingerprint(_train_outputs(tiny_orbit_scene)) == base

    images = shutil.copytree(tiny_orbit_scene, tmp_path / "images")
    first, other = (Path(p).relative_to(tiny_orbit_scene) for p in outputs.image_filenames[:2])
    shutil.copyfile(images / other, images / first)  # same names, one training image's contents differ
    assert fingerprint_differences(base, dataset_fingerprint(_train_outputs(images))) == ["images"]

    poses = shutil.copytree(tiny_orbit_scene, tmp_path / "poses")
    meta = json.loads((poses / "transforms.json").read_text())
    meta["frames"][0]["transform_matrix"][0][3] += 0.05
    (poses / "transforms.json").write_text(json.dumps(meta))
    assert fingerprint_differences(base, dataset_fingerprint(_train_outputs(poses))) == ["poses"]


def _moved_clean_run(clean: Path, tmp_path: Path, scene: Path, keep_record: bool) -> Path:
    """A copy of the clean run whose config points at ``scene``."""
    copy = Path(shutil.copytree(clean.parent, tmp_path / "clean-copy"))
    config = load_config(copy / "config.yml")
    config.pipeline.datamanager.data = scene
    config.pipeline.datamanager.dataparser.data = scene
    (copy / "config.yml").write_text(yaml.dump(config))
    if not keep_record:
        (copy / "dataset.json").unlink()
    return copy / "config.yml"


@pytest.mark.slow
def test_report_refuses_a_clean_run_of_another_dataset(tiny_run_pair, tiny_orbit_scene, tmp_path):
    from stealth_ns.foundation.fingerprint import dataset_fingerprint, recorded_fingerprint

    poisoned, clean = tiny_run_pair
    # both runs recorded their training split when training started, as the dataset computes it
    expected = dataset_fingerprint(_train_outputs(tiny_orbit_scene))
    assert recorded_fingerprint(poisoned.parent) == expected == recorded_fingerprint(clean.parent)
    # their configs load with the safe loader
    assert load_config(poisoned).pipeline.attack.enabled and not load_config(clean).pipeline.attack.enabled

    # same images, two cameras moved (a shift of all of them would be normalised away by the
    # dataparser, as it is in training); the clean run has no record: recomputed from its dataset
    other = shutil.copytree(tiny_orbit_scene, tmp_path / "other-scene")
    meta = json.loads((other / "transforms.json").read_text())
    for frame in meta["frames"][:2]:
        frame["transform_matrix"][2][3] += 0.1
    (other / "transforms.json").write_text(json.dumps(meta))
    moved = _moved_clean_run(clean, tmp_path, other, keep_record=False)
    proc = run_cli("stealth-ns", "report", "--poisoned", str(poisoned), "--clean", str(moved),
                   "--output", str(tmp_path / "r1"), check=False)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert "not trained on the same dataset" in line and "camera poses differ" in line
    assert "images differ" not in line and str(poisoned) in line and str(moved) in line
    assert not (tmp_path / "r1" / "report.json").exists()


@pytest.mark.slow
def test_report_refuses_a_recorded_fingerprint_of_other_images(tiny_run_pair, tmp_path):
    poisoned, clean = tiny_run_pair
    copy = Path(shutil.copytree(clean.parent, tmp_path / "clean-other"))
    record = json.loads((copy / "dataset.json").read_text())
    record["train"]["images"] = "0" * 64  # trained on other images than the dataset holds now
    (copy / "dataset.json").write_text(json.dumps(record))
    proc = run_cli("stealth-ns", "report", "--poisoned", str(poisoned), "--clean", str(copy / "config.yml"),
                   "--output", str(tmp_path / "r"), check=False)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "their training images differ" in proc.stderr and "poses" not in proc.stderr


# ------------------------------------------------------------------ item 9: smaller ones
@pytest.mark.slow
def test_reused_report_folder_loses_stale_pictures_and_keeps_user_files(tiny_report):
    out, _ = tiny_report  # written into a folder that held these files
    assert not any((out / name).exists() for name in STALE_REPORT_FILES)
    assert all((out / name).read_text() == "x" for name in USER_REPORT_FILES)
    page = (out / "report.html").read_text()
    assert "view9999" not in page and (out / "report.json").is_file()


def test_unwritable_report_output_fails_before_loading_runs(tmp_path, monkeypatch):
    from stealth_ns.report import write as report

    def no_loading(*args, **kwargs):
        raise AssertionError("the runs were loaded before the output was checked")

    monkeypatch.setattr(report.RunPair, "load", no_loading)
    for run in ("p", "c"):  # runs as far as the checks before loading can tell
        fake_run(tmp_path / run, "x: 1\n")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(StealthNSError, match="cannot write the report to .*a-file is a file"):
        report.write_report(tmp_path / "p", tmp_path / "c", blocker / "report")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "images").write_text("")
    with pytest.raises(StealthNSError, match="images is a file"):
        report.write_report(tmp_path / "p", tmp_path / "c", tmp_path / "out")
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        try:
            with pytest.raises(StealthNSError, match="cannot write the report"):
                report.write_report(tmp_path / "p", tmp_path / "c", locked / "report")
        finally:
            locked.chmod(0o700)


def test_a_report_that_fails_keeps_the_earlier_report(tmp_path, monkeypatch):
    """The earlier report in --output is cleared only once the new one's numbers exist."""
    from stealth_ns.report import write as report

    def failing_metrics(*args, **kwargs):
        raise StealthNSError("the poisoned views could not be rendered")

    monkeypatch.setattr(report.RunPair, "load", lambda *args: object())
    monkeypatch.setattr(report, "pair_metrics", failing_metrics)
    for run in ("p", "c"):
        fake_run(tmp_path / run, "x: 1\n")
    earlier = tmp_path / "out"
    (earlier / "images").mkdir(parents=True)
    (earlier / "report.html").write_text("earlier")
    (earlier / "images" / "view0000_target.png").write_bytes(b"png")
    with pytest.raises(StealthNSError, match="could not be rendered"):
        report.write_report(tmp_path / "p", tmp_path / "c", earlier)
    assert (earlier / "report.html").read_text() == "earlier"
    assert (earlier / "images" / "view0000_target.png").read_bytes() == b"png"


@pytest.mark.parametrize("iterations", ["0", "-5"])
def test_demo_with_no_iterations_fails_before_the_scene(tmp_path, monkeypatch, iterations):
    import stealth_ns.scene_generator
    from stealth_ns.cli import main

    def no_scene(*args, **kwargs):
        raise AssertionError("the scene was generated")

    monkeypatch.setattr(stealth_ns.scene_generator, "make_scene", no_scene)
    with pytest.raises(StealthNSError, match=f"--iterations must be at least 1, got {iterations}"):
        main(["demo", "--iterations", iterations, "--output", str(tmp_path / "demo")])
    assert not (tmp_path / "demo").exists()


def test_rank_views_names_the_frame_with_a_nan_pose(tiny_orbit_scene, tmp_path):
    from stealth_ns.difficulty.rank import rank_scene_views

    scene = shutil.copytree(tiny_orbit_scene, tmp_path / "scene")
    meta = json.loads((scene / "transforms.json").read_text())
    meta["frames"][3]["transform_matrix"][1][2] = float("nan")
    (scene / "transforms.json").write_text(json.dumps(meta))
    name = meta["frames"][3]["file_path"]
    with pytest.raises(StealthNSError) as err:
        rank_scene_views(scene)
    message = str(err.value)
    assert f"frame 3 ({name})" in message and "not finite" in message and "coincide" not in message


@pytest.mark.parametrize("method", ["stealth-splat-lite", "stealth-splat"])
def test_every_registered_method_config_loads_with_the_safe_loader(tmp_path, method):
    """A run's config.yml names every class of its method config (optimizers included): all allowed."""
    import copy

    from stealth_ns.method_configs.registry import method_config

    config = copy.deepcopy(method_config(method))
    path = tmp_path / "config.yml"
    path.write_text(yaml.dump(config), encoding="utf-8")
    loaded = load_config(path)
    assert loaded.optimizers["means"]["optimizer"] == config.optimizers["means"]["optimizer"]
