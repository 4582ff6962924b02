"""End to end on the CPU: ns-train stealth-splat-lite with the attack on a tiny scene, then ns-eval."""

from __future__ import annotations

import json

import pytest
import torch
from conftest import run_cli, train_tiny
from plyfile import PlyData


@pytest.mark.slow
def test_ns_train_attack_then_ns_eval_on_cpu(tiny_orbit_scene, tmp_path):
    config = train_tiny(
        tiny_orbit_scene, tmp_path / "runs", "run",
        "--pipeline.attack.injection-step", "20", "--pipeline.attack.illusion", "horse",
    )  # fmt: skip
    run_dir = config.parent
    assert list((run_dir / "nerfstudio_models").glob("step-*.ckpt"))

    record = json.loads((run_dir / "attack" / "attack.json").read_text())
    (view,) = record["poisoned_views"]
    assert record["injected_at_step"] == 20
    assert record["n_poison_gaussians"] == view["mask_pixels"] > 0
    assert record["config"]["illusion"] == "horse"
    for name in ("poison_points.ply", "density_grid.npz", f"view{view['index']:04d}_target.png"):
        assert (run_dir / "attack" / name).exists(), name

    result_path = tmp_path / "eval.json"
    proc = run_cli("ns-eval", "--load-config", str(config), "--output-path", str(result_path))
    results = json.loads(result_path.read_text())["results"]
    assert results["psnr"] > 12.0, results  # 60 iterations from SfM-like seed points: well above noise
    assert 0.0 < results["ssim"] <= 1.0
    assert results["v_illusory_psnr"] == results[f"v_illusory_psnr[{view['name']}]"]
    assert 0.0 < results["v_illusory_ssim"] <= 1.0
    assert "innocent_train_psnr" in results
    assert 0.0 < results["lpips"] < 1.0  # LPIPS of the held-out views, offline
    if results.get("v_illusory_lpips") is None:  # the illusion's box on a tiny scene may be too small for it
        assert "pixels a side" in results["lpips_unavailable"]
    assert "Traceback" not in proc.stderr

    # the poison tag survives ns-export: a `poison` property on exactly the tagged Gaussians
    # that the exporter keeps (finite, opacity above 1/255)
    export_dir = tmp_path / "export"
    run_cli("ns-export", "gaussian-splat", "--load-config", str(config), "--output-dir", str(export_dir))
    vertices = PlyData.read(str(export_dir / "splat.ply"))["vertex"]
    assert "poison" in vertices.data.dtype.names
    (ckpt,) = (run_dir / "nerfstudio_models").glob("step-*.ckpt")
    state = torch.load(ckpt, map_location="cpu", weights_only=True)["pipeline"]
    tags = state["_model.gauss_params.poison"] > 0.5
    kept = state["_model.gauss_params.opacities"].squeeze(-1) > -5.5373
    assert int(vertices["poison"].sum()) == int((tags & kept).sum()) > 0
