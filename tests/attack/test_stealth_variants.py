"""The stealth-aware variants and the defence that answers them (docs/design/stealth.md): support views
(the poison's support spreads over the poisoned view's neighbours, which show it too), the surface
placement, and camera-proximity."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from attack_helpers import Stepper, build_pipeline

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.injection import SURFACE_OFFSET, on_surface
from stealth_ns.attack.record import AttackRecord
from stealth_ns.attack.support import render_poison, support_target
from stealth_ns.attack.validation import validate_attack_config
from stealth_ns.attack.views import nearest_views
from stealth_ns.defence_eval.evaluate import defender_images
from stealth_ns.defences.scores import camera_proximity_scores, concentration_scores, frustum_depth_ratios
from stealth_ns.defences.signals import view_weight_matrix
from stealth_ns.foundation.errors import StealthNSError


def _poses(centres, looks_back=()) -> np.ndarray:
    """[N, 3, 4] OpenGL poses at ``centres`` looking down world -Z (+Z for indices in ``looks_back``)."""
    c2w = np.zeros((len(centres), 3, 4))
    for i, c in enumerate(centres):
        c2w[i, :3, :3] = np.diag([-1.0, 1.0, -1.0]) if i in looks_back else np.eye(3)
        c2w[i, :, 3] = c
    return c2w


def test_nearest_views_by_centre_distance_looking_the_same_way():
    c2w = _poses([(0, 0, 0), (1, 0, 0), (-0.5, 0, 0), (0.2, 0, 0), (3, 0, 0), (-1, 0, 0)], looks_back={3})
    assert nearest_views(c2w, 0, 2) == [2, 1]  # 3 is nearest but looks the other way
    assert nearest_views(c2w, 0, 3) == [2, 1, 5]  # 1 and 5 tie at distance 1: lower index first
    assert nearest_views(c2w, 0, 2, exclude=[2]) == [1, 5]
    with pytest.raises(StealthNSError, match="only 4 other training views looking the same way"):
        nearest_views(c2w, 0, 5)


def test_support_views_need_the_poison_and_its_images():
    validate_attack_config(AttackConfig(support_views=3))
    with pytest.raises(StealthNSError, match="support-views 3 shows the poison in more views: it needs"):
        validate_attack_config(AttackConfig(support_views=3, density_guided=False))
    with pytest.raises(StealthNSError, match=r"support-views must be an integer in \[0, 8\], got 9"):
        validate_attack_config(AttackConfig(support_views=9))
    with pytest.raises(StealthNSError, match="placement must be one of view-aware, kde, surface"):
        validate_attack_config(AttackConfig(placement="shared"))  # type: ignore[arg-type]


def test_a_support_view_shows_the_poison_over_its_own_image():
    # one opaque-ish red Gaussian 2 units in front of a camera at the origin (OpenCV, looking down +Z)
    K = torch.tensor([[20.0, 0.0, 10.0], [0.0, 20.0, 10.0], [0.0, 0.0, 1.0]])
    rgb, alpha = render_poison(
        torch.tensor([[0.0, 0.0, 2.0]]),
        torch.tensor([[1.0, 0.0, 0.0]]),
        torch.tensor([0.2]),
        torch.eye(4),
        K,
        20,
        20,
    )
    assert rgb.shape == (20, 20, 3) and alpha.shape == (20, 20)
    assert float(alpha[10, 10]) > 0.9 and float(alpha[0, 0]) < 1e-3
    clean = torch.full((20, 20, 3), 0.25)
    out = support_target(clean, rgb, alpha)
    assert out[10, 10, 0] > 0.9 and out[10, 10, 1] < 0.05  # the poison covers the centre
    torch.testing.assert_close(out[0, 0], clean[0, 0], atol=1e-3, rtol=0)  # its own image elsewhere
    empty = render_poison(torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(0), torch.eye(4), K, 20, 20)
    assert float(empty[1].max()) == 0.0


def test_surface_placement_sits_just_in_front_of_the_rendered_surface():
    o, d = torch.zeros(3, 3), torch.tensor([[0.0, 0.0, -1.0]]).repeat(3, 1)
    found = on_surface(o, d, torch.tensor([5.0, 0.1, float("nan")]), torch.tensor([0.5, 0.5, 0.5]))
    assert found.valid.tolist() == [True, False, False]  # the second surface is nearer than t_min
    assert float(found.t[0]) == pytest.approx(5.0 * (1 - SURFACE_OFFSET))
    assert float(found.points[0, 2]) == pytest.approx(-5.0 * (1 - SURFACE_OFFSET))


def test_support_views_spread_the_poison_over_several_views(tiny_orbit_scene):
    """At the injection the poison goes where the poisoned view's 3 nearest views see it too, their
    training images become its render over their own, and its blending weight spreads over them."""
    spread = {}
    for k in (0, 3):
        pipeline = build_pipeline(tiny_orbit_scene, AttackConfig(support_views=k))
        stepper = Stepper(pipeline)
        stepper.step(0)  # the injection runs before step 0
        model, dm = pipeline.model, pipeline.datamanager
        cams = dm.train_dataset.cameras
        poison = model.poison_mask.cpu().numpy()
        weights = view_weight_matrix(model, cams)[poison]
        seen = weights.sum(axis=1) > 1e-3
        spread[k] = float(np.median(1.0 / concentration_scores(weights[seen])))
        if k == 0:
            assert pipeline.support_views == {} and pipeline.record.support_targets == {}
            continue
        (view,) = pipeline.poison_views
        support = pipeline.support_views[view.index]
        assert support == nearest_views(cams.camera_to_worlds, view.index, 3)
        assert pipeline.record.injection.support_views == {
            view.name: [dm.train_image_names[i] for i in support]
        }
        assert pipeline.record.injection.support_views_seeing_poison[view.name] > 1.0
        for i in support:  # the datamanager serves each support view's poisoned image, noise-free
            served = dm.poison_targets[i]
            assert served.dtype == dm.cached_train[i]["image"].dtype
            changed = (served.float() - dm.cached_train[i]["image"].float()).abs().amax(-1) > 8
            assert changed.any(), f"support view {i} does not show the poison"
        # the defender trains on the same images
        target = SimpleNamespace(run=SimpleNamespace(pipeline=pipeline), record=pipeline.record)
        images = defender_images(target)
        for i in support:
            assert torch.equal(images[i], dm.poison_targets[i])
    assert spread[3] >= 2.0 and spread[3] > 1.5 * spread[0], spread


def test_depth_floor_moves_the_poison_out_of_camera_proximitys_reach(tiny_orbit_scene):
    """The adaptive variant against camera-proximity: at the injection no poison Gaussian sits nearer a
    camera that has it in view than the floor's share of that camera's scene depth (the defence's
    own ratio, measured on the model after the injection); the default attack's poison does."""
    from stealth_ns.method.camera_geometry import camera_geometry

    ratios = {}
    for floor in (0.0, 0.3):
        pipeline = build_pipeline(tiny_orbit_scene, AttackConfig(depth_floor=floor))
        Stepper(pipeline).step(0)  # the injection runs before step 0
        model = pipeline.model
        geometry = camera_geometry(model, pipeline.datamanager.train_dataset.cameras)
        means = model.means.detach().cpu().numpy()[model.poison_mask.cpu().numpy()]
        ratios[floor] = frustum_depth_ratios(
            means, geometry.viewmats, geometry.Ks, geometry.sizes, geometry.scene_depths
        )
        injection = pipeline.record.injection
        if floor:
            (dropped,) = injection.rays_below_depth_floor_per_view.values()
            assert injection.n_poison_gaussians + dropped == int(pipeline.poison_views[0].mask.sum())
        else:
            assert injection.rays_below_depth_floor_per_view == {}
    assert np.median(ratios[0.0]) < 0.15  # the default: in front of its camera, where the defence cuts
    floored = ratios[0.3]
    assert floored.size and np.quantile(floored, 0.01) >= 0.27, np.quantile(floored, [0, 0.01, 0.5])


