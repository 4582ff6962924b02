"""The bench's poisoned copies (:mod:`stealth_ns.bench.poisoned_copies`) and how the plan wires
them: a dataset attack's victim trains on ``OUTPUT/poisoned/EXP-ITERSit/NAME``, made first by
``stealth-ns ipa-poison`` / ``poison-dataset``. Nothing here runs a real poisoning command (runs of
the bench with fake trainings and fake copies are in test_bench_attack.py)."""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import tyro
from test_bench_attack import ranked_forward_scene

from stealth_ns.attack.normal_draw import NOISE_GENERATOR
from stealth_ns.attack.options import AttackSettings
from stealth_ns.bench import poisoned_copies
from stealth_ns.bench.attack import run_bench
from stealth_ns.bench.plan import bench_plan
from stealth_ns.bench.poisoned_copies import PoisonJob, ensure_copies
from stealth_ns.cli import COMMANDS
from stealth_ns.datasets.generated import scene_dir
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.method_configs.attack_experiments import CLEAN
from stealth_ns.poisoned_datasets.config import data_only_attack_defaults
from stealth_ns.runs.training import bin_path
from stealth_ns.scene_generator import make_scene

VIEW = "frame_00003.png"


def _arg(cmd: list[str], flag: str) -> str:
    return cmd[cmd.index(flag) + 1]


def _job(tmp_path: Path, kind: str = "ipa", **changes) -> PoisonJob:
    job = PoisonJob(
        kind, tmp_path / "scene", tmp_path / "poisoned" / "exp" / "ipa-easy", VIEW, AttackSettings(),
        "stealth-splat-lite", 0, 30,
    )  # fmt: skip
    return dataclasses.replace(job, **changes)


def _write_copy(job: PoisonJob, complete: bool = True, identity: dict | None = None) -> None:
    """What a finished make leaves: the copy's attack record and the marker beside the copy."""
    (job.output / "attack").mkdir(parents=True, exist_ok=True)
    record = {"poisoned_dataset": {"complete": complete}}
    (job.output / "attack" / "attack.json").write_text(json.dumps(record))
    write_json_atomic(job.marker, job.identity() if identity is None else identity)


# ------------------------------------------------------------------------------ PoisonJob
def test_identity_and_scene_id_follow_the_settings(tmp_path):
    job = _job(tmp_path)
    assert job.identity() == {
        "kind": "ipa", "source": "scene", "view": VIEW, "args": [],
        "method": "stealth-splat-lite", "seed": 0, "iterations": 30,
    }  # fmt: skip
    assert job.scene_id.startswith("poisoned-ipa:") and len(job.scene_id) == len("poisoned-ipa:") + 16
    assert job.scene_id == _job(tmp_path).scene_id  # deterministic
    # every setting that makes another copy gives another scene id (so the victim run is not reused)
    changed = [
        {"view": "frame_00009.png"}, {"view": None}, {"attack": AttackSettings.of(multi_view=2)},
        {"attack": AttackSettings.of(multi_view=3)}, {"seed": 1}, {"method": "stealth-splat"},
        {"source": tmp_path / "other"}, {"iterations": 31}, {"kind": "data-only"},
    ]  # fmt: skip
    ids = {job.scene_id, *(_job(tmp_path, **c).scene_id for c in changed)}
    assert len(ids) == len(changed) + 1
    # where the copy goes is not what it is
    assert _job(tmp_path, output=tmp_path / "elsewhere").scene_id == job.scene_id

    # data-only: the attacker does not train, so the iterations are not part of it
    data_only = _job(tmp_path, kind="data-only")
    assert "iterations" not in data_only.identity() and data_only.scene_id.startswith("poisoned-data-only:")
    assert _job(tmp_path, kind="data-only", iterations=3000).scene_id == data_only.scene_id
    assert _job(tmp_path, kind="data-only", seed=1).scene_id != data_only.scene_id
    assert _job(tmp_path, kind="data-only", view=None).scene_id != data_only.scene_id
    # static view noise: the generator is part of what the copy was made from
    noisy = _job(tmp_path, kind="data-only", attack=AttackSettings.of(view_noise=True, noise_sigma0=30.0))
    assert noisy.identity()["view_noise"] == NOISE_GENERATOR and "view_noise" not in data_only.identity()
    assert noisy.identity()["args"] == [
        "--view-noise",
        "--noise-sigma0",
        "30",
    ]  # as poison-dataset spells them
    # poison-dataset's own default is no noise: only settings that turn it on make noise
    quiet = _job(tmp_path, kind="data-only", attack=AttackSettings.of(noise_sigma0=30.0))
    assert "view_noise" not in quiet.identity()
    off = _job(tmp_path, kind="data-only", attack=AttackSettings.of(view_noise=True).then(view_noise=False))
    assert "view_noise" not in off.identity() and off.args == ("--view-noise", "--no-view-noise")


