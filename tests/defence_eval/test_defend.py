"""stealth-ns defend: the renderer's per-Gaussian weights, pruning a model, the input filter, the
pruned run, and one tiny end-to-end run of every defence (the scores' math: test_defence_scores.py)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch
from conftest import run_cli
from model_helpers import build_model, camera, pinhole_cameras

from stealth_ns.defence_eval.stealth import stealth_summary
from stealth_ns.defences.config import DEFENCES, DefendConfig
from stealth_ns.defences.pruned_run import pruned_state
from stealth_ns.defences.signals import (
    WEIGHT_BLOCK_VIEWS,
    gradient_energy_matrix,
    view_weight_matrix,
    view_weights_and_depths,
)
from stealth_ns.gaussians.rows import select_rows
from stealth_ns.images.input_filter import filter_image
from stealth_ns.method.camera_geometry import camera_geometry
from stealth_ns.method.render_view import render_camera


def _two_cameras():
    c2w = torch.eye(4)[:3].repeat(2, 1, 1)
    c2w[0, :, 3] = torch.tensor([0.0, 0.0, 3.0])
    c2w[1, :, 3] = torch.tensor([0.3, 0.0, 3.0])
    return pinhole_cameras(c2w)


def test_blend_weights_sum_to_the_accumulated_opacity():
    model, _ = build_model(n_points=200)
    model.eval()
    cam = camera()
    weights = model.blend_weights(cam)
    assert weights.shape == (200,) and bool((weights >= -1e-6).all())
    accumulation = render_camera(model, cam)["accumulation"]
    assert float(weights.sum()) == pytest.approx(float(accumulation.sum()), rel=1e-4)
    # a Gaussian behind the camera paints nothing
    with torch.no_grad():
        model.gauss_params["means"][0] = torch.tensor([0.0, 0.0, 10.0])
    assert float(model.blend_weights(cam)[0]) == 0.0


def test_view_weights_bring_the_scene_depths_of_camera_proximity():
    """camera-proximity's scene depths read off the view weights' renders are those of its own
    renders, exactly, and the weights those of view_weight_matrix; a view that shows nothing is NaN
    there and takes the other views' median in the geometry."""
    model, _ = build_model(n_points=200)
    model.eval()
    c2w = torch.eye(4)[:3].repeat(3, 1, 1)
    c2w[0, :, 3] = torch.tensor([0.0, 0.0, 3.0])
    c2w[1, :, 3] = torch.tensor([0.3, 0.0, 3.0])
    c2w[2, :, 3] = torch.tensor([0.0, 0.0, -30.0])  # looks away from every Gaussian
    cams = pinhole_cameras(c2w)
    weights, depths, nears = view_weights_and_depths(model, cams)
    assert np.array_equal(weights, view_weight_matrix(model, cams))
    rendered = camera_geometry(model, cams).scene_depths
    assert np.isfinite(depths[:2]).all() and np.isnan(depths[2])
    assert depths[:2].tolist() == rendered[:2].tolist()
    assert rendered[2] == np.median(depths[:2])
    assert np.isnan(nears[2]) and (0 < nears[:2]).all() and (nears[:2] <= depths[:2]).all()


def test_view_weight_columns_are_each_views_weights_across_blocks():
    """The matrix is written a block of views at a time: with more views than a block (and a last,
    partial block), every column is that view's own blend weights."""
    model, _ = build_model(n_points=120)
    model.eval()
    n_views = WEIGHT_BLOCK_VIEWS + 3
    c2w = torch.eye(4)[:3].repeat(n_views, 1, 1)
    c2w[:, 0, 3] = torch.linspace(-0.5, 0.5, n_views)
    c2w[:, 2, 3] = 3.0
    cams = pinhole_cameras(c2w)
    weights = view_weight_matrix(model, cams)
    for v in (0, WEIGHT_BLOCK_VIEWS - 1, WEIGHT_BLOCK_VIEWS, n_views - 1):
        assert np.array_equal(weights[:, v], model.blend_weights(cams[v : v + 1]).numpy())
    assert len({weights[:, v].tobytes() for v in range(n_views)}) == n_views


def test_kept_renders_as_if_the_rows_were_removed():
    model, _ = build_model(n_points=120)
    cam = camera()
    keep = torch.arange(120) % 3 != 0
    with model.kept(keep):
        restricted = render_camera(model, cam)["rgb"]
    assert model.keep_mask is None  # restored
    pruned, _ = build_model(n_points=120)
    with torch.no_grad():
        for name, param in model.gauss_params.items():
            pruned.gauss_params[name] = torch.nn.Parameter(param.data[keep].clone())
    assert torch.allclose(restricted, render_camera(pruned, cam)["rgb"], atol=1e-6)
    with pytest.raises(ValueError, match="keep mask"):
        with model.kept(torch.ones(5, dtype=torch.bool)):
            pass