def test_proximity_hinge_is_the_defences_ratio_below_the_target():
    from stealth_ns.attack.proximity_term import draw_points, proximity_hinge

    viewmats = torch.stack([torch.eye(4), torch.eye(4)])
    viewmats[1, :3, 3] = torch.tensor([0.0, 0.0, 2.0])  # 2 units behind the first camera
    Ks = torch.tensor([[10.0, 0, 10], [0, 10.0, 10], [0, 0, 1]]).expand(2, 3, 3)
    sizes, depths = torch.tensor([[20.0, 20.0], [20.0, 20.0]]), torch.tensor([4.0, 10.0])
    means = torch.tensor(
        [
            [0.0, 0.0, 1.0],  # ratios 0.25 and 0.3: 1 - 0.25 / 0.5 = 0.5
            [0.0, 0.0, 3.0],  # ratios 0.75 and 0.5: at or beyond the target, 0
            [50.0, 0.0, 1.0],  # in no camera's image: 0
        ],
        requires_grad=True,
    )
    value = proximity_hinge(means, viewmats, Ks, sizes, depths, target=0.5)
    assert float(value.detach()) == pytest.approx(0.5 / 3)
    value.backward()
    # only the point inside the reach is pushed, away from the camera that binds (camera 0, along +z)
    assert means.grad[0, 2] < 0 and torch.all(means.grad[1:] == 0)
    assert float(proximity_hinge(means[:0], viewmats, Ks, sizes, depths, 0.5)) == 0.0
    assert draw_points(10, step=3, seed=0, limit=20) is None
    drawn = draw_points(100, step=3, seed=0, limit=20)
    assert drawn.shape == (20,) and torch.equal(drawn, draw_points(100, step=3, seed=0, limit=20))
    assert not torch.equal(drawn, draw_points(100, step=4, seed=0, limit=20))