def test_marker_and_log_sit_beside_the_copy(tmp_path):
    job = _job(tmp_path)
    assert job.marker == tmp_path / "poisoned" / "exp" / "ipa-easy.poison.json"
    assert job.log == tmp_path / "poisoned" / "exp" / "ipa-easy.poison.log"


def test_ready_needs_a_complete_copy_made_from_the_same_settings(tmp_path):
    job = _job(tmp_path)
    assert not job.ready()  # nothing on disk
    job.output.mkdir(parents=True)
    write_json_atomic(job.marker, job.identity())
    assert not job.ready()  # a marker but no attack record in the copy
    _write_copy(job, complete=False)
    assert not job.ready()  # a copy whose making was interrupted
    _write_copy(job)
    assert job.ready()
    # the same copy for other settings: not ready (it would be made again)
    for other in (_job(tmp_path, seed=1), _job(tmp_path, view=None), _job(tmp_path, iterations=60)):
        assert other.output == job.output and not other.ready()
    _write_copy(job, identity={**job.identity(), "seed": 7})
    assert not job.ready()
    # a broken marker, or none
    job.marker.write_text("{not json")
    assert not job.ready()
    job.marker.unlink()
    assert not job.ready()
    # an attack record without the poisoned_dataset part (a run's record, say)
    _write_copy(job)
    (job.output / "attack" / "attack.json").write_text(json.dumps({"views": [VIEW]}))
    assert not job.ready()


def test_command_of_each_kind(tmp_path):
    ipa = _job(tmp_path, attack=AttackSettings.of(multi_view=2))
    cmd = ipa.command()
    assert cmd[0] == bin_path("stealth-ns") and cmd[1] == "ipa-poison"
    assert _arg(cmd, "--data") == str(tmp_path / "scene") and _arg(cmd, "--output") == str(ipa.output)
    assert "--overwrite" in cmd and _arg(cmd, "--method") == "stealth-splat-lite"
    assert _arg(cmd, "--seed") == "0"
    assert _arg(cmd, "--iterations") == "30" and _arg(cmd, "--views") == VIEW
    assert cmd[-2:] == ["--multi-view", "2"]  # the run's own options last
    assert _job(tmp_path, view=None).command().count("--views") == 0  # the attack's default view
    # a short bench gets one attack epoch half-way (ipa-poison refuses --every >= --iterations);
    # a full-length one keeps the paper's 200 steps per epoch
    assert _arg(cmd, "--every") == "15"
    assert "--every" not in _job(tmp_path, iterations=3000).command()

    data_only = _job(tmp_path, kind="data-only", seed=3)
    cmd = data_only.command()
    assert cmd[1] == "poison-dataset" and "--overwrite" in cmd and _arg(cmd, "--seed") == "3"
    assert "--iterations" not in cmd and _arg(cmd, "--views") == VIEW
    assert "--views" not in _job(tmp_path, kind="data-only", view=None).command()

    # shown with the command name, quoted for a shell
    placeholder = _job(tmp_path, view="<MEDIAN view of the KDE protocol>")
    assert placeholder.display_command().startswith(f"stealth-ns ipa-poison --data {tmp_path / 'scene'} ")
    assert placeholder.display_command().endswith("--views '<MEDIAN view of the KDE protocol>'")


