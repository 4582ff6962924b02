"""The attack inside nerfstudio: datamanager images, injection, poison tags through densify/prune/reload."""

from __future__ import annotations

import pytest
import torch
from attack_helpers import Stepper, build_pipeline, poison_count, reload

from stealth_ns.attack.config import AttackConfig


@pytest.fixture(scope="module")
def scene(tiny_orbit_scene):
    return tiny_orbit_scene


def test_poisoned_view_gets_target_and_innocent_views_get_noise(scene):
    attack = AttackConfig(density_guided=False, noise_sigma0=30.0)
    pipeline = build_pipeline(scene, attack)
    Stepper(pipeline, max_steps=100)  # hands targets + noise to the datamanager
    dm = pipeline.datamanager
    view = pipeline.poison_views[0]
    cached_before = {i: dm.cached_train[i]["image"].clone() for i in range(len(dm.cached_train))}
    seen = {}
    for step in range(2 * len(dm.cached_train)):
        camera, data = dm.next_train(step)
        seen.setdefault(int(camera.metadata["cam_idx"]), []).append((step, data["image"].clone()))
    # the poisoned view is exactly the illusion composite, every time, without noise
    for _, image in seen[view.index]:
        assert torch.equal(image[..., :3], (view.target * 255).round().to(torch.uint8))
    # innocent views are noisy, deterministic per (seed, view, step), and the cache is untouched
    innocent = next(i for i in seen if i != view.index)
    step, noisy = seen[innocent][0]
    assert not torch.equal(noisy, cached_before[innocent])
    from stealth_ns.attack.noise_schedule import noise_sigma, noisy_image

    sigma = noise_sigma(step, 100, 30.0, "linear")
    assert torch.equal(noisy, noisy_image(cached_before[innocent], sigma, 0, innocent, step))
    for i, image in cached_before.items():
        assert torch.equal(dm.cached_train[i]["image"], image)
    # eval images are never touched
    for _ in range(len(dm.cached_eval)):
        _, data = dm.next_eval_image(step=0)
        assert any(torch.equal(data["image"], dm.cached_eval[j]["image"]) for j in range(len(dm.cached_eval)))


def test_the_poisoned_view_is_drawn_as_often_as_asked(scene):
    def passes(repeat: int) -> tuple[int, list[int]]:
        pipeline = build_pipeline(scene, AttackConfig(density_guided=False, poisoned_view_repeat=repeat))
        Stepper(pipeline, max_steps=100)
        dm = pipeline.datamanager
        n = len(dm.cached_train)
        order = [int(dm.next_train(step)[0].metadata["cam_idx"]) for step in range(4 * (n + repeat - 1))]
        return pipeline.poison_views[0].index, order

    view, once = passes(1)
    _, thrice = passes(3)
    _, again = passes(3)
    n = len(set(once))
    assert once.count(view) == 4 and all(once.count(i) == 4 for i in set(once))  # the paper's: once a pass
    assert thrice.count(view) == 12 and all(thrice.count(i) == 4 for i in set(thrice) - {view})
    assert thrice == again  # seeded
    assert [i for i in thrice[: n + 2] if i != view] == [i for i in once[:n] if i != view]  # same order


def test_injection_adds_one_poison_gaussian_per_mask_pixel_and_tags_survive(scene):
    attack = AttackConfig(injection_step=3, view_noise=False)
    pipeline = build_pipeline(scene, attack, stop_split_at=40, reset_alpha_every=4)
    stepper = Stepper(pipeline)
    n_mask = sum(int(v.mask.sum()) for v in pipeline.poison_views)
    for step in range(3):
        stepper.step(step)
    before = pipeline.model.num_points
    stepper.step(3)  # injection happens before this step's render
    model = pipeline.model
    assert poison_count(pipeline) == n_mask
    assert model.num_points == before + n_mask  # no refinement before the warm-up ends (step 5)
    # Adam state has rows for the new Gaussians after a training step
    for name in ("means", "features_dc", "opacities", "scales", "quats"):
        p = model.gauss_params[name]
        assert model.optimizers[name].state[p]["exp_avg"].shape[0] == model.num_points
    # poison Gaussians sit where they were put (finite, coloured like the illusion)
    poison = model.poison_mask
    assert torch.isfinite(model.means[poison]).all()
    for step in range(4, 40):  # refinement every 5 steps: duplicate/split/prune and an opacity reset
        stepper.step(step)
    n_poison = poison_count(pipeline)
    assert n_poison > 0
    assert model.gauss_params["poison"].shape[0] == model.num_points
    restored = reload(pipeline, scene, attack, step=39)
    assert poison_count(restored) == n_poison
    assert restored.model.num_points == model.num_points
    assert torch.equal(restored.model.poison_mask, model.poison_mask)


def test_bad_inputs_fail_before_training_with_one_line(scene, tmp_path):
    from PIL import Image

    cases = {
        "view index 999 is out of range": AttackConfig(views=("999",)),
        "unknown illusion": AttackConfig(illusion="no-such-object"),
        "does not fit": AttackConfig(illusion_scale=3.0),
    }
    empty = tmp_path / "empty.png"
    Image.new("RGBA", (16, 16), (255, 0, 0, 0)).save(empty)
    cases["empty"] = AttackConfig(illusion=str(empty))
    missing = tmp_path / "missing.png"
    cases["missing.png"] = AttackConfig(illusion=str(missing))
    for needle, attack in cases.items():
        with pytest.raises(SystemExit) as exc:
            build_pipeline(scene, attack)
        message = str(exc.value)
        assert message.startswith("stealth-ns: error:") and "\n" not in message, message
        assert needle.lower() in message.lower(), message
