"""The held-out calibration of the scan's region threshold (pure functions over bench scan rows)."""

from __future__ import annotations

import math

import pytest

from stealth_ns.bench.scan_calibration import (
    calibration_lines,
    choose_rule,
    choose_threshold,
    confusion_at,
    held_out,
    margin,
    right_at,
    size_candidates,
    split_scenes,
    verdict_at,
)


def row(scene, run, groups, tampered=(), failed=False, poison=None):
    """A bench scan row: ``groups`` as (view index, share) or (view index, share, Gaussians); poisoned
    when ``tampered`` names views; ``poison``: view index -> the group's poison share."""
    return {
        "run": f"{scene}/{run}",
        "scene": scene,
        "poisoned": bool(tampered),
        "attack_failed": failed,
        "groups": [
            {
                "view": f"v{g[0]}",
                "index": g[0],
                "share": g[1],
                **({"gaussians": g[2]} if len(g) > 2 else {}),
                **({"poison": poison[g[0]]} if poison and g[0] in poison else {}),
            }
            for g in groups
        ],
        "tampered": list(tampered),
    }


def test_right_needs_the_poisoned_view_and_nothing_else():
    clean = row("a", "clean", [(3, 0.004)])
    poisoned = row("a", "p", [(5, 0.08), (3, 0.004)], tampered=[5])
    wrong = row("a", "w", [(3, 0.08)], tampered=[5])
    assert right_at(clean, 0.01) and not right_at(clean, 0.003)
    assert right_at(poisoned, 0.01) and not right_at(poisoned, 0.003)  # v3 would be named too
    assert not right_at(poisoned, 0.1)  # missed
    assert not right_at(wrong, 0.01)
    assert confusion_at([clean, poisoned, wrong], 0.01) == {
        "clean_clean": 1, "clean_suspicious": 0, "found": 1, "leaked": 0, "wrong_view": 1, "missed": 0,
    }  # fmt: skip
    assert confusion_at([clean, poisoned], 0.003)["clean_suspicious"] == 1
    assert margin(clean, 0.01) == pytest.approx(2.5) and margin(poisoned, 0.01) == pytest.approx(2.5)
    assert margin(row("a", "empty", []), 0.01) == math.inf


def test_a_named_view_whose_group_is_poison_is_a_leak_not_a_wrong_view():
    # v3's group is the poison of v5 drawn into v3: naming v3 is on target
    leak = row("a", "leak", [(5, 0.08), (3, 0.02)], tampered=[5], poison={5: 1.0, 3: 0.9})
    stray = row("a", "stray", [(5, 0.08), (3, 0.02)], tampered=[5], poison={5: 1.0, 3: 0.1})
    only_leak = row("a", "only", [(3, 0.08)], tampered=[5], poison={3: 1.0})
    assert right_at(leak, 0.01) and not right_at(stray, 0.01)
    assert not right_at(only_leak, 0.01)  # the poisoned view itself must be named
    counts = confusion_at([leak, stray, only_leak], 0.01)
    assert (counts["found"], counts["leaked"], counts["wrong_view"]) == (1, 1, 2)
    assert confusion_at([leak], 0.03)["leaked"] == 0  # the leak's group is below this threshold
    # a clean run's groups are never on target, whatever they record
    assert not right_at(row("a", "clean", [(3, 0.02)], poison={3: 1.0}), 0.01)


def test_the_threshold_is_the_log_middle_of_the_widest_right_gap():
    rows = [
        row("a", "clean", [(0, 0.002)]),
        row("a", "clean2", [(0, 0.004)]),
        row("a", "p", [(1, 0.04)], tampered=[1]),
        row("a", "p2", [(1, 0.16)], tampered=[1]),
    ]
    assert choose_threshold(rows) == pytest.approx(math.sqrt(0.004 * 0.04))
    # a clean model above a poisoned one: the best threshold gets 3 of 4 right
    rows.append(row("a", "clean3", [(0, 0.08)]))
    t = choose_threshold(rows)
    assert sum(right_at(r, t) for r in rows) == 4
    with pytest.raises(ValueError):
        choose_threshold([])