def test_proximity_weight_trains_the_poison_out_of_the_defences_reach(tiny_orbit_scene):
    """The white-box variant: the default attack's poison, trained with the term, moves away from the
    cameras that have it in view (camera-proximity's ratio grows), and the term is a loss of its own."""
    from stealth_ns.method.camera_geometry import camera_geometry

    medians, terms = {}, {}
    for weight in (0.0, 10.0):
        pipeline = build_pipeline(
            tiny_orbit_scene, AttackConfig(proximity_weight=weight, proximity_target=0.5)
        )
        stepper = Stepper(pipeline)
        for step in range(40):
            stepper.step(step)
        terms[weight] = set(pipeline.get_train_loss_dict(step=40)[1])
        model = pipeline.model
        geometry = camera_geometry(model, pipeline.datamanager.train_dataset.cameras)
        means = model.means.detach().cpu().numpy()[model.poison_mask.cpu().numpy()]
        ratios = frustum_depth_ratios(
            means, geometry.viewmats, geometry.Ks, geometry.sizes, geometry.scene_depths
        )
        medians[weight] = float(np.median(ratios))
    assert "poison_proximity" in terms[10.0] and "poison_proximity" not in terms[0.0]
    # Adam moves a centre by about its learning rate a step, whatever the weight: in 40 steps the
    # poison moves a little, but outward
    assert medians[10.0] > 1.03 * medians[0.0], medians


def test_the_record_keeps_the_support_views_images(tmp_path):
    view = SimpleNamespace(
        index=0,
        name="a.png",
        mask=torch.zeros(4, 4, dtype=torch.bool),
        target=torch.zeros(4, 4, 3),
        camera_json=lambda: {"c2w": np.eye(4)[:3].tolist(), "fx": 1.0, "fy": 1.0, "cx": 2.0, "cy": 2.0},
    )
    image = torch.rand(4, 4, 3)
    record = AttackRecord(config={}, views=[view], injection_step=0, noise=None, support_targets={5: image})
    record.write(tmp_path)
    assert (tmp_path / "view0005_support.png").is_file()
    back = AttackRecord.read(tmp_path)
    torch.testing.assert_close(back.support_targets[5], image)
    (tmp_path / "views.npz").unlink()  # an older record: the 8-bit picture
    back = AttackRecord.read(tmp_path)
    torch.testing.assert_close(back.support_targets[5], image, atol=1 / 255, rtol=0)


def test_camera_proximity_ratio_is_depth_over_the_cameras_scene_depth():
    viewmats = np.stack([np.eye(4), np.eye(4)])
    viewmats[1, :3, 3] = [0.0, 0.0, 2.0]  # the second camera sits 2 units behind the first (world z -2)
    Ks = np.stack([np.array([[10.0, 0, 10], [0, 10.0, 10], [0, 0, 1]])] * 2)
    sizes = np.array([[20, 20], [20, 20]])
    means = np.array(
        [
            [0.0, 0.0, 1.0],  # z 1 in camera 0 (scene depth 4): 0.25; z 3 in camera 1 (depth 10): 0.3
            [0.0, 0.0, -1.0],  # behind camera 0; z 1 in camera 1: 0.1
            [50.0, 0.0, 1.0],  # outside both images
            [np.nan, 0.0, 1.0],
        ]
    )
    ratios = frustum_depth_ratios(means, viewmats, Ks, sizes, np.array([4.0, 10.0]))
    np.testing.assert_allclose(ratios[:2], [0.25, 0.1])
    assert np.isinf(ratios[2]) and ratios[3] == 0.0
    scores = camera_proximity_scores(ratios)
    assert list(np.argsort(-scores, kind="stable")) == [3, 1, 0, 2]  # nearest first, never-in-view last
    assert np.isneginf(scores[2])
    with pytest.raises(ValueError, match="scene_depths must be finite and > 0"):
        frustum_depth_ratios(means, viewmats, Ks, sizes, np.array([4.0, 0.0]))
