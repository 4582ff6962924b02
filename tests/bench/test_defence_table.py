"""Table D of ``stealth-ns bench attack --defend``: wiring with fake trainings and a fake defend
(the real defend runs end to end in test_defend.py)."""

from __future__ import annotations

import json
from pathlib import Path

from test_bench_attack import TINY, fake_poison, fakes  # noqa: F401  (the fixtures)

from stealth_ns.bench.attack import run_bench
from stealth_ns.bench.defence_table import TABLE_KEY, table_data
from stealth_ns.defence_eval import command as defend_module
from stealth_ns.defence_eval.arguments import check_arguments
from stealth_ns.defences.config import DEFENCES, DefendConfig


def _fake_result(run: Path) -> dict:
    entry = {
        "kind": "post-hoc",
        "auroc": 0.9,
        "average_precision": 0.5,
        "operating_point": {"poison_removed": 0.75, "v_illusory_psnr": 12.5, "v_test_cost": 0.2},
    }
    return {
        "run": str(run),
        "undefended": {"v_illusory_psnr": 27.5, "v_test_psnr": 26.0},
        "defences": {name: dict(entry) for name in DEFENCES},
    }


def test_bench_defend_adds_table_d_and_reuses_it(tmp_path, fakes, monkeypatch, capsys):  # noqa: F811
    calls = []

    def fake_defend(run, output, cfg=None, clean=None):
        check_arguments(Path(run), Path(output), DefendConfig(), Path(clean))  # the real one's guard
        calls.append((Path(run).parent.name, Path(clean).parent.name))
        return _fake_result(run)

    monkeypatch.setattr(defend_module, "run_defend", fake_defend)
    out = tmp_path / "out"
    results = run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY, defend=True)
    assert "1" in results["tables"]  # --defend brings Table 1's runs
    assert calls == [("full", "clean")]
    table = results["table_d"]
    assert table["scenes"] == ["orbit"] and [r["defence"] for r in table["rows"]] == list(DEFENCES)
    assert table["rows"][0]["cells"]["orbit"] == ["0.900", "0.500", "75.0%", "12.50", "0.20"]
    md = (out / "tables.md").read_text()
    assert "## Table D: stealth under defences" in md
    assert "| none (undefended) |  |  |  | 27.50 | 0.00 |" in md
    saved = json.loads((out / "results.json").read_text())
    assert saved["table_d"]["rows"][0]["cells"]["orbit"][3] == "12.50"
    defend_json = json.loads((out / "defend" / "orbit" / "defend.json").read_text())
    assert defend_json["bench_stamp"]["settings"]["defences"] == list(DEFENCES)

    calls.clear()
    again = run_bench(out, tables=["6"], scenes=["orbit"], iterations=30, scene_options=TINY, defend=True)
    assert calls == [] and again["table_d"] == table  # the same run and settings: reused


def test_table_d_marks_missing_scenes():
    data = table_data({"orbit": None}, {"orbit": "its Table 1 runs did not finish"})
    assert data["rows"][0]["cells"]["orbit"] == ["n/a"] * 5
    assert data["undefended_v_illusory"] == {"orbit": "n/a"}
    assert TABLE_KEY == "D"
