"""`stealth-ns bench attack`: the plan, reuse of finished runs, resuming, the tables, bad input.

The fast tests replace ns-train (``stealth_ns.runs.training.run_command``), the run comparison
(``stealth_ns.report.numbers.compare_runs``) and the making of a poisoned copy (``PoisonJob.make``,
which would run ``stealth-ns poison-dataset`` / ``ipa-poison``) with fakes that write what the real
ones would; the one slow test trains a real tiny run through :mod:`stealth_ns.runs.training`.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest
from conftest import run_cli

from stealth_ns.attack.normal_draw import NOISE_GENERATOR
from stealth_ns.attack.options import AttackSettings
from stealth_ns.bench.attack import run_bench
from stealth_ns.bench.execute import METRICS_FILE, METRICS_LOG
from stealth_ns.bench.plan import bench_plan
from stealth_ns.bench.poisoned_copies import PoisonJob
from stealth_ns.bench.tables import NOT_IMPLEMENTED, render_markdown, table_data
from stealth_ns.datasets.generated import scene_dir
from stealth_ns.datasets.seeded import SEED_POINTS_MARKER
from stealth_ns.defence_eval.stealth import stealth_summary
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.method_configs.attack_experiments import (
    CLEAN,
    DEFAULT_SCENES,
    RUNS,
    TABLES,
    attack_settings,
    get_run,
    get_table,
    stealth_run,
)
from stealth_ns.runs import training as runs
from stealth_ns.runs.training import TrainSpec, is_finished, run_status, train

TINY = {"resolution": "64x48", "views": 16}
TABLE6_ORDER = ["orbit/clean", "orbit/gt-only", "orbit/gt-density", "orbit/gt-noise", "orbit/full"]


def _arg(cmd: list[str], flag: str) -> str:
    return cmd[cmd.index(flag) + 1]


class FakeTraining:
    """Stands in for ns-train: writes config.yml and the checkpoints a finished run has."""

    def __init__(self, fail: set[str] | None = None) -> None:
        self.trained: list[str] = []
        self.envs: dict[str, dict | None] = {}
        self.fail = fail or set()

    def __call__(self, cmd, log, stream=True, on_line=None, env=None) -> None:
        name = _arg(cmd, "--timestamp")
        self.envs[name] = env
        run_dir = Path(_arg(cmd, "--output-dir")) / _arg(cmd, "--experiment-name") / cmd[1] / name
        iters = int(_arg(cmd, "--max-num-iterations"))
        log.write_text("fake ns-train\n")
        if name in self.fail:
            raise StealthNSError(f"ns-train failed (exit 1); see {log}")
        (run_dir / "nerfstudio_models").mkdir(parents=True)
        (run_dir / "config.yml").write_text(f"method_name: {cmd[1]}\nmax_num_iterations: {iters}\n")
        (run_dir / "nerfstudio_models" / f"step-{iters - 1:09d}.ckpt").write_bytes(b"ckpt")
        if on_line is not None:
            on_line(f"{iters // 2}  ({50.0:.2f}%)\n")
            on_line(f"{iters // 2} (50.00%)          0.1 s\n")
        self.trained.append(name)


# V-illusory PSNR, V-test drop per run name: only the full attack succeeds (25 dB / 3 dB rule)
FAKE_NUMBERS = {
    "gt-only": (13.2, 0.1),
    "gt-density": (24.0, 0.2),
    "gt-noise": (13.4, 1.6),
    "full": (27.5, 1.7),
}


class FakeCompare:
    """Stands in for report.compare_runs (the contract's keys; LPIPS unavailable)."""

    def __init__(self) -> None:
        self.calls: list[str] = []

    def __call__(self, poisoned_config: Path, clean_config: Path) -> dict:
        name = Path(poisoned_config).parent.name
        assert Path(clean_config).parent.name == "clean"
        self.calls.append(name)
        ill, drop = FAKE_NUMBERS.get(name, (26.0, 1.0))
        return {
            "v_illusory_psnr": ill, "v_illusory_ssim": 0.8, "v_illusory_lpips": None,
            "v_illusory_clean_psnr": 12.5, "v_illusory_clean_ssim": 0.5, "v_illusory_clean_lpips": None,
            "v_test_psnr": 28.0 - drop, "v_test_ssim": 0.85, "v_test_lpips": None,
            "v_test_psnr_clean": 28.0, "v_test_ssim_clean": 0.9, "v_test_lpips_clean": None,
            "v_test_drop": drop, "attack_success": ill > 25 and drop <= 3,
            "success_thresholds": {"25/3": ill > 25 and drop <= 3},
            "lpips_unavailable": "no AlexNet weights on this machine",
            "n_gaussians": 1000, "n_gaussians_clean": 1200, "n_poison_gaussians": 50,
            "poisoned_views": ["frame_00007.png"],
            "stealth": stealth_summary(
                {"view-support": {"kind": "post-hoc", "auroc": 0.9, "curve": [], "operating_point": {
                    "v_illusory_psnr": 26.0 if name == "full" else 12.0, "v_test_cost": 0.1}}},
                ill > 25 and drop <= 3,
            ),
        }  # fmt: skip


class FakePoison:
    """Stands in for PoisonJob.make (no ``stealth-ns poison-dataset`` / ``ipa-poison`` subprocess): the
    copy is the source folder with a complete attack record, and the marker a real make writes."""

    def __init__(self) -> None:
        self.calls: list[PoisonJob] = []
        self.fail: set[str] = set()  # copy folder names whose making fails

    def make(self, job: PoisonJob) -> None:
        self.calls.append(job)
        if job.output.name in self.fail:
            raise RuntimeError(f"{job.kind} failed (CUDA error: out of memory; log: {job.log})")
        if job.output.exists():
            shutil.rmtree(job.output)
        shutil.copytree(job.source, job.output)
        (job.output / "attack").mkdir(exist_ok=True)
        record = {"poisoned_dataset": {"complete": True}}
        (job.output / "attack" / "attack.json").write_text(json.dumps(record))
        write_json_atomic(job.marker, job.identity())

    @property
    def made(self) -> list[str]:
        return [job.output.name for job in self.calls]


@pytest.fixture
def fake_poison(monkeypatch):
    fake = FakePoison()
    monkeypatch.setattr(PoisonJob, "make", lambda job: fake.make(job))
    return fake


@pytest.fixture
def fakes(monkeypatch, fake_poison):
    from stealth_ns.report import numbers as report

    training, compare = FakeTraining(), FakeCompare()
    monkeypatch.setattr(runs, "run_command", training)
    monkeypatch.setattr(report, "compare_runs", compare)
    return SimpleNamespace(training=training, compare=compare, poison=fake_poison)


# ------------------------------------------------------------------------------ the plan
def test_dry_run_lists_the_runs_and_writes_nothing(tmp_path, capsys):
    plan = run_bench(tmp_path / "out", tables=["6"], scenes=["orbit"], iterations=30, dry_run=True)
    assert [p.key for p in plan.runs] == TABLE6_ORDER  # clean first, then the paper's row order
    assert all(p.status == "missing" for p in plan.runs)
    out = capsys.readouterr().out
    assert "5 runs: 5 to train, 0 unfinished on disk (deleted and retrained), 0 finished (reused)" in out
    assert out.count("[train  ]") == 5 and "(to be generated)" in out
    gt_only = next(line for line in out.splitlines() if "--timestamp gt-only" in line)
    assert gt_only.strip().startswith("ns-train stealth-splat-lite ")
    assert "--pipeline.attack.density-guided False --pipeline.attack.view-noise False" in gt_only
    assert "--max-num-iterations 30" in gt_only and gt_only.endswith("scenes/orbit-seed0")
    assert not (tmp_path / "out").exists()


def test_all_tables_share_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ../shared/data/fox here: the default scenes skip it
    plan = bench_plan(tmp_path, iterations=30)  # scenes absent: KDE views are placeholders
    assert plan.scenes == ("orbit", "forward", "facing")
    assert plan.skipped_scenes == [
        "skipping fox: ../shared/data/fox not found (a dataset folder of the default --scenes; "
        "give --scenes fox=PATH to use it from elsewhere)"
    ]
    keys = [p.key for p in plan.runs]
    # the paper's runs of orbit
    orbit_runs = [r for r in RUNS if r.scene == "orbit" and not r.name.startswith(("st-", "ad-"))]
    # orbit: 17 in-loop runs + data-only, ipa, ipa-views-2/3/4; a KDE scene: 4 + ipa-easy/median/hard,
    # data-only-median
    assert len(keys) == len(set(keys)) == 38 == len(orbit_runs) + 2 * 8
    assert keys[0] == "orbit/clean" and keys[22] == "forward/clean" and keys[30] == "facing/clean"
    full = plan.get("orbit/full")
    assert full.tables == (1, 4, 5, 6)
    assert plan.get("forward/median").tables == (1, 2) == plan.get("facing/median").tables
    assert plan.get("facing/easy").tables == (2,)
    assert plan.get("orbit/ipa").tables == (1,) == plan.get("orbit/data-only").tables
    assert plan.get("orbit/ipa-views-3").tables == (3,) == plan.get("orbit/views-3").tables
    assert plan.get("forward/ipa-median").tables == (1, 2) == plan.get("facing/ipa-median").tables
    assert plan.get("forward/data-only-median").tables == (1,) and plan.get("facing/ipa-easy").tables == (2,)
    assert len({p.spec.run_dir for p in plan.runs}) == 38
    # the dataset attacks' copies: one folder per run, beside the runs
    copies = [p.poison.output for p in plan.runs if p.poison is not None]
    assert len(copies) == len(set(copies)) == 5 + 2 * 4
    assert all(c.parent.parent == tmp_path / "poisoned" for c in copies)
    # one run per distinct setting: no two presets of a scene train the same thing
    settings = {(r.scene, r.attack, r.view, r.poisoning, r.poison_attack) for r in RUNS}
    # orbit 22 + 10 of the stealth tables (2 more are Tables 3 and 5's); forward / facing / fox 8, 6 of
    # Table 3 and 11 of the stealth tables (st-views-2 is Table 3's views-2) each
    assert len(settings) == len(RUNS) == 139  # + Table 9's eight adaptive runs on each of the 4 scenes
    easy = plan.get("forward/easy")
    assert "<EASY view of the KDE protocol>" in easy.spec.options
    assert easy.spec.attack.config().views == ("<EASY view of the KDE protocol>",)
    assert plan.get("forward/ipa-easy").view == "<EASY view of the KDE protocol>"
    assert len(bench_plan(tmp_path, scenes=["orbit"], iterations=30).runs) == 22
    assert [p.key for p in bench_plan(tmp_path, tables=["2"], scenes=["forward"], iterations=30).runs] == [
        "forward/clean", "forward/easy", "forward/median", "forward/hard",
        "forward/ipa-easy", "forward/ipa-median", "forward/ipa-hard",
    ]  # fmt: skip
    # Table 1 and 2 columns: orbit, forward, facing, fox (Table 1: fox's Median view, like forward)
    assert [g.label.split()[0] for g in get_table(1).groups] == ["orbit", "forward", "facing", "fox"]
    assert [r.keys for r in get_table(1).rows] == [
        ("Naive 3DGS (w/o attack)",), ("IPA-Splat",), ("Ours (data-only)",), ("Ours (in-loop)",),
    ]  # fmt: skip
    assert get_table(1).rows[1].runs == ("ipa", "ipa-median", "ipa-median", "ipa-median")
    assert get_table(1).rows[2].runs == ("data-only", *["data-only-median"] * 3)
    assert get_table(1).rows[3].runs == ("full", "median", "median", "median")
    assert [g.label for g in get_table(2).groups][-3:] == ["fox Easy", "fox Median", "fox Hard"]


def ranked_forward_scene(out: Path, monkeypatch) -> SimpleNamespace:
    """OUTPUT with a forward scene on disk whose KDE views are fixed (no rendering, no ranking):
    ``scene`` (its folder) and ``ranking`` (easy / median / hard)."""
    from stealth_ns.difficulty import rank as difficulty

    scene = scene_dir(out, "forward", 0)
    scene.mkdir(parents=True)
    (scene / "transforms.json").write_text("{}")
    (scene / "scene.json").write_text(json.dumps({"preset": "forward", "seed": 0}))
    ranking = SimpleNamespace(easy="frame_00003.png", median="frame_00020.png", hard="frame_00041.png")
    monkeypatch.setattr(difficulty, "rank_scene_views", lambda data: ranking)
    return SimpleNamespace(scene=scene, ranking=ranking)


def test_kde_views_go_on_the_command_line(tmp_path, monkeypatch):
    ranking = ranked_forward_scene(tmp_path, monkeypatch).ranking
    plan = bench_plan(tmp_path, tables=["1", "2"], scenes=["forward"], iterations=30)
    assert plan.views["forward"] == {
        "easy": "frame_00003.png",
        "median": "frame_00020.png",
        "hard": "frame_00041.png",
    }
    for level in ("easy", "median", "hard"):
        options = plan.get(f"forward/{level}").spec.options
        assert options[options.index("--pipeline.attack.views") + 1] == getattr(ranking, level)
    assert "--pipeline.attack.views" not in plan.get("forward/clean").spec.options
    # a dataset attack's view goes to its poisoning command, not to the victim's ns-train
    for name, level in [("ipa-easy", "easy"), ("ipa-median", "median"), ("ipa-hard", "hard"),
                        ("data-only-median", "median")]:  # fmt: skip
        planned = plan.get(f"forward/{name}")
        assert "--pipeline.attack.views" not in planned.spec.options
        assert _arg(planned.poison.command(), "--views") == getattr(ranking, level) == planned.view
    assert [t.number for t in plan.tables] == [1, 2]


# ------------------------------------------------------------------------------ running
def test_second_invocation_reuses_finished_runs(tmp_path, fakes, capsys):
    out = tmp_path / "out"
    results = run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert fakes.training.trained == [k.split("/")[1] for k in TABLE6_ORDER]
    assert sorted(fakes.compare.calls) == sorted(["gt-only", "gt-density", "gt-noise", "full"])
    assert results["complete"] and all(e["status"] == "trained" for e in results["runs"].values())
    saved = json.loads((out / "results.json").read_text())
    assert saved["environment"]["iterations"] == 30 and saved["environment"]["method"] == "stealth-splat-lite"
    assert all(isinstance(e["train_seconds"], float) for e in saved["runs"].values())
    assert saved["runs"]["orbit/full"]["metrics"]["v_illusory_psnr"] == 27.5
    for key in TABLE6_ORDER:
        marker = json.loads((Path(saved["runs"][key]["run_dir"]) / runs.MARKER).read_text())
        assert marker["final_checkpoint"] == "nerfstudio_models/step-000000029.ckpt"

    md = (out / "tables.md").read_text()
    table6 = md.split("## Table 6")[1].split("## ")[0]
    rows = [line for line in table6.splitlines() if line.startswith("| ✓")]
    assert [r.split("|")[1:4] for r in rows] == [
        [" ✓ ", "  ", "  "], [" ✓ ", " ✓ ", "  "], [" ✓ ", "  ", " ✓ "], [" ✓ ", " ✓ ", " ✓ "],
    ]  # fmt: skip
    assert [r.rstrip(" |").split("|")[-1].strip() for r in rows] == ["0/1", "0/1", "0/1", "1/1"]
    assert "**27.50**" in rows[3] and "LPIPS shown as –: no AlexNet weights" in table6
    stealth = md.split("## Stealth under the post-hoc defences")[1].split("## ")[0]
    rows = {line.split(" | ")[0][2:]: line for line in stealth.splitlines() if line.startswith("| orbit/")}
    assert set(rows) == {"orbit/gt-only", "orbit/gt-density", "orbit/gt-noise", "orbit/full"}  # no clean run
    assert rows["orbit/full"].endswith("| 26.00 | none | yes |")
    assert rows["orbit/gt-only"].endswith("| 12.00 | view-support | no |")

    capsys.readouterr()
    fakes.training.trained.clear()
    fakes.compare.calls.clear()
    again = run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert fakes.training.trained == [] and fakes.compare.calls == []  # runs and metrics reused
    assert all(e["status"] == "reused" for e in again["runs"].values())
    assert all(e["metrics_cached"] for k, e in again["runs"].items() if k != "orbit/clean")
    assert (
        "0 to train, 0 unfinished on disk (deleted and retrained), 5 finished (reused)"
        in capsys.readouterr().out
    )

    # metrics cached before the stealth was measured (no version in the stamp) are computed again
    cache = Path(again["runs"]["orbit/full"]["run_dir"]) / METRICS_FILE
    data = json.loads(cache.read_text())
    del data["stamp"]["version"], data["metrics"]["stealth"]
    cache.write_text(json.dumps(data))
    third = run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert fakes.compare.calls == ["full"] and "stealth" in third["runs"]["orbit/full"]["metrics"]

    # Table 4 on the same output reuses orbit/clean and orbit/full (h = 7.5)
    plan = bench_plan(out, tables=["4"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert {p.key: p.status for p in plan.runs if p.status == "finished"} == {
        "orbit/clean": "finished", "orbit/full": "finished",
    }  # fmt: skip


def test_interrupted_run_is_retrained(tmp_path, fakes, capsys):
    out = tmp_path / "out"
    run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    plan = bench_plan(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    gt_noise = plan.get("orbit/gt-noise").spec
    # an interrupted ns-train: folder, config and an early checkpoint, but no marker
    (gt_noise.run_dir / runs.MARKER).unlink()
    (gt_noise.run_dir / "nerfstudio_models" / "step-000000029.ckpt").rename(
        gt_noise.run_dir / "nerfstudio_models" / "step-000000010.ckpt"
    )
    assert run_status(gt_noise) == "partial"
    capsys.readouterr()
    run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY, dry_run=True)
    listing = capsys.readouterr().out
    assert "1 unfinished on disk" in listing and "[retrain] orbit/gt-noise" in listing

    fakes.training.trained.clear()
    fakes.compare.calls.clear()
    run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert fakes.training.trained == ["gt-noise"] and fakes.compare.calls == ["gt-noise"]
    assert not (gt_noise.run_dir / "nerfstudio_models" / "step-000000010.ckpt").exists()
    assert is_finished(gt_noise)


def test_failed_run_is_reported_and_the_rest_still_runs(tmp_path, monkeypatch, fakes, capsys):
    fakes.training.fail = {"gt-density"}
    out = tmp_path / "out"
    with pytest.raises(StealthNSError, match=r"1 of 5 runs failed \(orbit/gt-density\)"):
        run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    captured = capsys.readouterr()
    failed = [line for line in captured.out.splitlines() if line.startswith("[3/5] FAILED orbit/gt-density")]
    assert len(failed) == 1 and failed[0].endswith("gt-density/ns-train.log")
    saved = json.loads((out / "results.json").read_text())
    assert not saved["complete"] and saved["runs"]["orbit/gt-density"]["status"] == "failed"
    assert saved["runs"]["orbit/full"]["status"] == "trained"
    md = (out / "tables.md").read_text()
    assert "**Incomplete**" in md and "n/a: no numbers for orbit/gt-density" in md


def test_failed_comparison_is_reported_and_retried(tmp_path, monkeypatch, fakes):
    compare = fakes.compare

    def flaky(poisoned_config, clean_config):
        if Path(poisoned_config).parent.name == "gt-noise":
            print("chatty nerfstudio output")
            raise RuntimeError("cannot render")
        return compare(poisoned_config, clean_config)

    from stealth_ns.report import numbers as report

    monkeypatch.setattr(report, "compare_runs", flaky)
    out = tmp_path / "out"
    with pytest.raises(StealthNSError, match=r"1 of 5 runs failed \(orbit/gt-noise \(metrics\)\)"):
        run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    saved = json.loads((out / "results.json").read_text())
    entry = saved["runs"]["orbit/gt-noise"]
    assert entry["status"] == "trained" and "RuntimeError: cannot render" in entry["metrics_error"]
    log = (Path(entry["run_dir"]) / METRICS_LOG).read_text()
    assert "chatty nerfstudio output" in log and "Traceback" in log

    monkeypatch.setattr(report, "compare_runs", compare)
    compare.calls.clear()
    again = run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert compare.calls == ["gt-noise"] and again["complete"]
    assert fakes.training.trained.count("gt-noise") == 1  # the run itself was reused


def test_failed_poisoned_copy_fails_only_its_run(tmp_path, fakes, capsys):
    """A copy that cannot be made fails its victim run only; the next invocation makes it and trains
    that run alone (the other copy and every finished run reused)."""
    fakes.poison.fail = {"ipa"}
    out = tmp_path / "out"
    with pytest.raises(StealthNSError, match=r"1 of 4 runs failed \(orbit/ipa\)"):
        run_bench(out, tables=["1"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert fakes.poison.made == ["ipa", "data-only"]  # made after the scene, before any training
    assert fakes.training.trained == ["clean", "full", "data-only"]
    assert sorted(fakes.compare.calls) == ["data-only", "full"]
    captured = capsys.readouterr().out
    reason = "its poisoned dataset could not be made: ipa failed (CUDA error: out of memory"
    lines = captured.splitlines()
    making = [i for i, line in enumerate(lines) if line.startswith(f"FAILED orbit/ipa: {reason}")]
    training = [i for i, line in enumerate(lines) if line.startswith(f"[3/4] FAILED orbit/ipa: {reason}")]
    assert len(making) == len(training) == 1 and making[0] < training[0]
    assert captured.index("poisoning orbit/data-only") < captured.index("[1/4] training orbit/clean")
    saved = json.loads((out / "results.json").read_text())
    assert not saved["complete"] and saved["runs"]["orbit/ipa"]["status"] == "failed"
    assert reason in saved["runs"]["orbit/ipa"]["error"]
    data_only = saved["runs"]["orbit/data-only"]
    copy = out / "poisoned" / f"{scene_dir(out, 'orbit', 0, TINY).name}-30it" / "data-only"
    assert data_only["status"] == "trained" and data_only["metrics"]["v_illusory_psnr"] == 26.0
    assert data_only["command"][-3:] == ["nerfstudio-data", "--data", str(copy)]
    assert (copy / "transforms.json").is_file() and not (copy.parent / "ipa").exists()
    table1 = (out / "tables.md").read_text().split("## Table 1")[1].split("## ")[0]
    rows = {line.split("|")[1].strip(): line for line in table1.splitlines() if line.startswith("| ")}
    assert rows["IPA-Splat"].startswith("| IPA-Splat | n/a |") and "n/a: no numbers for orbit/ipa" in table1
    assert rows["Ours (data-only)"].startswith("| Ours (data-only) | 26.00 |")
    assert rows["Ours (in-loop)"].startswith("| Ours (in-loop) | **27.50** |")

    fakes.poison.fail.clear()
    fakes.poison.calls.clear()
    fakes.training.trained.clear()
    again = run_bench(out, tables=["1"], scenes=["orbit"], iterations=30, scene_options=TINY)
    assert fakes.poison.made == ["ipa"] and fakes.training.trained == ["ipa"]
    assert again["complete"] and again["runs"]["orbit/ipa"]["status"] == "trained"
    assert {k: e["status"] for k, e in again["runs"].items() if k != "orbit/ipa"} == {
        "orbit/clean": "reused", "orbit/full": "reused", "orbit/data-only": "reused",
    }  # fmt: skip


# ------------------------------------------------------------------------------ the tables
def _fake_entry(ill: float, test: float, clean_test: float, lpips: float | None) -> dict:
    return {
        "metrics": {
            "v_illusory_psnr": ill, "v_illusory_ssim": 0.81, "v_illusory_lpips": lpips,
            "v_illusory_clean_psnr": 13.21, "v_illusory_clean_ssim": 0.521, "v_illusory_clean_lpips": lpips,
            "v_test_psnr": test, "v_test_ssim": 0.805, "v_test_lpips": lpips,
            "v_test_psnr_clean": clean_test, "v_test_ssim_clean": 0.883, "v_test_lpips_clean": lpips,
            "v_test_drop": clean_test - test, "attack_success": ill > 25 and clean_test - test <= 3,
            "lpips_unavailable": None if lpips is not None else "LPIPS weights missing",
            "poisoned_views": ["frame_00026.png"], "n_gaussians": 10, "n_poison_gaussians": 2,
        }
    }  # fmt: skip


def test_table_rendering_from_fake_results():
    runs_ = {
        "orbit/full": _fake_entry(27.04, 27.76, 29.45, 0.369),
        "forward/median": _fake_entry(26.66, 25.25, 26.80, None),
    }
    t1 = table_data(get_table(1), runs_, ("orbit", "forward"))
    assert len(t1["columns"]) == 12 and t1["columns"][0]["label"].startswith("orbit (360°")
    naive, ipa, data_only, ours = t1["rows"]
    assert naive["keys"] == ["Naive 3DGS (w/o attack)"] and naive["values"][0] == 13.21
    assert naive["values"][3] == 29.45 and ours["values"][:4] == [27.04, 0.81, 0.369, 27.76]
    assert ours["values"][8] is None and t1["lpips_unavailable"] == ["LPIPS weights missing"]
    assert ipa["keys"] == ["IPA-Splat"] and ipa["runs"] == ["orbit/ipa", "forward/ipa-median"]
    assert data_only["keys"] == ["Ours (data-only)"]
    assert data_only["runs"] == ["orbit/data-only", "forward/data-only-median"]
    assert ipa["values"] == data_only["values"] == ["n/a"] * 12  # no such runs in runs_
    assert t1["missing_runs"] == [
        "forward/data-only-median", "forward/ipa-median", "orbit/data-only", "orbit/ipa",
    ]  # fmt: skip

    t6 = table_data(get_table(6), runs_, ("orbit",))
    assert [r["asr"] for r in t6["rows"]] == ["n/a", "n/a", "n/a", "1/1"]
    assert t6["missing_runs"] == ["orbit/gt-density", "orbit/gt-noise", "orbit/gt-only"]

    results = {
        "environment": {"method": "stealth-splat-lite", "iterations": 3000, "seed": 0, "date": "today"},
        "scenes": {"orbit": {"resolution": [128, 96], "views": 60}},
        "runs": runs_,
        "tables": {"6": t6, "1": t1},
        "complete": True,
    }
    md = render_markdown(results)
    assert md.index("## Table 1") < md.index("## Table 6") < md.index("## All runs")
    # the header says what is not implemented: IPA-NeRF only (IPA-Splat has rows now)
    assert NOT_IMPLEMENTED in md and "IPA-NeRF (Instant-NGP) baselines" in md
    assert "IPA-Splat" not in NOT_IMPLEMENTED
    table1 = md.split("## Table 1")[1].split("## ")[0]
    lines = [line for line in table1.splitlines() if line.startswith("| ")]
    assert lines[0].startswith("| Method | orbit (360°, Mip-NeRF 360-like) V-illusory PSNR↑ |")
    assert lines[1].startswith("| Naive 3DGS (w/o attack) | 13.21 | 0.521 | 0.369 | 29.45 |")
    assert lines[2] == "| IPA-Splat |" + " n/a |" * 12
    assert lines[3] == "| Ours (data-only) |" + " n/a |" * 12
    assert lines[4].startswith(
        "| Ours (in-loop) | 27.04 | 0.810 | 0.369 | 27.76 | 0.805 | 0.369 | 26.66 | 0.810 | – |"
    )
    assert "LPIPS shown as –: LPIPS weights missing" in table1
    assert "- IPA-Splat: `stealth-ns ipa-poison`" in table1 and "IPA-NeRF (Nerfacto / Instant-NGP)" in table1
    assert "is not implemented: no rows" in table1 and "IPA-Splat are not implemented" not in table1
    assert "- Ours (data-only): `stealth-ns poison-dataset`" in table1
    assert "n/a: no numbers for forward/data-only-median, forward/ipa-median, orbit/data-only" in table1
    assert "| orbit/full |" in md.split("## All runs")[1]


def test_table_specs_are_consistent():
    names = {(r.scene, r.name) for r in RUNS}
    assert [t.number for t in TABLES] == [1, 2, 3, 4, 5, 6, 7, 8, 9]
    by_key = {(r.scene, r.name): r for r in RUNS}
    method_rows: list[tuple[int, tuple[str, ...]]] = []
    for table in TABLES:
        for row in table.rows:
            assert len(row.runs) == len(table.groups)
            assert all((g.scene, name) in names for g, name in zip(table.groups, row.runs, strict=True))
            # a row's method is what its runs are: IPA-Splat rows show ipa-poison victims, the
            # data-only rows poison-dataset victims, every other row in-loop attacks (or clean runs)
            kinds = {by_key[g.scene, name].poisoning for g, name in zip(table.groups, row.runs, strict=True)}
            expected = {"IPA-Splat": "ipa", "Ours (data-only)": "data-only"}.get(row.keys[-1], "")
            assert kinds == {expected}, (table.number, row.keys)
            if expected:
                method_rows.append((table.number, row.keys))
        labels = " ".join(" ".join(r.keys) for r in table.rows)
        assert "IPA-NeRF" not in labels  # not implemented: no rows pretend to be it
    assert method_rows == [
        (1, ("IPA-Splat",)), (1, ("Ours (data-only)",)), (2, ("IPA-Splat",)),
        (3, ("2", "IPA-Splat")), (3, ("3", "IPA-Splat")), (3, ("4", "IPA-Splat")),
    ]  # fmt: skip
    # a dataset attack is a plain victim (attack off) poisoned at the same view(s) as its Ours row
    for run in RUNS:
        if run.poisoning:
            assert run.attack == CLEAN and not run.clean, run.key
    for k in (2, 3, 4):
        assert by_key["orbit", f"ipa-views-{k}"].poison_attack == AttackSettings.of(multi_view=k)
    for scene in ("forward", "facing", "fox"):
        for level in ("easy", "median", "hard"):
            assert by_key[scene, f"ipa-{level}"].view == level == by_key[scene, level].view
        assert by_key[scene, "data-only-median"].view == "median"
    assert get_table(6).run_keys() == ["orbit/gt-only", "orbit/gt-density", "orbit/gt-noise", "orbit/full"]
    # the stealth tables: Table 1's in-loop run first, then one run per setting, the poisoned view of
    # Table 1 (the KDE Median view); a uniform scene reuses Tables 3 and 5's runs
    for number in (7, 8, 9):
        table = get_table(number)
        assert table.rows[0].runs == get_table(1).rows[-1].runs
        for row in table.rows[1:]:
            for g, name in zip(table.groups, row.runs, strict=True):
                run = by_key[g.scene, name]
                assert run.view == ("median-index" if g.scene == "orbit" else "median") and not run.poisoning
    support = [f"orbit/st-support-{k}" for k in (3, 4, 5, 6)]
    assert get_table(7).run_keys(("orbit",)) == ["orbit/full", *support, "orbit/st-surface"]
    assert "orbit/views-2" in get_table(8).run_keys() and "fox/views-2" in get_table(8).run_keys()


def test_table_3_takes_dataset_folders_not_presets():
    table = get_table(3).for_scenes(("orbit", "forward", "facing", "fox", "mine"))
    assert table.scenes == ("orbit", "fox", "mine")
    assert table.run_keys(("mine",)) == [f"mine/{m}views-{k}" for k in (2, 3, 4) for m in ("ipa-", "")]
    views = get_run("mine", "views-3")
    assert views.view == "median" and views.attack == attack_settings(multi_view=3)
    ipa = get_run("mine", "ipa-views-4")
    assert (
        ipa.view == "median"
        and ipa.poisoning == "ipa"
        and ipa.poison_attack == AttackSettings.of(multi_view=4)
    )
    assert get_run("orbit", "views-2").view == "median-index"
    # Table 8's two-view row is Table 3's run on every scene, not a second training of it
    assert stealth_run("mine", "st-views-2") == "views-2" == stealth_run("orbit", "st-views-2")
    assert (
        stealth_run("fox", "st-sigma-30") == "st-sigma-30"
        and stealth_run("orbit", "st-sigma-30") == "sigma30-linear"
    )


def test_only_plans_the_matching_runs_and_their_clean_baselines(tmp_path, capsys):
    plan = bench_plan(
        tmp_path,
        tables=["1", "3"],
        scenes=["orbit", "forward"],
        iterations=30,
        only=["views-2", "forward/median"],
    )
    assert [p.key for p in plan.runs] == [
        "orbit/clean", "orbit/ipa-views-2", "orbit/views-2", "forward/clean", "forward/median",
    ]  # fmt: skip
    assert plan.only == ("views-2", "forward/median")
    assert "only:    runs whose name contains views-2 or forward/median" in plan.describe(dry_run=True)
    with pytest.raises(StealthNSError, match=r"--only views-9 matches none of the tables' runs: orbit/"):
        bench_plan(tmp_path, tables=["3"], scenes=["orbit"], iterations=30, only=["views-9"])


# ------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"tables": ["10"]}, "unknown table '10'"),
        ({"tables": ["six"]}, "unknown table 'six'"),
        ({"scenes": ["garden"]}, "unknown scene 'garden'"),
        ({"tables": ["2"], "scenes": ["orbit"]}, "nothing to run: Table 2 skipped"),
        (
            {"tables": ["9"], "scenes": ["orbit"], "attacks": ["data-only"]},
            "Table 9 skipped: it has no data-only runs",
        ),
        ({"method": "splatfacto"}, "unknown method 'splatfacto'"),
        ({"iterations": 0}, "iterations must be a positive integer"),
        ({"seed": -1}, "seed must be a non-negative integer"),
    ],
)
def test_bad_input_is_an_error(tmp_path, kwargs, message):
    kwargs = {"iterations": 30, **kwargs}
    with pytest.raises(StealthNSError, match=message):
        bench_plan(tmp_path, **kwargs)


def test_cli_dry_run_and_one_line_errors(tmp_path):
    out = tmp_path / "o"
    proc = run_cli(
        "stealth-ns", "bench", "attack", "--dry-run", "--tables", "6", "--scenes", "orbit",
        "--iterations", "30", "--output", str(out),
    )  # fmt: skip
    assert "5 runs: 5 to train" in proc.stdout and not out.exists()
    proc = run_cli("stealth-ns", "bench", "attack", "--tables", "10", "--dry-run", check=False)
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0
    assert "unknown table '10'" in proc.stderr
    assert "bench attack" in run_cli("stealth-ns", "--help").stdout


# ------------------------------------------------------------------------------ dataset folders
@pytest.fixture(scope="module")
def tiny_forward(tmp_path_factory) -> Path:
    """A tiny generated forward scene (with its seed points)."""
    from stealth_ns.scene_generator import make_scene

    out = tmp_path_factory.mktemp("folder") / "forward_tiny"
    make_scene(preset="forward", output=out, resolution="64x48", views=16, seed=0)
    return out


def _snapshot(folder: Path) -> dict[str, str]:
    return {
        str(f.relative_to(folder)): hashlib.sha256(f.read_bytes()).hexdigest()
        for f in sorted(folder.rglob("*"))
        if f.is_file()
    }


@pytest.fixture
def folder_scene(tiny_forward, tmp_path):
    """A copy of the tiny scene as a user's dataset without seed points (no ply_file_path), read-only;
    and its seed points, kept aside for the fake make_seed_points."""
    folder = tmp_path / "data" / "mine"
    shutil.copytree(tiny_forward, folder)
    meta = json.loads((folder / "transforms.json").read_text())
    del meta["ply_file_path"]
    (folder / "transforms.json").write_text(json.dumps(meta, indent=2))
    ply = tmp_path / "stash.ply"
    shutil.move(folder / "sparse_pc.ply", ply)
    (folder / "scene.json").unlink()  # a user's folder, not a generated scene
    for f in [folder, *folder.rglob("*")]:
        f.chmod(0o555 if f.is_dir() else 0o444)
    yield SimpleNamespace(path=folder, ply=ply, snapshot=_snapshot(folder))
    for f in [folder, *folder.rglob("*")]:
        f.chmod(0o755 if f.is_dir() else 0o644)


class FakeSeedPoints:
    """Stands in for stealth_ns.datasets.seed_points.make_seed_points: a seeded copy whose images are the
    original ones (absolute paths), with the stashed point cloud."""

    def __init__(self, ply: Path) -> None:
        self.ply = ply
        self.calls: list[tuple[Path, Path]] = []

    def __call__(self, data, output=None, overwrite=False, max_points=None, seed=0):
        data, output = Path(data), Path(output)
        self.calls.append((data, output))
        assert overwrite and output != data
        meta = json.loads((data / "transforms.json").read_text())
        for frame in meta["frames"]:
            frame["file_path"] = str(data / frame["file_path"])
            frame.pop("depth_file_path", None)
        for split in ("train", "val", "test"):
            if f"{split}_filenames" in meta:
                meta[f"{split}_filenames"] = [str(data / f) for f in meta[f"{split}_filenames"]]
        meta["ply_file_path"] = "sparse_pc.ply"
        output.mkdir(parents=True, exist_ok=True)
        shutil.copy(self.ply, output / "sparse_pc.ply")
        (output / "transforms.json").write_text(json.dumps(meta))
        return SimpleNamespace(dataset=output, ply=output / "sparse_pc.ply", n_points=1234, seconds=0.5)


@pytest.fixture
def fake_seed_points(folder_scene, monkeypatch):
    from stealth_ns.datasets import seed_points

    fake = FakeSeedPoints(folder_scene.ply)
    monkeypatch.setattr(seed_points, "make_seed_points", fake)
    return fake


def test_folder_scene_dry_run_plans_its_seed_points(folder_scene, fake_seed_points, tmp_path, capsys):
    out = tmp_path / "out"
    spec = f"mine={folder_scene.path}"
    plan = run_bench(out, tables=["1", "2"], scenes=["orbit", spec], iterations=30, dry_run=True)
    assert plan.scenes == ("orbit", "mine")
    assert [p.key for p in plan.runs] == [
        "orbit/clean", "orbit/full", "orbit/ipa", "orbit/data-only",
        "mine/clean", "mine/median", "mine/ipa-median", "mine/data-only-median",
        "mine/easy", "mine/hard", "mine/ipa-easy", "mine/ipa-hard",
    ]  # fmt: skip
    text = capsys.readouterr().out
    assert f"scene:   mine -> {folder_scene.path}  (nerfstudio-data, no seed points; used in place" in text
    assert f"seed points: triangulated into {out / 'scenes' / 'mine'}  (to be made first)" in text
    median = next(
        line for line in text.splitlines() if "--experiment-name mine-seed0-30it --timestamp median" in line
    )
    assert median.endswith(f"nerfstudio-data --data {out / 'scenes' / 'mine'}")
    assert "--pipeline.attack.views '<MEDIAN view of the KDE protocol>'" in median
    # its dataset attacks poison the seeded copy (not the user's folder)
    ipa = next(line for line in text.splitlines() if "stealth-ns ipa-poison" in line and "ipa-median" in line)
    copy = out / "poisoned" / "mine-seed0-30it" / "ipa-median"
    assert f"--data {out / 'scenes' / 'mine'} --output {copy} --overwrite" in ipa
    assert ipa.endswith("--views '<MEDIAN view of the KDE protocol>'")
    # Tables 1 and 2 get columns for the folder, like fox's
    t1, t2 = plan.tables
    assert [g.scene for g in t1.groups][-1] == "mine" and t1.rows[3].runs[-1] == "median"
    assert t1.rows[1].runs[-1] == "ipa-median" and t1.rows[2].runs[-1] == "data-only-median"
    assert [g.label for g in t2.groups][-3:] == ["mine Easy", "mine Median", "mine Hard"]
    assert fake_seed_points.calls == [] and not out.exists()
    assert _snapshot(folder_scene.path) == folder_scene.snapshot


def test_folder_scene_runs_on_its_seeded_copy(folder_scene, fake_seed_points, fakes, tmp_path, capsys):
    """Seed points made once into OUTPUT/scenes/NAME (the folder untouched), KDE views ranked on the
    seeded copy, runs trained on it, the source recorded; the second invocation reuses all of it."""
    out = tmp_path / "out"
    spec = f"mine={folder_scene.path}"
    results = run_bench(out, tables=["1", "2"], scenes=[spec], iterations=30)
    seeded = out / "scenes" / "mine"
    assert fake_seed_points.calls == [(folder_scene.path, seeded)]
    assert _snapshot(folder_scene.path) == folder_scene.snapshot  # the user's data is never written
    marker = json.loads((out / "scenes" / f"mine{SEED_POINTS_MARKER}").read_text())
    assert marker["source"] == str(folder_scene.path) and marker["n_points"] == 1234
    assert fakes.training.trained == [
        "clean", "median", "ipa-median", "data-only-median", "easy", "hard", "ipa-easy", "ipa-hard",
    ]  # fmt: skip
    # the dataset attacks' copies are made from the seeded copy, before the trainings
    assert fakes.poison.made == ["ipa-median", "data-only-median", "ipa-easy", "ipa-hard"]
    assert {job.source for job in fakes.poison.calls} == {seeded}
    scene = results["scenes"]["mine"]
    sha = hashlib.sha256((folder_scene.path / "transforms.json").read_bytes()).hexdigest()
    assert scene["source"] == "folder" and scene["path"] == str(folder_scene.path)
    assert scene["content_sha256"] == sha and scene["format"] == "nerfstudio-data"
    assert scene["seed_points"] == "triangulated" and scene["seed_points_made"]["n_points"] == 1234
    assert scene["dataset"] == str(seeded) and scene["views"] == 16
    views = scene["kde_views"]  # the real KDE protocol on the seeded copy
    assert set(views) == {"easy", "median", "hard"} and all(v.startswith("frame_") for v in views.values())
    for level in ("easy", "median", "hard"):
        cmd = results["runs"][f"mine/{level}"]["command"]
        assert _arg(cmd, "--pipeline.attack.views") == views[level]
        assert cmd[-3:] == ["nerfstudio-data", "--data", str(seeded)]
        # IPA-Splat at the same view: the view went to ipa-poison, the victim trains on the copy
        copy = out / "poisoned" / "mine-seed0-30it" / f"ipa-{level}"
        job = next(job for job in fakes.poison.calls if job.output == copy)
        assert job.kind == "ipa" and job.view == views[level] and job.ready()
        cmd = results["runs"][f"mine/ipa-{level}"]["command"]
        assert "--pipeline.attack.views" not in cmd and cmd[-3:] == ["nerfstudio-data", "--data", str(copy)]
    env = results["environment"]
    assert {"torch", "nerfstudio", "gsplat", "numpy", "pycolmap"} <= set(env)
    md = (out / "tables.md").read_text()
    assert "mine (dataset folder) V-illusory PSNR↑" in md and "mine Hard V-illusory PSNR↑" in md

    capsys.readouterr()
    fakes.training.trained.clear()
    again = run_bench(out, tables=["1", "2"], scenes=[spec], iterations=30)
    assert len(fake_seed_points.calls) == 1 and fakes.training.trained == []  # all reused
    assert len(fakes.poison.calls) == 4  # the copies too
    assert "(done: 1234 points, reused" in capsys.readouterr().out
    assert again["scenes"]["mine"]["kde_views"] == views
    # the record gone: the seed points are made again (and the runs, same data, still reused)
    (out / "scenes" / f"mine{SEED_POINTS_MARKER}").unlink()
    run_bench(out, tables=["1"], scenes=[spec], iterations=30)
    assert len(fake_seed_points.calls) == 2 and fakes.training.trained == []


def test_failed_seed_points_fail_only_that_scenes_runs(folder_scene, fakes, tmp_path, monkeypatch, capsys):
    from stealth_ns.datasets import seed_points

    def broken(data, output=None, overwrite=False, max_points=None, seed=0):
        raise StealthNSError("triangulation gave no points")

    monkeypatch.setattr(seed_points, "make_seed_points", broken)
    out = tmp_path / "out"
    failed_runs = r"mine/clean, mine/median, mine/ipa-median, mine/data-only-median"
    with pytest.raises(StealthNSError, match=rf"4 of 8 runs failed \({failed_runs}\)"):
        run_bench(out, tables=["1"], scenes=["orbit", f"mine={folder_scene.path}"], iterations=30,
                  scene_options=TINY)  # fmt: skip
    assert fakes.training.trained == ["clean", "full", "ipa", "data-only"]  # orbit's runs went on
    assert fakes.poison.made == ["ipa", "data-only"]  # no copies of a scene that cannot be used
    captured = capsys.readouterr()
    assert "FAILED mine: making its seed points failed: triangulation gave no points" in captured.err
    saved = json.loads((out / "results.json").read_text())
    assert saved["runs"]["mine/median"]["status"] == "failed"
    assert "triangulation gave no points" in saved["scenes"]["mine"]["error"]


def test_default_scenes_skip_a_missing_fox(tmp_path, monkeypatch, capsys):
    from stealth_ns.bench.command_line import BenchAttack
    from stealth_ns.cli import main

    assert BenchAttack.scenes == DEFAULT_SCENES == ("orbit", "forward", "facing", "fox=../shared/data/fox")
    monkeypatch.chdir(tmp_path)
    main([*"bench attack --dry-run --tables 1 --iterations 30 --output".split(), str(tmp_path / "o")])
    out = capsys.readouterr().out
    assert out.splitlines()[0] == (
        "skipping fox: ../shared/data/fox not found (a dataset folder of the default --scenes; "
        "give --scenes fox=PATH to use it from elsewhere)"
    )
    assert "12 runs: 12 to train" in out and "fox/" not in out  # 3 scenes x clean, IPA, data-only, in-loop
    # named explicitly, a missing folder is an error
    for scenes in (["fox"], ["orbit", "fox=../shared/data/fox"]):
        with pytest.raises(StealthNSError, match=r"^scene fox: \.\./shared/data/fox not found$"):
            bench_plan(tmp_path, tables=["1"], scenes=scenes, iterations=30)
    # "all" is the default list: the missing folder is skipped
    assert bench_plan(tmp_path, tables=["1"], scenes=["all"], iterations=30).scenes == (
        "orbit", "forward", "facing",
    )  # fmt: skip


def test_colmap_and_blender_folders(tmp_path, monkeypatch):
    from stealth_ns.difficulty import rank as difficulty

    colmap = tmp_path / "garden"
    (colmap / "sparse" / "0").mkdir(parents=True)
    (colmap / "images").mkdir()
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        (colmap / "sparse" / "0" / name).write_text(f"# {name}\n")
    blender = tmp_path / "lego"
    blender.mkdir()
    (blender / "transforms_train.json").write_text('{"camera_angle_x": 0.69, "frames": []}')
    ranking = SimpleNamespace(easy="a.png", median="b.png", hard="c.png")
    ranked: list[Path] = []
    monkeypatch.setattr(difficulty, "rank_scene_views", lambda data: ranked.append(Path(data)) or ranking)
    from stealth_ns.bench import scenes as bench_scenes

    monkeypatch.setattr(bench_scenes, "check_source", lambda src: None)  # placeholder files: planning only

    plan = bench_plan(
        tmp_path / "out", tables=["1"], scenes=[f"garden={colmap}", f"lego={blender}"], iterations=30
    )
    assert plan.scenes == ("garden", "lego") and ranked == [colmap]  # lego has no seed points yet
    cmd = plan.get("garden/median").spec.command()
    assert cmd[-7:] == [
        "colmap",
        "--data",
        str(colmap),
        "--colmap-path",
        "sparse/0",
        "--downscale-factor",
        "1",
    ]
    assert _arg(cmd, "--pipeline.attack.views") == "b.png"
    assert plan.sources["garden"].seed_points == "colmap" and plan.scene_ready["garden"]
    lego = plan.get("lego/clean").spec.command()
    assert _arg(lego, "--pipeline.model.background-color") == "white"
    assert lego[-3:] == ["nerfstudio-data", "--data", str(tmp_path / "out" / "scenes" / "lego")]
    assert plan.sources["lego"].triangulated and plan.sources["lego"].format == "blender"
    # run identities: a folder's name and content hash (other data under the same name is not reused)
    assert plan.get("garden/clean").spec.identity()["scene"] == f"garden:{plan.sources['garden'].sha256[:16]}"
    assert plan.get("garden/clean").spec.identity()["dataparser"][0] == "colmap"


@pytest.mark.parametrize(
    ("scenes", "message"),
    [
        (["mine={missing}"], r"^scene mine: .*nowhere not found$"),
        (["mine={empty}"], r"^scene mine: unknown dataset format in .*: no transforms.json"),
        (["mine={file}"], r"^scene mine: .* is not a folder"),
        (["mine={good}", "mine={good}"], r"^scene 'mine' is given twice in --scenes$"),
        (["fox", "fox={good}"], r"^scene 'fox' is given twice"),
        (["orbit={good}"], r"^scene name 'orbit' .* is taken by the generated preset orbit"),
        (["forward-seed0={good}"], r"taken by the generated preset forward"),
        (["mine="], r"^no folder given for scene 'mine'"),
        (["my/scene={good}"], r"^bad scene name 'my/scene'"),
        (["all={good}"], r"^bad scene name 'all'"),
        (["mine={noframes}"], r"is not a nerfstudio transforms.json"),
        (["mine={badply}"], r"the ply_file_path 'points.ply' of .* does not exist"),
        (["mine={colmap_noimages}"], r"has a COLMAP model in sparse/0 but no images/ folder"),
        # what ns-train's start-up check would refuse, before any run is planned (issue 32)
        (["mine={good}"], r"^scene mine: .*frame 0 \(images/a.png\): transform_matrix must be"),
    ],
)
def test_bad_scene_specs_are_one_line_errors(tmp_path, scenes, message):
    dirs = {name: tmp_path / name for name in ("empty", "good", "noframes", "badply", "colmap_noimages")}
    for d in dirs.values():
        d.mkdir()
    (dirs["good"] / "transforms.json").write_text('{"frames": [{"file_path": "images/a.png"}]}')
    (dirs["noframes"] / "transforms.json").write_text('{"frames": []}')
    (dirs["badply"] / "transforms.json").write_text('{"frames": [{}], "ply_file_path": "points.ply"}')
    (dirs["colmap_noimages"] / "sparse" / "0").mkdir(parents=True)
    (dirs["colmap_noimages"] / "sparse" / "0" / "cameras.bin").write_bytes(b"")
    (tmp_path / "file").write_text("")
    paths = {**dirs, "missing": tmp_path / "nowhere", "file": tmp_path / "file"}
    with pytest.raises(StealthNSError, match=message) as err:
        bench_plan(tmp_path / "out", tables=["1"], scenes=[s.format(**paths) for s in scenes], iterations=30)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ runs/training.py
def test_train_spec_paths_and_finished_semantics(tmp_path, monkeypatch):
    spec = TrainSpec(
        scene=tmp_path / "scene", name="r", output_dir=tmp_path / "runs", experiment="e", iterations=5
    )
    assert spec.run_dir == tmp_path / "runs" / "e" / "stealth-splat-lite" / "r"
    assert spec.config_path == spec.run_dir / "config.yml"
    for bad in ("", "..", "a/b"):
        with pytest.raises(StealthNSError, match="plain folder name"):
            TrainSpec(scene=tmp_path, name=bad, output_dir=tmp_path)
    assert run_status(spec) == "missing"
    # a folder with a final checkpoint but no marker is not finished (ns-train may not have exited 0)
    (spec.run_dir / "nerfstudio_models").mkdir(parents=True)
    (spec.config_path).write_text("max_num_iterations: 5\n")
    (spec.run_dir / "nerfstudio_models" / "step-000000004.ckpt").write_bytes(b"")
    assert run_status(spec) == "partial"

    fake = FakeTraining()
    monkeypatch.setattr(runs, "run_command", fake)
    record = train(spec, stream=False)
    assert record.trained_now and record.iterations == 5 and is_finished(spec)
    assert not train(spec, stream=False).trained_now and fake.trained == ["r"]
    # other settings under the same name, or other iterations: not this run
    assert not is_finished(TrainSpec(**{**spec.__dict__, "extra": ("--x", "1")}))
    assert not is_finished(TrainSpec(**{**spec.__dict__, "attack": AttackSettings.of(seed=1)}))
    assert not is_finished(TrainSpec(**{**spec.__dict__, "iterations": 6}))
    assert is_finished(TrainSpec(**{**spec.__dict__, "iterations": None}))
    (spec.run_dir / "nerfstudio_models" / "step-000000004.ckpt").unlink()
    assert run_status(spec) == "partial"


def test_attacked_runs_of_another_noise_generator_are_not_reused(tmp_path, monkeypatch):
    """A training that draws view noise records the generator; a marker without it (an earlier version's
    Mersenne Twister draws) is retrained. Runs that draw none keep their identity (reused)."""
    base = {"scene": tmp_path / "scene", "name": "r", "output_dir": tmp_path / "runs", "iterations": 5}
    attacked, clean = TrainSpec(**base), TrainSpec(**base, attack=AttackSettings.of(enabled=False))
    assert attacked.identity()["view_noise"] == NOISE_GENERATOR
    assert "view_noise" not in clean.identity()
    assert clean.identity()["extra"] == ["--pipeline.attack.enabled", "False"]
    for attack in (
        AttackSettings.of(enabled=False),
        AttackSettings.of(view_noise=False),
        AttackSettings.of(noise_sigma0=0.0),
        AttackSettings.of(view_noise=False, noise_sigma0=30.0),
        AttackSettings.of(noise_sigma0=30.0, enabled=True).then(enabled=False),  # the last one counts
    ):
        assert not TrainSpec(**base, attack=attack).draws_view_noise(), attack
    assert TrainSpec(**base, attack=AttackSettings.of(noise_sigma0=30.0)).draws_view_noise()
    assert TrainSpec(
        **base, attack=AttackSettings.of(view_noise=False).then(view_noise=True)
    ).draws_view_noise()
    assert not TrainSpec(**base, method="splatfacto").draws_view_noise()
    # the attack's options are typed settings, never strings in extra (which nothing reads back)
    with pytest.raises(ValueError, match="TrainSpec.attack"):
        TrainSpec(**base, extra=("--pipeline.attack.enabled", "False"))

    monkeypatch.setattr(runs, "run_command", FakeTraining())
    train(attacked, stream=False)
    assert is_finished(attacked)
    marker = json.loads(attacked.marker_path.read_text())
    del marker["identity"]["view_noise"]  # as an earlier version wrote it
    attacked.marker_path.write_text(json.dumps(marker))
    assert not is_finished(attacked)


@pytest.mark.slow
def test_real_tiny_training_is_finished_then_reused(tiny_orbit_scene, tmp_path):
    """The runner's ns-train command for the full attack, on the tiny scene, for 30 iterations."""
    plan = bench_plan(tmp_path, tables=["6"], scenes=["orbit"], iterations=30)
    full = plan.get("orbit/full").spec
    spec = TrainSpec(**{**full.__dict__, "scene": tiny_orbit_scene})
    record = train(spec, stream=False)
    assert record.trained_now and record.iterations == 30 and is_finished(spec)
    assert (spec.run_dir / "nerfstudio_models" / "step-000000029.ckpt").is_file()
    assert "--pipeline.attack.bandwidth 7.5" in (spec.run_dir / runs.TRAIN_LOG).read_text().splitlines()[0]
    assert (spec.run_dir / "attack" / "attack.json").is_file()
    again = train(spec, stream=False)
    assert not again.trained_now and again.run_id == record.run_id


def test_demo_reuses_finished_runs_and_rewrites_the_report(tmp_path, monkeypatch):
    from stealth_ns import demo
    from stealth_ns.report import write as report_module

    training, reports = FakeTraining(), []

    def fake_report(poisoned, clean, output):
        reports.append((Path(poisoned).parent.name, Path(clean).parent.name, output))
        return {"fake": True}

    scene = tmp_path / f"scene-{demo.DEMO_PRESET}"
    scene.mkdir()
    (scene / "transforms.json").write_text("{}")  # the demo only generates a missing scene
    monkeypatch.setattr(runs, "run_command", training)
    monkeypatch.setattr(report_module, "write_report", fake_report)
    first = demo.run_demo(tmp_path, iterations=7)
    assert sorted(training.trained) == ["clean", "poisoned"]  # side by side, half the cores each
    half = str(max(1, (os.cpu_count() or 2) // 2))
    assert training.envs == {"clean": {"OMP_NUM_THREADS": half}, "poisoned": {"OMP_NUM_THREADS": half}}
    assert reports == [("poisoned", "clean", tmp_path / "report")]
    assert first.poisoned == tmp_path / "runs" / "demo" / "stealth-splat-lite" / "poisoned" / "config.yml"
    assert (tmp_path / "train-clean.log").is_file() and set(first.seconds) == {
        "scene",
        "clean",
        "poisoned",
        "report",
    }
    again = demo.run_demo(tmp_path, iterations=7)
    assert len(training.trained) == 2 and len(reports) == 2
    assert again.seconds["clean"] == again.seconds["poisoned"] == 0.0
