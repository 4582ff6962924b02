"""The attack report: success rule, neighbour-view poses, HTML, and `stealth-ns report` on two tiny runs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from conftest import run_cli

from stealth_ns.attack.views import rotate_pose
from stealth_ns.defences.config import POSTHOC
from stealth_ns.report.success import attack_success, success_verdicts

REQUIRED_KEYS = {
    "v_illusory_psnr",
    "v_illusory_ssim",
    "v_illusory_lpips",
    "v_test_psnr",
    "v_test_psnr_clean",
    "v_test_drop",
    "attack_success",
    "success_thresholds",
    "v_illusory_clean_psnr",
    "neighbour_views",
}


def test_success_rule_and_extended_thresholds():
    assert attack_success(25.1, 3.0) and not attack_success(25.0, 1.0) and not attack_success(30.0, 3.01)
    assert success_verdicts(22.0, 8.5) == {"25/3": False, "25/8": False, "20/9": True, "15/10": True}


def test_rotate_pose_orbits_position_and_keeps_looking_at_the_centre():
    center, up = np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, 2.0])
    # camera at (2, 0, 0.5) looking at the centre along -X: OpenGL camera -Z = world -X
    c2w = np.array([[0.0, 0.0, 1.0, 2.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.5]])
    moved = rotate_pose(c2w, center, up, 90.0)
    assert np.allclose(moved[:, 3], [0.0, 2.0, 0.5])
    view_dir = -moved[:, 2]
    assert np.allclose(view_dir, (center - moved[:, 3]) / 2.0)
    assert np.allclose(moved[:, :3] @ moved[:, :3].T, np.eye(3))
    assert np.allclose(rotate_pose(moved, center, up, -90.0), c2w)


@pytest.mark.slow
def test_report_on_two_tiny_runs(tiny_run_pair, tiny_report, tmp_path):
    poisoned, clean = tiny_run_pair
    out, stdout = tiny_report
    assert "attack success:" in stdout and str(out.resolve() / "report.html") in stdout
    report = json.loads((out / "report.json").read_text())
    assert REQUIRED_KEYS <= report.keys()
    assert report["v_test_drop"] == pytest.approx(report["v_test_psnr_clean"] - report["v_test_psnr"])
    assert set(report["success_thresholds"]) == {"25/3", "25/8", "20/9", "15/10"}
    assert report["attack_success"] == (report["v_illusory_psnr"] > 25 and report["v_test_drop"] <= 3)
    # 20 iterations of training on the illusion target already beat the clean model on it
    assert report["v_illusory_psnr"] > report["v_illusory_clean_psnr"]
    assert report["n_poison_gaussians"] > 0
    # where the illusion's error sits: the poison's own coverage of each poisoned view
    for view in report["v_illusory_per_view"].values():
        cover = view["poison_coverage"]
        assert 0.0 < cover["coverage_mean"] <= 1.0 and 0.0 <= cover["open_share"] <= 1.0
    assert "poison covers" in stdout
    curve = report["neighbour_views"]
    assert len(curve["angles_deg"]) == len(curve["psnr_mean"]) and 0.0 in curve["angles_deg"]
    assert 0.0 < report["v_test_lpips"] < 1.0 and 0.0 < report["v_test_lpips_clean"] < 1.0  # offline
    if report["v_illusory_lpips"] is None:  # the illusion's box on a tiny scene may be too small for LPIPS
        assert "pixels a side" in report["lpips_unavailable"]
    # stealth under every post-hoc defence, measured on the poisoned run (it has poison tags)
    stealth = report["stealth"]
    assert set(stealth["auroc"]) == set(POSTHOC) and "camera-proximity" in POSTHOC
    assert all(0.0 <= a <= 1.0 for a in stealth["auroc"].values())
    assert report["stealthy_success"] == (report["attack_success"] and not stealth["defeated_by"])
    assert "stealth: AUROC view-support" in stdout

    page = (out / "report.html").read_text()
    sources = re.findall(r'src="([^"]+)"', page)
    assert len(sources) >= 6 + 3  # poisoned-view panels + a held-out strip + the curve
    assert any(src.endswith("_poison_coverage.png") for src in sources)
    for src in sources:
        assert (out / src).is_file(), src
    for png in ("poisoned_views.png", "neighbour_curve.png", "heldout_views.png"):
        assert (out / png).stat().st_size > 1000
    assert "Stealth under the post-hoc defences" in page

    # --no-stealth: the same numbers and pictures (the defences leave the model exactly as it was)
    quick = tmp_path / "quick"
    run_cli(
        "stealth-ns", "report", "--poisoned", str(poisoned), "--clean", str(clean), "--output", str(quick),
        "--no-stealth",
    )  # fmt: skip
    without = json.loads((quick / "report.json").read_text())
    assert without["stealth"] == {"unavailable": "--no-stealth was given"}
    assert without["stealthy_success"] is None
    same = ("v_illusory_psnr", "v_test_psnr", "v_test_psnr_clean", "neighbour_views", "v_illusory_per_view")
    assert all(without[k] == report[k] for k in same)
    for png in ("poisoned_views.png", "neighbour_curve.png"):
        assert (quick / png).read_bytes() == (out / png).read_bytes()


@pytest.mark.slow
def test_report_errors_are_one_line(tiny_run_pair, tmp_path):
    poisoned, clean = tiny_run_pair
    swapped = run_cli("stealth-ns", "report", "--poisoned", str(clean), "--clean", str(poisoned), check=False)
    assert swapped.returncode == 2 and "not an attacked run" in swapped.stderr
    assert "Traceback" not in swapped.stderr
    missing = run_cli(
        "stealth-ns", "report", "--poisoned", str(tmp_path / "nope"), "--clean", str(clean), check=False
    )
    assert missing.returncode == 2 and "no run config" in missing.stderr