@pytest.mark.parametrize(
    ("kind", "view", "attack"),
    [
        ("ipa", VIEW, AttackSettings()),
        ("ipa", None, AttackSettings.of(multi_view=3)),
        ("data-only", VIEW, AttackSettings()),
        ("data-only", None, AttackSettings()),
        ("data-only", None, AttackSettings.of(view_noise=True, noise_sigma0=30.0, density_guided=False)),
        ("data-only", VIEW, AttackSettings.of(support_views=2, t_min=0.25, injection_step=0)),
    ],
)
def test_command_parses_as_the_cli_command(tmp_path, kind, view, attack):
    """The bench's command line is one the real `stealth-ns` command accepts, with the job's settings."""
    job = _job(tmp_path, kind=kind, view=view, attack=attack, seed=2)
    cmd = job.command()
    parsed = tyro.cli(COMMANDS[cmd[1]], args=cmd[2:], prog=f"stealth-ns {cmd[1]}")
    assert parsed.data == job.source and parsed.output == job.output and parsed.overwrite
    assert parsed.method == job.method
    views = () if view is None else (view,)
    if kind == "ipa":
        assert parsed.seed == 2 and parsed.iterations == 30 and parsed.views == views
        assert parsed.multi_view == attack.config().multi_view
    else:
        assert parsed.attack.seed == 2 and parsed.attack.views == views and parsed.attack.enabled
        expected = attack.config(data_only_attack_defaults())
        assert dataclasses.replace(parsed.attack, seed=0, views=()) == expected


def test_make_runs_the_command_and_writes_the_marker_only_on_success(tmp_path, monkeypatch):
    job = _job(tmp_path)
    script = "print('loading'); print('stealth-ns: error: no such view frame_00003.png'); print('bye')"
    monkeypatch.setattr(PoisonJob, "command", lambda self: [sys.executable, "-c", script + "; exit(2)"])
    with pytest.raises(RuntimeError, match=r"^ipa-poison failed \(stealth-ns: error: no such view") as err:
        job.make()
    assert str(job.log) in str(err.value)
    assert "loading" in job.log.read_text() and not job.marker.exists()

    monkeypatch.setattr(PoisonJob, "command", lambda self: [sys.executable, "-c", "print('ok')"])
    job.make()
    command = shlex.join([sys.executable, "-c", "print('ok')"])
    assert (
        json.loads(job.marker.read_text()) == job.identity() and job.log.read_text() == f"$ {command}\nok\n"
    )


def test_make_reports_the_last_line_when_no_line_says_error(tmp_path, monkeypatch):
    job = _job(tmp_path, kind="data-only")
    monkeypatch.setattr(PoisonJob, "command", lambda self: [sys.executable, "-c", "print('killed'); exit(9)"])
    with pytest.raises(RuntimeError, match=r"^poison-dataset failed \(killed; log: "):
        job.make()


def test_ensure_copies_makes_what_is_not_ready_and_reports_failures(tmp_path, monkeypatch):
    jobs = {
        "orbit/ipa": _job(tmp_path, output=tmp_path / "p" / "ipa"),
        "orbit/data-only": _job(tmp_path, kind="data-only", output=tmp_path / "p" / "data-only"),
        "orbit/ipa-views-2": _job(
            tmp_path, output=tmp_path / "p" / "ipa-views-2", attack=AttackSettings.of(multi_view=2)
        ),
    }
    _write_copy(jobs["orbit/data-only"])  # made earlier: reused
    made: list[str] = []

    def make(self):
        made.append(self.output.name)
        if self.output.name == "ipa-views-2":
            raise RuntimeError("ipa-poison failed (CUDA error: out of memory; log: x.log)")
        _write_copy(self)

    monkeypatch.setattr(PoisonJob, "make", make)
    lines: list[str] = []
    errors = ensure_copies(jobs, echo=lambda line, flush=False: lines.append(line))
    assert made == ["ipa", "ipa-views-2"]
    assert errors == {
        "orbit/ipa-views-2": "its poisoned dataset could not be made: ipa-poison failed (CUDA error: out of "
        "memory; log: x.log)"
    }
    assert lines[0].startswith("poisoning orbit/ipa: IPA-Splat (the attacker trains first) -> ")
    assert lines[-1].startswith("FAILED orbit/ipa-views-2: its poisoned dataset could not be made")
    assert jobs["orbit/ipa"].ready() and not jobs["orbit/ipa-views-2"].ready()
    made.clear()
    assert ensure_copies({k: jobs[k] for k in ("orbit/ipa", "orbit/data-only")}, echo=print) == {}
    assert made == []


