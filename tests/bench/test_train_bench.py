"""``stealth-ns bench train``: the phase timer and the per-phase breakdown of training steps."""

from __future__ import annotations

import json
import time

import pytest
from conftest import run_cli

from stealth_ns.bench.train_step import PHASES, leaf_phases, summarise
from stealth_ns.foundation.step_timing import StepTimer, phase


def test_phases_are_timed_only_while_active():
    timer = StepTimer()
    with timer.phase("a"):
        time.sleep(0.001)
    assert timer.current == {}
    timer.active = True
    for _ in range(2):
        with timer.phase("a"):
            time.sleep(0.002)
    timed = timer.wrap("b", lambda x: x + 1)
    assert timed(1) == 2
    assert timer.current["a"] >= 0.004 and "b" in timer.current
    untimed = timer.excluded(lambda: timer.phase("c").__enter__())
    untimed()
    assert "c" not in timer.current and timer.active
    timer.end_step(gaussians=5)
    assert timer.steps == [
        {"a": pytest.approx(timer.steps[0]["a"]), "b": timer.steps[0]["b"], "gaussians": 5}
    ]
    assert timer.current == {}


def test_a_timer_with_sync_waits_for_the_device_at_both_ends_of_a_phase():
    """On CUDA the bench gives the timer torch.cuda.synchronize: a phase's time must include the
    queued work its sync waits for, at its start (earlier work, not charged to it) and its end."""
    timer, calls = StepTimer(), []
    timer.active = True

    def sync() -> None:
        calls.append(len(calls))
        time.sleep(0.01 if len(calls) == 2 else 0.0)  # the phase's own GPU work, waited for at its end

    timer.sync = sync
    with timer.phase("gpu"):
        pass
    assert calls == [0, 1] and timer.current["gpu"] >= 0.01
    timer.sync = None
    with timer.phase("cpu"):
        pass
    assert len(calls) == 2 and timer.current["cpu"] < 0.01


def test_module_phase_is_a_no_op_by_default():
    with phase("anything"):
        pass  # the process's timer is inactive outside a benchmark


def test_leaf_phases_add_up_to_the_step():
    raw = {
        "step": 0.100,
        "train iteration": 0.080,
        "loss dict": 0.040,
        "data": 0.002,
        "forward": 0.030,
        "projection+SH": 0.010,
        "tile sort": 0.003,
        "rasterize forward": 0.008,
        "densification: pre": 0.001,
        "loss": 0.005,
        "optimizer": 0.010,
        "backward: rasterize": 0.012,
        "backward: projection+SH": 0.006,
        "densification: post": 0.004,
    }
    leaves = leaf_phases(raw)
    assert list(leaves) == list(PHASES)
    assert sum(leaves.values()) == pytest.approx(raw["step"])
    assert leaves["forward: other"] == pytest.approx(0.030 - 0.010 - 0.003 - 0.008 - 0.001)
    assert leaves["backward: other"] == pytest.approx(0.080 - 0.040 - 0.010 - 0.012 - 0.006)
    assert leaves["callbacks/logging"] == pytest.approx(0.100 - 0.080 - 0.004)
    median, mean, steps = summarise([raw, {**raw, "step": 0.2}])
    assert steps == pytest.approx([100.0, 200.0])
    assert mean["callbacks/logging"] == pytest.approx(1000 * (0.016 + 0.116) / 2)


def test_bench_train_times_a_generated_preset_at_a_resolution_clean_or_attacked(tmp_path, capsys):
    from stealth_ns.bench.train_step import run_train_benchmark

    result = run_train_benchmark(
        preset="facing", resolution="80x60", warmup=2, steps=2, threads=1, attack=False
    )
    assert result.scene == "generated facing 80x60 (seed 0), clean run" and len(result.step_ms) == 2


def test_bench_train_object_preset_gets_triangulated_seed_points_and_the_attack(capsys):
    """The 360-degree object-centred preset is a Blender scene without points: the bench triangulates
    them as bench attack does, and the attacked run's injection (at step 0 with --warmup 0) is timed."""
    from stealth_ns.bench.train_step import run_train_benchmark

    result = run_train_benchmark(preset="object", warmup=0, steps=2, threads=1)
    out = capsys.readouterr().out
    assert result.scene == "generated object 128x128 (seed 0)" and len(result.step_ms) == 2
    assert "triangulating the seed points" in out and "injected" in out
    assert result.step_ms[0] > result.step_ms[1]  # the injection is in the first step