def test_view_weights_and_gradient_energy_leave_the_model_as_it_was():
    model, _ = build_model(n_points=150)
    cams = _two_cameras()
    before = {k: v.detach().clone() for k, v in model.gauss_params.items()}
    weights = view_weight_matrix(model, cams)
    assert weights.shape == (150, 2) and weights.sum() > 0
    images = [torch.full((32, 48, 3), 0.5), torch.zeros(32, 48, 3, dtype=torch.uint8)]
    rates = dict.fromkeys(("means", "scales", "quats", "features_dc", "features_rest", "opacities"), 1e-2)
    energy = gradient_energy_matrix(model, cams, images, rates)
    assert energy.shape == (150, 2) and energy.sum() > 0 and np.isfinite(energy).all()
    # no gradient where a Gaussian is not seen by the view
    assert bool(((weights == 0) <= (energy == 0)).all())
    for k, v in model.gauss_params.items():
        assert torch.equal(v.detach(), before[k]), k


def test_select_rows_and_pruned_checkpoint_state():
    keep = torch.tensor([True, False, True])
    rows = select_rows({"a": torch.arange(3), "b": torch.zeros(4), "s": 1.0, "m": torch.ones(3, 2)}, keep)
    assert rows["a"].tolist() == [0, 2] and rows["b"].shape == (4,) and rows["s"] == 1.0
    assert rows["m"].shape == (2, 2)
    state = {
        "_model.gauss_params.means": torch.arange(9.0).reshape(3, 3),
        "_model.gauss_params.poison": torch.tensor([0.0, 1.0, 0.0]),
        "_model._extra_state": {"grad2d": torch.ones(3), "scene_scale": 1.0},
        "_model.data_background": torch.zeros(3),  # 3 values, but not a Gaussian row
        "_extra_state": {"attack_record": "{}"},
    }
    out = pruned_state(state, keep)
    assert out["_model.gauss_params.means"][:, 0].tolist() == [0.0, 6.0]
    assert out["_model.gauss_params.poison"].tolist() == [0.0, 0.0]
    assert out["_model._extra_state"]["grad2d"].shape == (2,)
    assert out["_model.data_background"].shape == (3,)


@pytest.mark.parametrize("kind", ["wavelet", "gaussian"])
def test_input_filter_smooths_noise_and_keeps_dtype_and_alpha(kind):
    rng = np.random.default_rng(0)
    clean = np.tile(np.linspace(0, 255, 64, dtype=np.float64)[None, :, None], (48, 1, 3))
    noisy = np.clip(clean + rng.normal(0, 20, clean.shape), 0, 255).round().astype(np.uint8)
    rgba = np.concatenate([noisy, np.full((48, 64, 1), 200, np.uint8)], -1)
    out = filter_image(rgba, kind)
    assert out.dtype == np.uint8 and out.shape == rgba.shape
    assert (out[..., 3] == 200).all()
    err_before = np.abs(noisy.astype(float) - clean).mean()
    err_after = np.abs(out[..., :3].astype(float) - clean).mean()
    assert err_after < 0.7 * err_before
    as_float = filter_image(noisy.astype(np.float32) / 255, kind)
    assert as_float.dtype == np.float32 and 0 <= as_float.min() and as_float.max() <= 1
    assert np.array_equal(filter_image(noisy, "none"), noisy)
    with pytest.raises(ValueError, match="unknown input filter"):
        filter_image(noisy, "median")


@pytest.mark.parametrize(
    "change, message",
    [
        ({"defences": ("zscore", "nope")}, "unknown defence 'nope'"),
        ({"defences": ()}, "--defences is empty"),
        ({"count_cap_keep": 0.0}, "--count-cap-keep must be in"),
        ({"concentration_threshold": 2.0}, "--concentration-threshold"),
        ({"input_filter": "median"}, "--input-filter must be one of"),
        ({"finetune_epochs": 0}, "--finetune-epochs"),
    ],
)
def test_bad_options_are_named(change, message):
    cfg = DefendConfig(**change)
    with pytest.raises(ValueError, match=re.escape(message)):
        cfg.validate()


