"""A report compares two models, so it refuses one model given twice however it is spelled: the clean
run's own PLY (or a copy of its checkpoint) as the poisoned model is the clean run by content (the same
Gaussians, :func:`stealth_ns.foundation.fingerprint.same_points`), and would score a V-test drop of 0.00
dB."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from conftest import run_cli

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.fingerprint import same_points


def test_same_points_ignores_order_and_export_noise_but_not_training():
    rng = np.random.default_rng(0)
    means = rng.uniform(-1, 1, (500, 3)).astype(np.float32)
    exported = means[rng.permutation(500)] + rng.normal(0, 1e-7, (500, 3))  # a PLY round trip, reordered
    assert same_points(means, exported)
    with_nan = np.concatenate([means, [[np.nan, 0, 0]]])  # a PLY export drops non-finite rows
    assert same_points(with_nan, means)
    trained = means.copy()
    trained[17] += 2e-4  # one Gaussian moved by about one Adam step
    assert not same_points(means, trained)
    assert not same_points(means, means[:-1])  # one Gaussian more (a poison point)
    moved_apart = means.copy()
    moved_apart[:2] = moved_apart[0]  # as many points, but one of them has no match
    assert not same_points(means, moved_apart)


def _fake_pair(ours: np.ndarray, theirs: np.ndarray):
    from stealth_ns.runs.pair import RunPair

    def run(means: np.ndarray) -> SimpleNamespace:
        return SimpleNamespace(model=SimpleNamespace(means=torch.from_numpy(means)))

    return RunPair(run(ours), run(theirs), record=None)  # type: ignore[arg-type]


def test_a_pair_of_one_model_is_refused_in_one_line():
    means = np.random.default_rng(1).uniform(-1, 1, (40, 3)).astype(np.float32)
    pair = _fake_pair(means[::-1].copy(), means)
    with pytest.raises(StealthNSError) as info:
        pair.check_distinct(Path("victim.ply"), Path("runs/clean"))
    assert str(info.value) == (
        "the poisoned model victim.ply is the clean run runs/clean: both hold the same 40 Gaussians (a copy "
        "of the run, or a model exported from it); give the model trained on the poisoned data"
    )
    _fake_pair(means + 1e-3, means).check_distinct(Path("a"), Path("b"))  # two models: no error


def _export(config: Path, ply: Path, frame: str = "nerfstudio") -> Path:
    """A run's Gaussians as a 3DGS PLY in nerfstudio's frame or its dataset's (as another trainer
    writes it: no poison tag)."""
    from stealth_ns.datasets.frames import frame_transforms
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.gaussians.ply import write_gaussian_ply
    from stealth_ns.gaussians.transform import transform_cloud
    from stealth_ns.method.model_cloud import cloud_of_model
    from stealth_ns.runs.loaded import load_run

    run = load_run(config)
    cloud = cloud_of_model(run.model)
    cloud.extra.clear()
    if frame != "nerfstudio":
        to_ns = frame_transforms(
            run.pipeline.datamanager.train_dataparser_outputs, inspect_folder("--data", str(run.data))
        )
        cloud = transform_cloud(cloud, np.linalg.inv(to_ns[frame]))
    write_gaussian_ply(ply, cloud)
    return ply


def test_report_refuses_the_poisoned_runs_own_ply_as_its_clean_run(tiny_run_pair, tiny_orbit_scene, tmp_path):
    """Before: a report of the poisoned run against itself (V-test drop 0.00 dB, the clean run's
    "V-illusory" as high as the attack's)."""
    from stealth_ns.report.write import write_report

    poisoned, _ = tiny_run_pair
    ply = _export(poisoned, tmp_path / "poisoned.ply")
    out = tmp_path / "report"
    with pytest.raises(
        StealthNSError, match=f"^the poisoned model {poisoned} is the clean run {ply}: both hold"
    ):
        write_report(poisoned, ply, out, stealth=False, clean_data=tiny_orbit_scene)
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
def test_report_refuses_the_clean_runs_ply_as_the_victim_of_a_poisoned_copy(
    tiny_run_pair, tiny_orbit_scene, tmp_path
):
    """The issue's case: the clean run exported as another trainer's PLY, given as the victim trained on
    poison-dataset's copy of its scene; before, a report with a V-test drop of 0.00 dB."""
    _, clean = tiny_run_pair
    copy = tmp_path / "copy"
    run_cli("stealth-ns", "poison-dataset", "--data", str(tiny_orbit_scene), "--output", str(copy))
    ply = _export(clean, tmp_path / "clean.ply", frame="dataset")
    out = tmp_path / "report"
    proc = run_cli("stealth-ns", "report", "--poisoned", str(ply), "--poisoned-data", str(copy),
                   "--clean", str(clean), "--output", str(out), "--no-stealth", check=False)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith(
        f"stealth-ns: error: the poisoned model {ply} is the clean run {clean}: both hold"
    ), line
    assert not (out / "report.json").exists()
