"""Stealth as a measured property (:mod:`stealth_ns.defence_eval.stealth`): which cut is a defence's
strongest, when an attack counts as defeated, stealthy success, and the bench's stealth table."""

from __future__ import annotations

import pytest

from stealth_ns.bench.tables import stealth_table
from stealth_ns.defence_eval.stealth import cuts, stealth_line, stealth_summary, strongest_cut


def _point(
    ill: float | None, cost: float | None, fraction: float | None = None, removed: float = 0.5
) -> dict:
    p = {"v_illusory_psnr": ill, "v_test_cost": cost, "poison_removed": removed}
    if fraction is not None:
        p["fraction"] = fraction
    return p


def _entry(op: dict, curve: list[dict], auroc: float | None = 0.9) -> dict:
    return {"kind": "post-hoc", "rule": "score > 0.5", "auroc": auroc, "operating_point": op, "curve": curve}


def test_the_strongest_cut_is_the_lowest_v_illusory_within_the_cost():
    entry = _entry(
        _point(20.0, 0.1),
        [
            _point(30.0, 0.0, 0.0),  # the unpruned model: not a cut
            _point(18.0, 0.4, 0.01),
            _point(9.0, 0.51, 0.1),  # cheapest V-illusory, but over 0.5 dB of V-test
            _point(None, 0.2, 0.3),  # not measured
        ],
    )
    assert [label for label, _ in cuts(entry)] == [
        "rule (score > 0.5)", "prune 1.0%", "prune 10.0%", "prune 30.0%",
    ]  # fmt: skip
    assert strongest_cut(entry) == {
        "cut": "prune 1.0%", "v_illusory_psnr": 18.0, "v_test_cost": 0.4, "poison_removed": 0.5,
    }  # fmt: skip
    assert strongest_cut(entry, max_cost=1.0)["v_illusory_psnr"] == 9.0
    assert strongest_cut(_entry(_point(10.0, 2.0), [_point(5.0, 3.0, 0.1)])) is None


def test_defeated_by_any_cut_and_stealthy_success():
    defences = {
        "view-support": _entry(_point(16.0, 0.0), [_point(14.9, 0.5, 0.03)], auroc=0.99),  # defeats at 0.5 dB
        "zscore": _entry(_point(10.0, 4.0), [_point(22.0, 0.2, 0.01)], auroc=0.7),  # too costly to defeat
        "input-filter": {"kind": "training-time", "operating_point": _point(5.0, 0.0)},  # no cuts: left out
    }
    s = stealth_summary(defences, attack_success=True)
    assert s["auroc"] == {"view-support": 0.99, "zscore": 0.7}
    assert s["defeated_by"] == ["view-support"] and not s["stealthy"] and s["stealthy_success"] is False
    assert s["strongest_defence"] == "view-support" and s["v_illusory_after_strongest"] == 14.9
    assert s["strongest_cut"]["zscore"]["v_illusory_psnr"] == 22.0
    assert "defeated by view-support; stealthy success: no" in stealth_line(s)
    assert "view-support 0.990" in stealth_line(s) and "V-illusory 14.90 dB" in stealth_line(s)

    survives = {"view-support": _entry(_point(26.0, 0.0), [_point(15.0, 0.3, 0.03)], auroc=None)}
    s = stealth_summary(survives, attack_success=True)
    assert s["stealthy"] and s["stealthy_success"] and s["defeated_by"] == []
    assert s["auroc"] == {"view-support": None} and "AUROC n/a" in stealth_line(s)
    assert stealth_summary(survives, attack_success=False)["stealthy_success"] is False
    nothing = stealth_summary({}, attack_success=True)
    assert nothing["strongest_defence"] is None and nothing["v_illusory_after_strongest"] is None
    assert (
        stealth_line({"unavailable": "--no-stealth was given"})
        == "stealth: not measured (--no-stealth was given)"
    )


def test_bench_stealth_table_lists_attacked_runs_only():
    stealth = stealth_summary(
        {
            "view-support": _entry(_point(12.0, 0.0), [], auroc=0.95),
            "grad-concentration": _entry(_point(30.0, 0.0), [], auroc=0.5),
        },
        attack_success=True,
    )
    runs = {
        "orbit/clean": {"clean": True, "metrics": None},
        "orbit/full": {"metrics": {"v_illusory_psnr": 30.0, "v_test_drop": 0.5, "attack_success": True,
                                   "stealth": stealth}},
        "orbit/victim": {"metrics": {"v_illusory_psnr": 27.0, "v_test_drop": 0.4, "attack_success": True,
                                     "stealth": {"unavailable": "no stealth-splat model"}}},
        "orbit/failed": {"metrics": None},
    }  # fmt: skip
    md = stealth_table(runs)
    rows = [line for line in md.splitlines() if line.startswith("| orbit/")]
    assert [r.split(" | ")[0] for r in rows] == ["| orbit/full", "| orbit/victim"]
    assert rows[0].endswith("| 0.950 | 0.500 | view-support | 12.00 | view-support | no |")
    assert "n/a (no stealth-splat model)" in rows[1]
    assert stealth_table({"orbit/clean": {"clean": True}}) == ""


