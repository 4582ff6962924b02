"""The attack record (one writer, one reader), the model's rows and renders, V-illusory, fail()."""

from __future__ import annotations

import json

import pytest
import torch
from model_helpers import build_model, camera, train_step

from stealth_ns.attack.record import AttackRecord, Injection, PoisonView, RecordError
from stealth_ns.foundation.errors import StealthNSError, StealthNSExit, fail
from stealth_ns.gaussians.rows import append_rows
from stealth_ns.images.metrics import v_illusory
from stealth_ns.method.model import POISON_TAG
from stealth_ns.method.render_view import render_camera


def _view(index: int, h: int = 6, w: int = 8, seed: int = 0) -> PoisonView:
    g = torch.Generator().manual_seed(seed)
    mask = torch.zeros(h, w, dtype=torch.bool)
    mask[1:4, 2:6] = True
    c2w = torch.eye(4)[:3].clone()
    c2w[:, 3] = torch.tensor([0.1, 0.2, 3.0])
    target = torch.rand(h, w, 3, generator=g)  # float32: not representable in 8 bits
    return PoisonView(index, f"images/{index:04d}.png", c2w, 7.0, 7.5, 4.0, 3.0, mask, target)


def _record(views: list[PoisonView]) -> AttackRecord:
    return AttackRecord(
        config={"illusion": "astronaut", "illusion_center": (0.5, 0.5), "seed": 0},
        views=views,
        injection_step=3,
        noise={"sigma0": 100.0, "decay": "linear", "total_steps": 30, "seed": 0},
    )


def _injection() -> Injection:
    return Injection(
        injected_at_step=3,
        n_gaussians_before=100,
        n_poison_gaussians=12,
        poison_per_view={"images/0002.png": 12},
        invalid_rays_per_view={"images/0002.png": 0},
        t_min_per_view={"images/0002.png": 0.03},
        t_min_unseen_per_view={"images/0002.png": 0.03},
        innocent_views_seeing_poison={"images/0002.png": 1.5},
        poison_unseen_fraction={"images/0002.png": 0.25},
        density_grid={"shape": [4, 4, 4], "voxel_size": 0.5, "origin": [0.0, 0.0, 0.0]},
        timings_s={"total_s": 0.1},
    )


def test_record_round_trip_is_exact(tmp_path):
    record = _record([_view(2), _view(5, seed=1)])
    record.write(tmp_path, views=True)
    record.injection = _injection()
    record.resumed.append({"step": 10, "poison_gaussians": 12})
    record.write(tmp_path, views=False)  # after the injection: the JSON only
    back = AttackRecord.read(tmp_path)
    assert back.to_json() == json.loads(json.dumps(record.to_json()))
    assert back.injection == record.injection and back.n_poison_gaussians == 12
    for ours, theirs in zip(record.views, back.views, strict=True):
        assert (ours.index, ours.name, ours.fx, ours.fy, ours.cx, ours.cy) == (
            theirs.index,
            theirs.name,
            theirs.fx,
            theirs.fy,
            theirs.cx,
            theirs.cy,
        )
        assert torch.equal(ours.c2w, theirs.c2w)
        assert torch.equal(ours.target, theirs.target)  # bit-equal: scores read from it are the same
        assert torch.equal(ours.mask, theirs.mask) and theirs.mask.dtype == torch.bool
    data = json.loads((tmp_path / "attack.json").read_text())  # the first version's flat keys
    assert data["poisoned_views"][0]["mask_pixels"] == 12 and data["injected_at_step"] == 3
    assert (tmp_path / "view0002_target.png").is_file() and (tmp_path / "view0005_mask.png").is_file()


class _Cameras:
    """The parts of nerfstudio's Cameras the reader uses for records without cameras."""

    def __init__(self, views: list[PoisonView]) -> None:
        self.by_index = {v.index: v for v in views}

    def __len__(self) -> int:
        return max(self.by_index) + 1

    def __getitem__(self, index: int):
        v = self.by_index[index]
        return type("Cam", (), {"camera_to_worlds": v.c2w, "fx": v.fx, "fy": v.fy, "cx": v.cx, "cy": v.cy})


def test_record_of_an_older_run_reads_pngs_and_dataset_cameras(tmp_path):
    view = _view(2)
    _record([view]).write(tmp_path, views=True)
    (tmp_path / "views.npz").unlink()
    data = json.loads((tmp_path / "attack.json").read_text())
    for entry in data["poisoned_views"]:
        for key in ("c2w", "fx", "fy", "cx", "cy"):
            del entry[key]
    (tmp_path / "attack.json").write_text(json.dumps(data))
    with pytest.raises(RecordError, match="predates the cameras"):
        AttackRecord.read(tmp_path)
    (back,) = AttackRecord.read(tmp_path, cameras=_Cameras([view])).views
    assert torch.equal(back.c2w, view.c2w) and torch.equal(back.mask, view.mask)
    assert torch.allclose(back.target, view.target, atol=0.5 / 255 + 1e-6)  # from the 8-bit PNG
    (exact,) = AttackRecord.read(tmp_path, cameras=_Cameras([view]), rebuilt=[view]).views
    assert torch.equal(exact.target, view.target)  # as the loaded pipeline rebuilt it: scores as before