# ------------------------------------------------------------------------------ the plan
@pytest.fixture
def ranked_forward(tmp_path, monkeypatch):
    """OUTPUT with a forward scene on disk whose KDE views are fixed (no rendering, no ranking)."""
    out = tmp_path / "out"
    ranked = ranked_forward_scene(out, monkeypatch)
    return SimpleNamespace(out=out, scene=ranked.scene, ranking=ranked.ranking)


def test_dry_run_plans_the_poisoned_copies(ranked_forward, capsys):
    out, forward = ranked_forward.out, ranked_forward.scene
    plan = run_bench(out, tables=["1"], scenes=["orbit", "forward"], iterations=30, dry_run=True)
    assert [p.key for p in plan.runs] == [
        "orbit/clean", "orbit/full", "orbit/ipa", "orbit/data-only",
        "forward/clean", "forward/median", "forward/ipa-median", "forward/data-only-median",
    ]  # fmt: skip
    orbit = scene_dir(out, "orbit", 0)
    poisoned = {p.key: p for p in plan.runs if p.run.poisoning}
    assert list(poisoned) == [
        "orbit/ipa", "orbit/data-only", "forward/ipa-median", "forward/data-only-median",
    ]  # fmt: skip
    for key, p in poisoned.items():
        scene, name = key.split("/")
        source = orbit if scene == "orbit" else forward
        copy = out / "poisoned" / f"{source.name}-30it" / name
        assert p.poison is not None and p.poison.output == copy and p.poison.source == source
        assert p.poison.kind == ("ipa" if name.startswith("ipa") else "data-only")
        # the victim: a plain run (attack off) on the copy, beside the scene's other runs
        assert p.spec.scene == copy and p.spec.scene_id == p.poison.scene_id
        assert p.spec.experiment == plan.get(f"{scene}/clean").spec.experiment
        assert p.spec.attack == CLEAN and p.spec.options == ("--pipeline.attack.enabled", "False")
        assert p.spec.command()[-3:] == ["nerfstudio-data", "--data", str(copy)]
        assert p.status == "missing" and not p.poison.ready()
    assert poisoned["orbit/ipa"].poison.view is None and poisoned["orbit/ipa"].view is None
    ipa_median = poisoned["forward/ipa-median"]
    assert ipa_median.poison.view == "frame_00020.png" == ipa_median.view
    assert poisoned["forward/data-only-median"].poison.view == "frame_00020.png"
    # the in-loop runs still carry their view and seed
    median = plan.get("forward/median").spec.options
    assert _arg(list(median), "--pipeline.attack.views") == "frame_00020.png"
    assert _arg(list(median), "--pipeline.attack.seed") == "0"

    text = capsys.readouterr().out
    assert "8 runs: 8 to train" in text
    lines = text.splitlines()
    ipa_line = next(i for i, line in enumerate(lines) if f"ipa-poison --data {forward} " in line)
    assert lines[ipa_line].strip() == (
        f"poisoned dataset (made first): stealth-ns ipa-poison --data {forward} --output "
        f"{out / 'poisoned' / 'forward-seed0-30it' / 'ipa-median'} --overwrite --method stealth-splat-lite "
        "--seed 0 --iterations 30 --every 15 --views frame_00020.png"
    )
    victim = lines[ipa_line + 1].strip()  # its ns-train line right after
    assert victim.startswith("ns-train stealth-splat-lite ") and "--timestamp ipa-median" in victim
    assert victim.endswith(f"--data {out / 'poisoned' / 'forward-seed0-30it' / 'ipa-median'}")
    assert "--pipeline.attack.enabled False" in victim and victim.count("--pipeline.attack") == 1
    orbit_ipa = next(line for line in lines if f"ipa-poison --data {orbit} " in line)
    assert "--iterations 30" in orbit_ipa and "--views" not in orbit_ipa  # the median-indexed frame
    data_only = [line.strip() for line in lines if "stealth-ns poison-dataset" in line]
    assert len(data_only) == 2 and data_only[1].endswith("--seed 0 --views frame_00020.png")
    assert not any("--iterations" in line for line in data_only)
    assert not (out / "poisoned").exists()  # a dry run makes nothing

    # a copy made earlier (its marker matches, its record complete) is reused
    _write_copy(poisoned["forward/ipa-median"].poison)
    run_bench(out, tables=["1"], scenes=["orbit", "forward"], iterations=30, dry_run=True)
    text = capsys.readouterr().out
    assert text.count("poisoned dataset (reused): stealth-ns ipa-poison") == 1
    assert text.count("poisoned dataset (made first): ") == 3