@pytest.mark.parametrize("stealthy", [True, False])
def test_html_shows_the_stealth_section(stealthy):
    from test_report_html import _report

    from stealth_ns.report.html import render_html

    ill = 26.0 if stealthy else 9.5
    report = _report()
    report["stealth"] = stealth_summary(
        {"grad-concentration": _entry(_point(ill, 0.01), [], auroc=0.97)}, attack_success=True
    )
    page = render_html(report)
    assert "Stealth under the post-hoc defences" in page
    assert f"stealthy success: {'yes' if stealthy else 'no'}" in page
    assert ("no post-hoc defence defeats it" in page) == stealthy
    assert "0.970" in page and f"{ill:.3f}" in page
    report["stealth"] = {"unavailable": "--no-stealth was given"}
    assert "Not measured: --no-stealth was given" in render_html(report)


def test_the_stealth_plot_shows_every_measured_attacked_run(tmp_path):
    from stealth_ns.bench.stealth_plot import plot_stealth, stealth_points

    def run(auroc_vs, auroc_gc, ill, stealthy, scene="orbit", **extra):
        stealth = {"auroc": {"view-support": auroc_vs, "grad-concentration": auroc_gc, "zscore": 0.99}}
        metrics = {"v_illusory_psnr": ill, "stealthy_success": stealthy, "stealth": stealth}
        return {"scene": scene, "metrics": metrics, **extra}

    runs = {
        "orbit/clean": {"clean": True, "scene": "orbit"},
        "orbit/full": run(0.85, 0.96, 30.2, False),
        "orbit/st-support-6": run(0.48, 0.61, 26.7, True),
        "fox/victim": run(None, None, 30.0, False, scene="fox"),  # a victim of a poisoned dataset: no tag
        "fox/broken": {"scene": "fox", "metrics": {"stealth": {"unavailable": "not measured"}}},
    }
    points = stealth_points(runs)
    assert [p["key"] for p in points] == ["orbit/full", "orbit/st-support-6", "fox/victim"]
    assert (
        points[0]["auroc"] == 0.96 and points[1]["stealthy"] and points[2]["auroc"] is None
    )  # zscore ignored
    assert plot_stealth(runs, tmp_path / "stealth.png") == tmp_path / "stealth.png"
    assert (tmp_path / "stealth.png").stat().st_size > 1000
    assert plot_stealth({"orbit/clean": runs["orbit/clean"]}, tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()


def test_the_frontier_plot_shows_table_9_runs_against_what_the_strongest_defence_leaves(tmp_path):
    from stealth_ns.bench.stealth_plot import frontier_points, plot_frontier

    def run(ill, after, stealthy, tables=(1, 9), scene="fox"):
        metrics = {
            "v_illusory_psnr": ill,
            "stealthy_success": stealthy,
            "stealth": {"auroc": {}, "v_illusory_after_strongest": after},
        }
        return {"scene": scene, "tables": list(tables), "metrics": metrics}

    runs = {
        "fox/clean": {"clean": True, "scene": "fox", "tables": [9]},
        "fox/median": run(38.3, 9.9, False),
        "fox/ad-floor-0.3-support-3": run(30.0, 12.4, False, tables=(9,)),
        "fox/ad-whitebox": run(27.0, None, True, tables=(9,)),  # no cut within 0.5 dB
        "fox/st-support-3": run(38.1, 10.0, False, tables=(7,)),  # not an adaptive table's run
    }
    points = frontier_points(runs)
    assert [p["variant"] for p in points] == ["default attack", "ad-floor-0.3-support-3", "ad-whitebox"]
    assert points[1]["after"] == 12.4 and points[2]["after"] is None and points[2]["stealthy"]
    assert plot_frontier(runs, tmp_path / "frontier.png") == tmp_path / "frontier.png"
    assert (tmp_path / "frontier.png").stat().st_size > 1000
    assert plot_frontier({"fox/st-support-3": runs["fox/st-support-3"]}, tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()