@pytest.mark.slow
def test_defend_end_to_end_on_tiny_runs(tiny_run_pair, tmp_path):
    """Every defence on a 60-iteration poisoned run; the pruned run loads; the report shows the section."""
    poisoned, clean = tiny_run_pair
    out = tmp_path / "defend"
    proc = run_cli(
        "stealth-ns", "defend", "--run", str(poisoned), "--clean", str(clean), "--output", str(out),
        "--finetune-epochs", "1", in_process=False,
    )  # fmt: skip
    assert "Traceback" not in proc.stderr
    result = json.loads((out / "defend.json").read_text())
    assert set(result["defences"]) == set(DEFENCES)
    assert result["n_poison"] > 0 and result["undefended"]["v_illusory_psnr"] is not None
    for name, entry in result["defences"].items():
        op = entry["operating_point"]
        assert op["v_illusory_psnr"] is not None and op["v_test_cost"] is not None, name
        if entry["kind"] == "post-hoc":
            assert 0.0 <= entry["auroc"] <= 1.0 and 0.0 < entry["average_precision"] <= 1.0, name
            assert len(entry["curve"]) >= 5 and entry["curve"][0]["fraction"] == 0.0
            assert entry["curve"][0]["v_test_cost"] == pytest.approx(0.0, abs=1e-9)
            assert (out / "pruned" / name).is_dir()
    assert result["clean"]["v_test_psnr"] is not None
    for png in ("roc.png", "curves.png", "poisoned_view.png"):
        assert (out / png).stat().st_size > 1000
    assert "| zscore |" in (out / "defend.md").read_text()

    # the pruned model is a run that ns-eval loads, with the pruned rows gone
    from stealth_ns.runs.loaded import load_run

    entry = result["defences"]["view-support"]
    pruned = load_run(entry["pruned_run"])
    assert pruned.model.num_points == result["n_gaussians"] - entry["operating_point"]["n_pruned"]
    eval_json = tmp_path / "eval.json"
    run_cli("ns-eval", "--load-config", entry["pruned_run"], "--output-path", str(eval_json))
    assert "v_illusory_psnr" in json.loads(eval_json.read_text())["results"]

    report = tmp_path / "report"
    run_cli(
        "stealth-ns", "report", "--poisoned", str(poisoned), "--clean", str(clean), "--output", str(report),
        "--defend", str(out),
    )  # fmt: skip
    page = (report / "report.html").read_text()
    assert "<h2>Defences</h2>" in page and "view-support" in page
    # the report's stealth is defend's own scoring: the same AUROC for the defences that do not
    # depend on the fine-tune's length (defend ran one epoch here, the report its default two)
    stealth = json.loads((report / "report.json").read_text())["stealth"]
    for name in ("zscore", "sor", "count-cap", "view-support"):
        assert stealth["auroc"][name] == result["defences"][name]["auroc"], name
    same = stealth_summary({k: v for k, v in result["defences"].items() if k != "grad-concentration"}, True)
    assert {k: stealth["strongest_cut"][k] for k in same["strongest_cut"]} == same["strongest_cut"]
    assert (report / "defences" / "curves.png").is_file()
    wrong = run_cli(
        "stealth-ns", "report", "--poisoned", str(clean), "--clean", str(poisoned), "--output", str(report),
        "--defend", str(out), check=False,
    )  # fmt: skip
    assert wrong.returncode == 2 and "Traceback" not in wrong.stderr
    assert f"--defend {out} was made for {poisoned.resolve()}" in wrong.stderr
    assert (report / "report.html").read_text() == page  # refused before the earlier report was cleared


def test_defend_refuses_an_output_inside_the_run(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yml").write_text("x: 1\n")
    proc = run_cli("stealth-ns", "defend", "--run", str(run / "config.yml"), "--output", str(run / "d"),
                   check=False)  # fmt: skip
    assert proc.returncode == 2 and "inside the run folder" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_defend_refuses_the_attacked_run_as_its_clean_run_before_loading(tiny_run_pair, tmp_path):
    """``--clean`` the attacked run itself: one line before any run is loaded (``report`` refuses it too;
    another attacked run as ``--clean`` is refused once loaded, by ``clean_reference``)."""
    from stealth_ns.defence_eval.arguments import check_arguments
    from stealth_ns.foundation.errors import StealthNSError

    poisoned, _ = tiny_run_pair
    for clean in (poisoned, poisoned.parent):  # its config.yml or its folder
        with pytest.raises(StealthNSError, match="is the attacked run itself"):
            check_arguments(poisoned, tmp_path / "out", DefendConfig(), clean)
