"""Console scripts as a user runs them: registration with nerfstudio, help, one-line errors."""

from __future__ import annotations

import json

from conftest import run_cli


def test_ns_train_lists_the_methods():
    out = run_cli("ns-train", "--help").stdout
    assert "stealth-splat" in out and "stealth-splat-lite" in out


def test_stealth_ns_help_lists_commands():
    out = run_cli("stealth-ns", "--help").stdout
    for command in ("make-scene", "demo", "bench raster"):
        assert command in out


def test_unknown_command_is_one_line_error():
    proc = run_cli("stealth-ns", "frobnicate", check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "unknown command 'frobnicate'" in proc.stderr


def test_bench_raster_quick_writes_json(tmp_path):
    path = tmp_path / "bench.json"
    run_cli("stealth-ns", "bench", "raster", "--quick", "--json", str(path))
    data = json.loads(path.read_text())
    (case_cpp, case_torch) = sorted(data["cases"], key=lambda c: c["backend"])
    for case in (case_cpp, case_torch):
        assert {
            "name",
            "n_gaussians",
            "width",
            "height",
            "backend",
            "forward_ms",
            "forward_backward_ms",
        } <= set(case)
        # both measured (their ratio is a benchmark figure, not behaviour: a loaded machine can invert it)
        assert case["forward_backward_ms"] > 0 and case["forward_ms"] > 0
    assert data["speedup_fwd_bwd"][case_cpp["name"]] > 1.0


def test_bench_raster_json_into_missing_folder_is_an_error(tmp_path):
    proc = run_cli(
        "stealth-ns", "bench", "raster", "--quick", "--json", str(tmp_path / "nope" / "b.json"), check=False
    )
    assert proc.returncode == 2 and "does not exist" in proc.stderr