def test_missing_or_broken_records_are_one_line_errors(tmp_path):
    with pytest.raises(RecordError, match="no attack record at .*trained without the attack"):
        AttackRecord.read(tmp_path)
    (tmp_path / "attack.json").write_text("{not json")
    with pytest.raises(RecordError, match="cannot read .*attack.json"):
        AttackRecord.read(tmp_path)
    _record([_view(2)]).write(tmp_path, views=True)
    (tmp_path / "views.npz").unlink()
    (tmp_path / "view0002_mask.png").unlink()
    with pytest.raises(RecordError, match="missing target/mask of poisoned view images/0002.png") as err:
        AttackRecord.read(tmp_path)
    assert "\n" not in str(err.value) and isinstance(err.value, StealthNSError)


def test_append_rows_keeps_adam_and_strategy_state_in_step():
    params = torch.nn.ParameterDict({"means": torch.randn(5, 3), "tag": torch.zeros(5)})
    params["tag"].requires_grad_(False)
    adam = torch.optim.Adam([params["means"]], lr=0.1)
    params["means"].grad = torch.ones(5, 3)
    adam.step()
    state = {"grad2d": torch.ones(5), "count": torch.ones(5), "scene_scale": 1.0}
    old_means = params["means"].detach().clone()
    append_rows(params, {"means": adam}, state, {"means": torch.full((2, 3), 7.0), "tag": torch.ones(2)})
    assert torch.equal(params["means"][:5], old_means) and torch.equal(
        params["means"][5:], torch.full((2, 3), 7.0)
    )
    assert params["means"].requires_grad and not params["tag"].requires_grad
    assert adam.param_groups[0]["params"][0] is params["means"]
    moments = adam.state[params["means"]]
    assert moments["exp_avg"].shape == (7, 3) and not moments["exp_avg"][5:].any()
    assert state["grad2d"].shape == (7,) and state["scene_scale"] == 1.0
    params["means"].grad = torch.ones(7, 3)
    adam.step()  # no shape error
    with pytest.raises(ValueError, match="new rows for"):
        append_rows(params, {"means": adam}, state, {"means": torch.zeros(1, 3)})
    with pytest.raises(ValueError, match="disagree on their count"):
        append_rows(params, {"means": adam}, state, {"means": torch.zeros(1, 3), "tag": torch.ones(2)})


def test_model_appends_poison_rows_and_keeps_training():
    model, optimizers = build_model(n_points=50)
    cam, target = camera(), torch.rand(32, 48, 3)
    train_step(model, optimizers, 0, cam, target)
    n = model.num_points
    colors = torch.tensor([[0.2, 0.5, 0.9], [1.0, 0.0, 0.0]])
    model.append_gaussians(torch.zeros(2, 3), colors, torch.tensor([0.01, 0.02]), opacity=0.9)
    assert model.num_points == n + 2 and int(model.poison_mask.sum()) == 2
    assert torch.allclose(torch.sigmoid(model.opacities[n:]), torch.tensor(0.9))
    assert torch.allclose(torch.exp(model.scales[n:, 0]), torch.tensor([0.01, 0.02]))
    assert torch.allclose(model.colors[n:], colors, atol=1e-5)
    assert model.gauss_params[POISON_TAG][:n].sum() == 0
    train_step(model, optimizers, 1, cam, target)  # Adam and densification state grew with the rows


def test_render_camera_restores_mode_and_filter():
    model, _ = build_model(n_points=50)
    model.append_gaussians(torch.zeros(3, 3), torch.ones(3, 3), torch.full((3,), 0.05), opacity=0.99)
    model.train()
    everything = model.render_view(camera())["rgb"]
    hidden = render_camera(model, camera(), "hide_poison")["rgb"]
    assert model.training and model.render_filter == "all"
    assert not torch.equal(everything, hidden)
    model.eval()
    assert torch.equal(model.render_view(camera())["rgb"], everything) and not model.training


def test_viewer_filter_applies_only_in_viewer_render_threads(monkeypatch):
    import stealth_ns.method.model as model_module

    model, _ = build_model(n_points=50)
    model.append_gaussians(torch.zeros(3, 3), torch.ones(3, 3), torch.full((3,), 0.05), opacity=0.99)
    model.eval()
    shown = model.get_outputs_for_camera(camera())["rgb"]
    model.viewer_render_filter = "hide_poison"
    assert torch.equal(model.get_outputs_for_camera(camera())["rgb"], shown)  # evaluation: unfiltered
    monkeypatch.setattr(model_module, "_in_viewer_render_thread", lambda: True)
    hidden = model.get_outputs_for_camera(camera())["rgb"]
    assert not torch.equal(hidden, shown) and model.render_filter == "all"


def test_v_illusory_is_a_mean_over_every_view_or_none():
    per_view = {
        "a": {"psnr": 20.0, "ssim": 0.5, "lpips": 0.1},
        "b": {"psnr": 30.0, "ssim": 0.7, "lpips": None},
    }
    assert v_illusory(per_view) == {"psnr": 25.0, "ssim": pytest.approx(0.6), "lpips": None}
    assert v_illusory({}) == {"psnr": None, "ssim": None, "lpips": None}


def test_fail_exits_with_one_line_and_keeps_the_error():
    original = StealthNSError("the scene is empty")
    with pytest.raises(SystemExit) as exc:
        fail(original)
    assert isinstance(exc.value, StealthNSExit) and exc.value.error is original
    assert str(exc.value) == "stealth-ns: error: the scene is empty"
    with pytest.raises(StealthNSExit) as exc:
        fail("plain text")
    assert str(exc.value.error) == "plain text"
