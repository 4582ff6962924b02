"""IPA-Splat (stealth-ns ipa-poison): its rules as pure functions, its settings' checks, and one short
attacker run on a tiny scene whose poisoned copy must stay within the L-infinity budget and the angle
limit (everything else byte-identical, the input never written)."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_cli

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.record import AttackRecord
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image
from stealth_ns.poisoned_datasets.config import IPAConfig
from stealth_ns.poisoned_datasets.ipa import (
    angles_to,
    clip_parameter_change,
    linf_project,
    nearest_views,
    viewing_directions,
    views_within_angle,
)
from stealth_ns.scene_generator import make_scene

# ---------------------------------------------------------------------------------- pure functions


def test_linf_project_keeps_the_budget_and_the_unit_range():
    gen = torch.Generator().manual_seed(0)
    clean = torch.rand(12, 16, 3, generator=gen)
    clean[0, 0] = torch.tensor([0.0, 1.0, 0.99])  # at the range's ends
    image = clean + (torch.rand(12, 16, 3, generator=gen) - 0.5) * 0.6  # some far, some near
    eps = 16 / 255
    out = linf_project(image, clean, eps)
    assert out.shape == clean.shape
    assert float((out - clean).abs().max()) <= eps + 1e-6
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    # inside the ball (and the range) nothing moves; outside it lands on the ball's surface
    near = ((image - clean).abs() <= eps) & (image >= 0) & (image <= 1)
    assert bool(near.any())
    torch.testing.assert_close(out[near], image[near])
    far = ((image - clean).abs() > eps) & (clean + eps <= 1) & (clean - eps >= 0)
    assert bool(far.any())
    torch.testing.assert_close((out - clean).abs()[far], torch.full_like(out[far], eps))
    torch.testing.assert_close(linf_project(clean, clean, eps), clean)
    # the sign of the change is kept
    assert bool(((out - clean) * (image - clean) >= 0).all())


def _yaw_poses(degrees: list[float], centres: np.ndarray | None = None) -> np.ndarray:
    """[N, 3, 4] OpenGL camera-to-world poses looking along -z rotated by ``degrees`` about +y."""
    poses = []
    for i, a in enumerate(np.radians(degrees)):
        r = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
        t = np.zeros(3) if centres is None else centres[i]
        poses.append(np.concatenate([r, t[:, None]], axis=1))
    return np.stack(poses)


def test_viewing_directions_and_angles():
    poses = _yaw_poses([0, 30, 90, 180])
    d = viewing_directions(poses)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    np.testing.assert_allclose(d[0], [0, 0, -1], atol=1e-12)  # OpenGL cameras look down -z
    np.testing.assert_allclose(angles_to(poses, 0), [0, 30, 90, 180], atol=1e-6)
    np.testing.assert_allclose(angles_to(torch.from_numpy(poses).float(), 1), [30, 0, 60, 150], atol=1e-3)
    scaled = poses.copy()
    scaled[:, :3, :3] *= 3.0  # a scaled rotation (as after nerfstudio's scaling) gives the same angles
    np.testing.assert_allclose(angles_to(scaled, 0), [0, 30, 90, 180], atol=1e-6)


def test_views_within_angle():
    poses = _yaw_poses([0, 10, 19.9, 20.1, 45, -15, 170, 100])
    assert views_within_angle(poses, [0], 20) == [0, 1, 2, 5]
    assert views_within_angle(poses, [0], 19.85) == [0, 1, 5]
    assert views_within_angle(poses, [0], 0) == [0]  # the backdoor always
    assert views_within_angle(poses, [0], 180) == list(range(8))
    # several backdoor views: the union, each backdoor included whatever the angle
    assert views_within_angle(poses, [0, 6], 12) == [0, 1, 6]
    assert views_within_angle(poses, [4, 7], 0) == [4, 7]
    assert views_within_angle(torch.from_numpy(poses), [7], 60) == [4, 7]  # 45: 55 degrees; 170: 70 > 60


def test_nearest_views_order_exclusion_and_ties():
    x = np.array([0.0, 1.0, -1.0, 2.0, 5.0, -2.0, 0.5])
    poses = _yaw_poses([0] * len(x), np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1))
    # from view 0: 6 (0.5), then 1 and 2 tie at 1 (by index), then 3 and 5 tie at 2
    assert nearest_views(poses, 0, 4) == [6, 1, 2, 3]
    assert nearest_views(poses, 0, 5) == [6, 1, 2, 3, 5]
    assert nearest_views(poses, 0, 3, exclude=[6, 1]) == [2, 3, 5]
    assert nearest_views(poses, 0, 100) == [6, 1, 2, 3, 5, 4]  # never the view itself
    assert nearest_views(poses, 0, 0) == []
    assert nearest_views(poses, 4, 2, exclude=[4]) == [3, 1]
    assert nearest_views(torch.from_numpy(poses).float(), 3, 2) == [1, 6]


def test_clip_parameter_change_bounds_each_group_in_place():
    gen = torch.Generator().manual_seed(1)
    reference = {"means": torch.randn(50, 3, generator=gen), "opacities": torch.randn(50, 1, generator=gen),
                 "empty": torch.zeros(0, 3)}  # fmt: skip
    moved = {
        "means": reference["means"] + torch.randn(50, 3, generator=gen),
        "opacities": reference["opacities"] + 0.01 * torch.randn(50, 1, generator=gen),
        "empty": torch.zeros(0, 3),
    }
    params = {k: torch.nn.Parameter(v.clone()) for k, v in moved.items()}
    ids = {k: id(p) for k, p in params.items()}
    budgets = {"means": 0.1, "opacities": 0.5, "empty": 1.0}
    largest = clip_parameter_change(params, reference, budgets)
    assert {k: id(p) for k, p in params.items()} == ids  # the same parameters, changed in place
    assert set(largest) == {"means", "opacities", "empty"} and largest["empty"] == 0.0
    for name in ("means", "opacities"):
        change = (params[name].detach() - reference[name]).abs()
        assert float(change.max()) <= budgets[name] + 1e-6
        assert largest[name] == pytest.approx(float(change.max()), abs=1e-6)
        small = (moved[name] - reference[name]).abs() <= budgets[name]
        torch.testing.assert_close(params[name].detach()[small], moved[name][small])  # left as it was
    assert largest["means"] == pytest.approx(0.1, abs=1e-6)  # many coordinates hit the budget
    assert largest["opacities"] < 0.5  # none did
    assert params["means"].requires_grad  # still a parameter to optimise


# ---------------------------------------------------------------------------------- settings
@pytest.mark.parametrize(
    "field, value, option",
    [
        ("epsilon", 0.0, "--epsilon"),
        ("epsilon", 300.0, "--epsilon"),
        ("every", 0, "--every"),
        ("attack_steps", 0, "--attack-steps"),
        ("every", 2.5, "--every"),
        ("neighbours", -1, "--neighbours"),
        ("angle_limit", 200.0, "--angle-limit"),
        ("angle_limit", -1.0, "--angle-limit"),
        ("neighbour_weight", -0.1, "--neighbour-weight"),
        ("budget_means", -0.1, "--budget-"),
    ],
)
def test_ipa_config_validate_names_the_bad_option(field, value, option):
    IPAConfig().validate()  # the defaults are fine
    with pytest.raises(StealthNSError, match=option) as err:
        IPAConfig(**{field: value}).validate()
    assert "\n" not in str(err.value)


def test_ipa_config_budgets_cover_every_parameter_group():
    from stealth_ns.method.model import TRAINABLE

    budgets = IPAConfig(budget_features=0.3).budgets()
    assert set(budgets) == set(TRAINABLE)
    assert budgets["features_dc"] == budgets["features_rest"] == 0.3


# ---------------------------------------------------------------------------------- a short run
def tree_hashes(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


#: As the CLI builds it: the illusion and backdoor view only, every StealthAttack component off.
IPA_ATTACK = AttackConfig(gt_replacement=False, density_guided=False, view_noise=False)
#: A short run: 2 attack epochs of 2 Adam steps; 40 degrees takes the orbit's two neighbours (30 apart).
SHORT = IPAConfig(every=10, attack_steps=2, neighbours=2, angle_limit=40.0)
ITERATIONS = 20


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ipa_scene") / "scene"
    make_scene(preset="orbit", output=out, resolution="48x36", views=12, seed=0)
    return out


@pytest.fixture(scope="module")
def ipa_copy(scene, tmp_path_factory) -> tuple[Path, dict[str, str], str]:
    from stealth_ns.poisoned_datasets.ipa_splat import ipa_poison

    before = tree_hashes(scene)
    out = tmp_path_factory.mktemp("ipa_out") / "poisoned"
    summary = ipa_poison(scene, out, IPA_ATTACK, SHORT, iterations=ITERATIONS)
    return out, before, summary


@pytest.mark.slow
def test_ipa_poison_writes_bounded_perturbations_near_the_backdoor_only(ipa_copy, scene):
    out, before, summary = ipa_copy
    assert tree_hashes(scene) == before  # the input is never written
    meta = json.loads((scene / "transforms.json").read_text())
    assert json.loads((out / "transforms.json").read_text()) == meta

    record = AttackRecord.read(out / "attack")
    info = record.poisoned_dataset
    assert info["threat_model"] == "ipa-splat" and info["complete"] is True
    assert info["ipa"]["epsilon"] == SHORT.epsilon and info["ipa"]["angle_limit"] == SHORT.angle_limit
    assert record.injection is None and info["seed_points_added"] == 0
    (view,) = record.views
    train, evals = list(meta["train_filenames"]), list(meta["test_filenames"])
    assert view.name == train[view.index]

    # the perturbed views: those within the angle limit of the backdoor, from the poses on disk
    by_name = {f["file_path"]: np.asarray(f["transform_matrix"]) for f in meta["frames"]}
    poses = np.stack([by_name[name][:3] for name in train])
    angles = angles_to(poses, view.index)
    expected = [name for name, a in zip(train, angles, strict=True) if a <= SHORT.angle_limit]
    assert view.name in expected and 1 < len(expected) < len(train)  # the test is about a real split
    assert info["perturbed_views"] == expected
    assert set(info["images_written"]) == set(expected)
    # (as a set: the orbit's two nearest views are at the same distance, so their order is a tie)
    (listed,) = info["neighbours"].values()
    assert list(info["neighbours"]) == [view.name]
    assert set(listed) == set(nearest_views_names(poses, train, view.index, SHORT.neighbours))

    epochs = info["epochs"]
    assert [e["step"] for e in epochs] == list(range(0, ITERATIONS, SHORT.every))
    budgets = SHORT.budgets()
    for epoch in epochs:
        assert set(epoch["largest_change"]) == set(budgets)
        for group, change in epoch["largest_change"].items():
            assert change <= budgets[group] + 1e-6, (group, change)

    differs = 0
    for name in train:
        clean = read_image(scene / name, "clean").astype(np.int16)
        written = read_image(out / name, "written").astype(np.int16)
        if name in expected:
            linf = int(np.abs(written - clean).max())
            assert linf <= SHORT.epsilon, (name, linf)
            assert info["images_written"][name]["linf_255"] == linf
            differs += linf > 0
        else:
            assert (scene / name).read_bytes() == (out / name).read_bytes(), name
    assert differs >= 1
    for name in evals:
        assert (scene / name).read_bytes() == (out / name).read_bytes(), name
    assert f"{len(epochs)} attack epochs" in summary and str(out) in summary


def nearest_views_names(poses: np.ndarray, names: list[str], index: int, k: int) -> list[str]:
    """Independently of nearest_views: the k training views with the nearest camera centres."""
    centres = poses[:, :3, 3]
    dist = np.linalg.norm(centres - centres[index], axis=1)
    order = sorted((d, i) for i, d in enumerate(dist) if i != index)
    return [names[i] for _, i in order[:k]]


def assert_one_error_line(stderr: str, expected: str) -> None:
    """The error is one line ``stealth-ns: error: ...``, the last of stderr (libraries may warn before)."""
    lines = stderr.strip().splitlines()
    errors = [line for line in lines if line.startswith("stealth-ns:")]
    assert len(errors) == 1 and errors[0] == lines[-1], stderr[-3000:]
    assert errors[0].startswith("stealth-ns: error:") and expected in errors[0], errors[0]


def test_ipa_poison_refuses_bad_settings_before_writing(scene, tmp_path):
    from stealth_ns.poisoned_datasets.ipa_splat import ipa_poison

    with pytest.raises(StealthNSError, match="--epsilon"):
        ipa_poison(scene, tmp_path / "out", IPA_ATTACK, IPAConfig(epsilon=0), iterations=5)
    with pytest.raises(StealthNSError, match="inside the input dataset"):
        ipa_poison(scene, scene / "poisoned", IPA_ATTACK, SHORT, iterations=5)
    assert not (tmp_path / "out").exists() and not (scene / "poisoned").exists()


def test_ipa_poison_missing_view_writes_nothing(scene, tmp_path):
    """A misspelt --views is a one-line error, and (as poison-dataset) leaves no output behind, so the
    corrected command can be run as it is."""
    from dataclasses import replace

    from stealth_ns.poisoned_datasets.ipa_splat import ipa_poison

    attack = replace(IPA_ATTACK, views=("frame_0006.png",))
    with pytest.raises(StealthNSError, match=r"unknown view name 'frame_0006.png'.*did you mean") as err:
        ipa_poison(scene, tmp_path / "out", attack, SHORT, iterations=5)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists(), sorted(p.name for p in (tmp_path / "out").iterdir())


@pytest.mark.parametrize(
    "extra, expected",
    [
        (("--epsilon", "0"), "--epsilon must be in (0, 255]"),
        (("--iterations", "0"), "--iterations must be a positive integer"),
    ],
    ids=["epsilon", "iterations"],
)
def test_cli_errors_are_one_line_with_status_2(scene, tmp_path, extra, expected):
    args = ["--data", str(scene), "--output", str(tmp_path / "out"), *extra]
    proc = run_cli("stealth-ns", "ipa-poison", *args, check=False, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert_one_error_line(proc.stderr, expected)
    assert not (tmp_path / "out").exists()
