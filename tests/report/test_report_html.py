"""report.html from report.json's content: every number and picture shown, user text escaped."""

from __future__ import annotations

import re

from stealth_ns.report.html import render_html


def _report(
    name: str = "images/<b>frame</b>&1.png", lpips: float | None = 0.1234, coverage: dict | None = None
) -> dict:
    kinds = ("target", "poisoned", "clean", "poison_hidden", "mask") + (
        ("poison_coverage",) if coverage else ()
    )
    files = {k: f"images/view0003_{k}.png" for k in kinds}
    return {
        "poisoned_run": "/runs/<poisoned>/config.yml",
        "clean_run": "/runs/clean/config.yml",
        "step": 2999,
        "step_clean": 2999,
        "created": "2026-11-23T10:00:00",
        "attack_success": True,
        "v_illusory_psnr": 30.0123,
        "v_illusory_ssim": 0.9,
        "v_illusory_lpips": lpips,
        "v_illusory_clean_psnr": 9.81,
        "v_illusory_clean_ssim": 0.2,
        "v_illusory_clean_lpips": None,
        "v_test_psnr": 26.13,
        "v_test_ssim": 0.8,
        "v_test_lpips": None,
        "v_test_psnr_clean": 26.87,
        "v_test_ssim_clean": 0.81,
        "v_test_lpips_clean": None,
        "v_test_drop": 0.74,
        "n_gaussians": 90000,
        "n_gaussians_clean": 89000,
        "n_poison_gaussians": 476,
        "lpips_unavailable": None if lpips is not None else "no AlexNet weights <offline>",
        "success_thresholds": {"25/3": True, "25/8": True, "20/9": True, "15/10": False},
        "v_illusory_per_view": {
            name: {
                "psnr": 30.0123,
                "ssim": 0.9,
                "lpips": lpips,
                "clean_psnr": 9.81,
                "clean_ssim": 0.2,
                "clean_lpips": None,
                "poison_coverage": coverage,
            }
        },
        "images": {
            "poisoned_views": {name: files},
            "figures": {
                "poisoned_views": "poisoned_views.png",
                "heldout_views": None,
                "neighbour_curve": "neighbour_curve.png",
            },
        },
        "heldout_strip": [],
        "neighbour_views": {"angles_deg": [-2.5, 0.0, 2.5], "psnr_mean": [31.04, 12.5, 30.96]},
    }


def test_html_shows_the_numbers_and_pictures_and_escapes_names():
    page = render_html(_report())
    assert "attack succeeded" in page and "30.01 dB in the mask" in page
    assert "<b>frame</b>" not in page and "&lt;b&gt;frame&lt;/b&gt;&amp;1.png" in page
    assert "/runs/&lt;poisoned&gt;/config.yml" in page
    sources = re.findall(r'src="([^"]+)"', page)
    assert sources[:5] == [
        f"images/view0003_{k}.png" for k in ("target", "poisoned", "clean", "poison_hidden", "mask")
    ]
    assert sources[-1] == "neighbour_curve.png"
    assert '<td class="num">30.012</td>' in page and "<td>yes</td>" in page and "<td>no</td>" in page
    assert "<th>-2.5</th>" in page and '<td class="num">12.5</td>' in page
    assert "Innocent (held-out) views" not in page  # no strip: no section
    assert "LPIPS unavailable" not in page


def test_html_says_why_lpips_is_missing():
    page = render_html(_report(lpips=None))
    assert "LPIPS unavailable: no AlexNet weights &lt;offline&gt;" in page
    assert "<td>–</td>" in page


def test_html_shows_where_the_error_sits_when_the_run_has_poison():
    assert "Where the error sits" not in render_html(_report())  # a victim's run: no poison rows
    coverage = {
        "coverage_mean": 0.803,
        "open_share": 0.141,
        "open_error_share": 0.622,
        "open_psnr": 16.51,
        "covered_psnr": 27.3,
    }
    page = render_html(_report(coverage=coverage))
    assert "Where the error sits" in page
    for cell in ("80.30", "14.10", "62.20", "16.51", "27.30"):
        assert f'<td class="num">{cell}</td>' in page
    assert "images/view0003_poison_coverage.png" in re.findall(r'src="([^"]+)"', page)