def test_victim_identity_changes_with_the_poisoning(ranked_forward):
    """Another seed or iteration count poisons differently: another copy, another victim run."""
    out = ranked_forward.out
    plan = bench_plan(out, tables=["1"], scenes=["forward"], iterations=30)
    other_seed = bench_plan(out, tables=["1"], scenes=["forward"], iterations=30, seed=1)
    other_iters = bench_plan(out, tables=["1"], scenes=["forward"], iterations=40)
    for key in ("forward/ipa-median", "forward/data-only-median"):
        ids = {p.get(key).spec.identity()["scene"] for p in (plan, other_seed, other_iters)}
        assert len(ids) == (3 if "ipa" in key else 2)  # data-only's copy does not depend on iterations
        assert plan.get(key).poison.output != other_seed.get(key).poison.output  # seed in the folder name
    # two runs of a scene never share a copy
    copies = [p.poison.output for p in plan.runs if p.poison is not None]
    assert len(copies) == len(set(copies)) == 2


def test_poisoned_copies_module_constants():
    assert poisoned_copies.COMMANDS == {"data-only": "poison-dataset", "ipa": "ipa-poison"}
    assert set(poisoned_copies.COMMANDS.values()) <= set(COMMANDS)


def test_copies_are_named_by_content_not_path(tmp_path, monkeypatch):
    """A moved output folder keeps its copies and victims; a dataset folder whose files change does not."""
    monkeypatch.chdir(tmp_path)
    one = bench_plan(tmp_path / "out1", tables=["1"], scenes=["orbit"], iterations=30).get("orbit/ipa")
    two = bench_plan(tmp_path / "out2", tables=["1"], scenes=["orbit"], iterations=30).get("orbit/ipa")
    assert one.poison.identity() == two.poison.identity() and one.spec.identity() == two.spec.identity()
    folder = tmp_path / "mine"
    make_scene(preset="facing", output=folder, resolution="32x24", views=8, seed=0)

    def ipa_identity() -> dict:
        plan = bench_plan(
            tmp_path / "out1", tables=["1"], scenes=[f"mine={folder}"], iterations=30, rank_views=False
        )
        return plan.get("mine/ipa-median").poison.identity()

    before = ipa_identity()
    meta = json.loads((folder / "transforms.json").read_text())
    meta["frames"][0]["transform_matrix"][0][3] += 0.5
    (folder / "transforms.json").write_text(json.dumps(meta))
    assert ipa_identity()["source"] != before["source"]


def test_attacks_option_plans_and_shows_only_those_rows(tmp_path):
    plan = bench_plan(tmp_path, tables=["1", "3"], scenes=["orbit"], iterations=30, attacks=["in-loop"])
    assert [p.key for p in plan.runs] == [
        "orbit/clean",
        "orbit/full",
        "orbit/views-2",
        "orbit/views-3",
        "orbit/views-4",
    ]
    assert [r.keys for r in plan.tables[0].rows] == [("Naive 3DGS (w/o attack)",), ("Ours (in-loop)",)]
    ipa = bench_plan(tmp_path, tables=["1"], scenes=["orbit"], iterations=30, attacks=["ipa"])
    # the naive row scores the clean run at the in-loop run's poisoned views: that run stays planned
    assert [p.key for p in ipa.runs] == ["orbit/clean", "orbit/full", "orbit/ipa"] and ipa.attacks == ("ipa",)
    with pytest.raises(StealthNSError, match="--attacks takes some of in-loop, data-only, ipa"):
        bench_plan(tmp_path, tables=["1"], scenes=["orbit"], iterations=30, attacks=["nope"])
