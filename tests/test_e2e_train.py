"""End to end on the CPU: ns-train stealth-splat-lite on a tiny scene, then ns-eval."""

from __future__ import annotations

import json

import pytest
from conftest import run_cli


@pytest.mark.slow
def test_ns_train_then_ns_eval_on_cpu(tiny_orbit_scene, tmp_path):
    out = tmp_path / "runs"
    run_cli(
        "ns-train",
        "stealth-splat-lite",
        "--vis",
        "tensorboard",
        "--output-dir",
        str(out),
        "--experiment-name",
        "tiny",
        "--timestamp",
        "run",
        "--max-num-iterations",
        "40",
        "--steps-per-eval-all-images",
        "1000",
        "nerfstudio-data",
        "--data",
        str(tiny_orbit_scene),
    )
    config = out / "tiny" / "stealth-splat-lite" / "run" / "config.yml"
    assert config.exists()
    assert list((config.parent / "nerfstudio_models").glob("step-*.ckpt"))
    assert "device_type: cpu" in config.read_text() or "device_type: cuda" in config.read_text()

    result_path = tmp_path / "eval.json"
    proc = run_cli("ns-eval", "--load-config", str(config), "--output-path", str(result_path))
    results = json.loads(result_path.read_text())["results"]
    assert results["psnr"] > 12.0, results  # 40 iterations from SfM-like seed points: well above noise
    assert 0.0 < results["ssim"] <= 1.0
    assert "Traceback" not in proc.stderr