def test_held_out_folds_fit_on_one_half_and_judge_the_other():
    rows = []
    for scene, clean_share, poison_share in (("s1", 0.003, 0.05), ("s2", 0.002, 0.2), ("s3", 0.03, 0.06)):
        rows += [row(scene, "clean", [(0, clean_share)]), row(scene, "p", [(1, poison_share)], tampered=[1])]
    rows.append(row("s4", "failed", [(0, 0.5)], tampered=[1], failed=True))  # neither fitted nor judged
    assert split_scenes(["s1", "s2", "s3"]) == (["s1", "s3"], ["s2"])
    assert split_scenes(["s1", "s2", "s3"], ["s2"]) == (["s2"], ["s1", "s3"])
    result = held_out(rows)
    first, second = result["folds"]
    assert (first["fit"], first["held_out"]) == (["s1", "s3"], ["s2"])
    assert first["confusion"] == {
        "clean_clean": 1,
        "clean_suspicious": 0,
        "found": 1,
        "leaked": 0,
        "wrong_view": 0,
        "missed": 0,
    }
    # fitted on s2 alone (0.002 | 0.2), the threshold lies between them: s3's clean 3 % is called suspicious
    assert second["threshold"] == pytest.approx(math.sqrt(0.002 * 0.2))
    assert second["confusion"]["clean_suspicious"] == 1
    assert result["confusion"]["clean_suspicious"] == 1 and result["confusion"]["found"] == 3
    assert len(result["margins"]) == 6 and {m["run"] for m in result["margins"]} == {
        r["run"] for r in rows[:6]
    }
    text = "\n".join(calibration_lines(result))
    assert "| s1, s3 | " in text and "| both folds | – | – | every scene | 2 | 1 | 3 | 0 | 0 |" in text
    assert "| s3/clean | clean | 2.00% | 0.67x | no |" in text  # on the wrong side: below 1
    assert held_out(rows[:2])["folds"] == []  # one scene: nothing held out


def test_the_group_size_is_chosen_with_the_threshold():
    # a clean capture's floater (10 Gaussians) covers more of its view than a stealthy attack's poison
    rows = [
        row("a", "clean", [(0, 0.02, 10)]),
        row("a", "clean2", [(0, 0.004, 8)]),
        row("a", "p", [(1, 0.0165, 400)], tampered=[1]),
        row("a", "p2", [(1, 0.05, 2000), (3, 0.002, 6)], tampered=[1]),
    ]
    # the share alone cannot be right on all four ...
    assert max(sum(right_at(r, t) for r in rows) for t in (0.003, 0.005, 0.0145, 0.02, 0.06)) == 3
    # ... the share and the size can: groups of fewer than ~63 Gaussians (sqrt(10 * 400)) do not count
    assert size_candidates(rows) == pytest.approx(
        [5, math.sqrt(5 * 6), math.sqrt(6 * 8), math.sqrt(80), math.sqrt(4000), math.sqrt(800000)]
    )
    t, m = choose_rule(rows)
    assert m == pytest.approx(math.sqrt(10 * 400)) and sum(right_at(r, t, m) for r in rows) == 4
    assert confusion_at(rows, t, m) == {
        "clean_clean": 2,
        "clean_suspicious": 0,
        "found": 2,
        "leaked": 0,
        "wrong_view": 0,
        "missed": 0,
    }
    # where the share alone is right, the scan's own group size is kept
    assert choose_rule(rows[1:])[1] == 5
    # a group whose size was not recorded (an older scan-results.json) always counts
    assert verdict_at(row("a", "old", [(0, 0.02)]), 0.01, 1e9) == "suspicious"


def test_a_group_too_coarse_for_a_picture_never_counts():
    floater = row("a", "clean", [(0, 0.02, 10)])
    floater["groups"][0]["detailed"] = False  # the scan's --max-pixels-per-gaussian said so
    assert verdict_at(floater, 0.01) == "clean" and right_at(floater, 0.001)
    floater["groups"][0]["detailed"] = True
    assert verdict_at(floater, 0.01) == "suspicious"