def test_bench_train_cli_on_a_small_scene(tiny_orbit_scene, tmp_path):
    path = tmp_path / "train.json"
    proc = run_cli(
        "stealth-ns", "bench", "train", "--data", str(tiny_orbit_scene), "--warmup", "3", "--steps", "4",
        "--threads", "1", "--json", str(path),
    )  # fmt: skip
    assert "median step" in proc.stdout and "backward: rasterize" in proc.stdout
    result = json.loads(path.read_text())
    assert result["steps"] == 4 and len(result["step_ms"]) == 4 and result["threads"] == 1
    assert f"{sum(result['step_ms']) / 1000:.1f} s in all" in proc.stdout  # a whole run's time (--warmup 0)
    assert set(result["phases_ms"]) == set(PHASES)
    assert result["median_step_ms"] > 0 and result["phases_ms"]["rasterize forward"] > 0
    assert result["phases_ms"]["backward: projection+SH"] > 0  # the compiled projection ran
    assert result["gaussians"] > 0 and result["pairs"] > 0 and result["peak_rss_mb"] > 100
    # every step's phases add up to its measured time
    assert sum(result["phases_mean_ms"].values()) == pytest.approx(result["mean_step_ms"], rel=1e-6)


def test_bench_train_bad_options(tmp_path):
    proc = run_cli("stealth-ns", "bench", "train", "--steps", "0", check=False)
    assert proc.returncode != 0 and "--steps" in proc.stderr + proc.stdout
    assert "Traceback" not in proc.stderr
    proc = run_cli("stealth-ns", "bench", "train", "--data", str(tmp_path / "missing"), check=False)
    assert proc.returncode != 0 and "does not exist" in proc.stderr + proc.stdout
    for args, needle in (
        (["--preset", "nope"], "--preset 'nope': choose one of orbit, forward, facing, object"),
        (["--resolution", "10x"], "resolution"),
        (["--data", str(tmp_path), "--preset", "facing"], "not with --data"),
    ):
        proc = run_cli("stealth-ns", "bench", "train", *args, check=False)
        assert proc.returncode == 2 and needle in proc.stderr.strip().splitlines()[-1], proc.stderr[-500:]
    # a folder given as --json: refused before the benchmark (it used to fail after it had run)
    proc = run_cli("stealth-ns", "bench", "train", "--json", str(tmp_path), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"--json {tmp_path} is a folder" in proc.stderr.strip().splitlines()[-1]


def test_run_command_reports_the_childs_peak_rss(tmp_path):
    import sys

    from stealth_ns.foundation.errors import StealthNSError
    from stealth_ns.runs.training import run_command

    grow = "b = bytearray(300 * 2**20); b[::4096] = b'x' * len(b[::4096]); print('done')"
    peak = run_command([sys.executable, "-c", grow], tmp_path / "log", stream=False)
    assert peak is not None and peak >= 300
    assert "done" in (tmp_path / "log").read_text()
    with pytest.raises(StealthNSError, match="exit 3"):
        run_command([sys.executable, "-c", "raise SystemExit(3)"], tmp_path / "log2", stream=False)


def test_event_writers_are_closed_and_forgotten(monkeypatch, tmp_path):
    """nerfstudio never closes its TensorBoard writers; bench train does, before it removes its
    temporary run folder (their flush thread would otherwise write into it while it is removed)."""
    import nerfstudio.engine.trainer  # noqa: F401 - writer alone is a circular import in nerfstudio 1.1.5
    from nerfstudio.utils import writer
    from torch.utils.tensorboard import SummaryWriter

    from stealth_ns.bench.train_step import _close_event_writers

    tb = writer.TensorboardWriter(log_dir=tmp_path / "run")
    tb.write_scalar("x", 1.0, 0)
    monkeypatch.setattr(writer, "EVENT_WRITERS", [tb, object()])  # and a writer with no TensorBoard file
    _close_event_writers()
    assert writer.EVENT_WRITERS == []
    assert isinstance(tb.tb_writer, SummaryWriter) and tb.tb_writer.all_writers is None  # closed
