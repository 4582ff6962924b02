"""stealth-ns scan: 3DGS PLYs in and out, frames, the verdict on tiny runs, a PLY victim in the report."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_cli, train_tiny
from numpy.lib import recfunctions

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.ply import GaussianCloud, read_gaussian_ply, write_gaussian_ply
from stealth_ns.gaussians.transform import _SH_ROWS_PER_BLOCK, transform_cloud
from stealth_ns.raster.projection import quat_to_rotmat, spherical_harmonics, viewmat_from_c2w


def make_cloud(n: int = 7, degree: int = 3, seed: int = 0, **extra: np.ndarray) -> GaussianCloud:
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1

    def f(*shape: int) -> np.ndarray:
        return rng.normal(size=shape).astype(np.float32)

    return GaussianCloud(f(n, 3), f(n, 3), f(n, 4), f(n), f(n, 3), f(n, k, 3), dict(extra))


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_a_ply_reads_back_exactly(tmp_path, degree):
    cloud = make_cloud(degree=degree, poison=np.array([0, 1, 0, 0, 1, 1, 0], dtype=np.uint8))
    write_gaussian_ply(tmp_path / "m.ply", cloud)
    back = read_gaussian_ply(tmp_path / "m.ply")
    assert back.sh_degree == degree and len(back) == 7
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest"):
        assert np.array_equal(getattr(back, name), getattr(cloud, name)), name
    assert np.array_equal(back.extra["poison"], cloud.extra["poison"])
    # the official layout: channel-major f_rest (all of red's coefficients first)
    from plyfile import PlyData

    vertex = PlyData.read(str(tmp_path / "m.ply"))["vertex"]
    if degree:
        k = (degree + 1) ** 2 - 1
        assert np.array_equal(vertex["f_rest_1"], cloud.sh_rest[:, 1, 0])
        assert np.array_equal(vertex[f"f_rest_{k}"], cloud.sh_rest[:, 0, 1])


def _write_raw(path: Path, rows: np.ndarray) -> Path:
    from plyfile import PlyData, PlyElement

    PlyData([PlyElement.describe(rows, "vertex")]).write(str(path))
    return path


def _rows(cloud: GaussianCloud, drop: str = "") -> np.ndarray:
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", *[f"scale_{i}" for i in range(3)]]
    names += [f"rot_{i}" for i in range(4)]
    names = [n for n in names if n != drop]
    rows = np.zeros(len(cloud), dtype=[(n, "<f4") for n in names])
    for n in names:
        rows[n] = 0.5
    return rows


def test_bad_plys_are_one_line(tmp_path):
    cloud = make_cloud(degree=0)
    cases = {
        "lacks rot_3": _write_raw(tmp_path / "missing.ply", _rows(cloud, drop="rot_3")),
        "holds no Gaussians": _write_raw(tmp_path / "empty.ply", _rows(make_cloud(n=0, degree=0))),
        "not a readable PLY": tmp_path / "text.ply",
        "no PLY file": tmp_path / "absent.ply",
    }
    (tmp_path / "text.ply").write_text("hello")
    nan = make_cloud(degree=3)
    nan.means[4, 1] = np.nan
    write_gaussian_ply(tmp_path / "nan.ply", nan)
    # one broken row of 7 is far above the share a reader leaves out (1 %): refused, not left out
    cases["1 of 7 Gaussians have a NaN, infinite or zero-rotation value (rows 4): 14.3% of its rows"] = (
        tmp_path / "nan.ply"
    )
    odd = _rows(cloud)
    odd = recfunctions.append_fields(odd, "f_rest_0", np.zeros(len(odd), "<f4"), usemask=False)
    cases["1 f_rest_* properties fit no SH degree"] = _write_raw(tmp_path / "odd.ply", odd)
    for needle, path in cases.items():
        with pytest.raises(StealthNSError, match=re.escape(needle)) as info:
            read_gaussian_ply(path)
        assert "\n" not in str(info.value)


def test_a_frame_change_keeps_every_gaussian_as_seen():
    from scipy.spatial.transform import Rotation

    cloud = make_cloud(n=5, degree=3, seed=1)
    s, r, t = 2.5, Rotation.random(random_state=3).as_matrix(), np.array([1.0, -2.0, 3.0])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = s * r, t
    moved = transform_cloud(cloud, m)
    assert np.allclose(moved.means, cloud.means @ (s * r).T + t, atol=1e-5)

    def covariances(c: GaussianCloud) -> np.ndarray:
        q = torch.from_numpy(c.quats.astype(np.float64))
        rot = quat_to_rotmat(q / q.norm(dim=1, keepdim=True)).numpy()
        return rot @ (np.exp(2 * c.log_scales.astype(np.float64))[:, :, None] * rot.transpose(0, 2, 1))

    assert np.allclose(covariances(moved), s * s * r @ covariances(cloud) @ r.T, atol=1e-4)
    # the colour seen along R d in the new frame is the colour seen along d before
    d = torch.from_numpy(np.random.default_rng(2).normal(size=(5, 3)))

    def colours(c: GaussianCloud, dirs: torch.Tensor) -> torch.Tensor:
        coeffs = torch.from_numpy(np.concatenate([c.sh_dc[:, None], c.sh_rest], 1).astype(np.float64))
        return spherical_harmonics(3, dirs, coeffs)

    assert torch.allclose(colours(cloud, d), colours(moved, d @ torch.from_numpy(r.T)), atol=1e-5)


def test_the_colour_rotation_is_the_same_in_every_block_of_rows():
    """The SH coefficients are rotated a block of rows at a time: rows in the first, a middle and the
    last, partial block come out as each row rotated alone."""
    from scipy.spatial.transform import Rotation

    cloud = make_cloud(n=2 * _SH_ROWS_PER_BLOCK + 3, degree=3, seed=4)
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=5).as_matrix()
    moved = transform_cloud(cloud, m)
    for row in (0, _SH_ROWS_PER_BLOCK - 1, _SH_ROWS_PER_BLOCK, len(cloud) - 1):
        alone = transform_cloud(cloud.subset(np.array([row])), m)
        assert np.array_equal(moved.sh_rest[row], alone.sh_rest[0]), row
        assert not np.array_equal(moved.sh_rest[row], cloud.sh_rest[row])


def test_a_dataset_frame_point_projects_where_the_dataset_says(tiny_orbit_scene):
    """A Gaussian 2 units along the optical axis of a camera of transforms.json, in the dataset's frame,
    lands on that camera's principal point once loaded (the known projection of docs/design/scan.md)."""
    from stealth_ns.datasets.frames import frame_transforms
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.method.datamanager import dataset_image_names
    from stealth_ns.runs.imported import host_config, host_run

    scene = inspect_folder("--data", str(tiny_orbit_scene))
    run = host_run(host_config(scene), tiny_orbit_scene / "x.ply")
    dm = run.pipeline.datamanager
    names = dataset_image_names(tiny_orbit_scene, dm.train_dataparser_outputs.image_filenames)
    meta = json.loads((tiny_orbit_scene / "transforms.json").read_text())
    frame = next(f for f in meta["frames"] if f["file_path"].lstrip("./") == names[3])
    c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)  # OpenGL: the camera looks down -z
    point = c2w[:3, 3] - 2.0 * c2w[:3, 2]
    cloud = make_cloud(n=1, degree=0)
    cloud.means[:] = point
    moved = transform_cloud(cloud, frame_transforms(dm.train_dataparser_outputs, scene)["dataset"])
    cameras = dm.train_dataset.cameras
    view = viewmat_from_c2w(cameras.camera_to_worlds[3:4].float())[0].double().numpy()
    k = cameras.get_intrinsics_matrices()[3].double().numpy()
    p = view[:3, :3] @ moved.means[0].astype(np.float64) + view[:3, 3]
    uv = (k @ (p / p[2]))[:2]
    assert np.allclose(uv, [meta.get("cx", frame.get("cx")), meta.get("cy", frame.get("cy"))], atol=1e-3)


# ------------------------------------------------------------------ the scan on tiny runs
@pytest.fixture(scope="module")
def poisoned_run(tiny_poisoned_run) -> Path:
    """A poisoned run of the tiny scene trained long enough (300 steps) for its illusion to show."""
    return tiny_poisoned_run


def _scan(model: Path, out: Path, data: Path | None = None) -> dict:
    from stealth_ns.scan.command import run_scan
    from stealth_ns.scan.config import ScanConfig

    return run_scan(model, data, out, ScanConfig())


def test_scan_names_the_poisoned_view_and_calls_the_clean_run_clean(poisoned_run, tiny_run_pair, tmp_path):
    poisoned, clean = poisoned_run, tiny_run_pair[1]
    record = json.loads((poisoned.parent / "attack" / "attack.json").read_text())
    truth = [v["name"] for v in record["poisoned_views"]]
    doc = _scan(poisoned, tmp_path / "p")
    assert doc["verdict"] == "suspicious" and [t["name"] for t in doc["targeted_views"]] == truth
    gt = doc["ground_truth"]
    assert gt["removed_poison"] > 0.5 * gt["n_poison"] and gt["removed_clean"] < gt["removed_poison"]
    for kind in ("full", "without", "flagged", "effect"):
        assert (tmp_path / "p" / doc["images"][truth[0]][kind]).is_file()
    assert "suspicious" in (tmp_path / "p" / "scan.html").read_text()
    cleaned = read_gaussian_ply(tmp_path / "p" / "cleaned.ply")
    assert len(cleaned) == doc["model"]["gaussians"] - doc["removed"]
    assert (tmp_path / "p" / doc["cleaned"]["run"]).is_file()
    assert _scan(clean, tmp_path / "c")["verdict"] == "clean"


def test_scan_of_the_ns_export_ply_matches_the_run(poisoned_run, tiny_orbit_scene, tmp_path):
    poisoned = poisoned_run
    run_cli(
        "ns-export", "gaussian-splat", "--load-config", str(poisoned), "--output-dir", str(tmp_path / "e")
    )
    ply = tmp_path / "e" / "splat.ply"
    of_run = _scan(poisoned, tmp_path / "run")
    of_ply = _scan(ply, tmp_path / "ply", tiny_orbit_scene)
    assert of_ply["model"]["frame"] == "nerfstudio"
    assert (
        of_ply["model"]["frame_match"]["nerfstudio"]["psnr"]
        > of_ply["model"]["frame_match"]["dataset"]["psnr"]
    )
    assert of_ply["targeted_views"] == of_run["targeted_views"]
    assert of_ply["flagged"] == of_run["flagged"] and of_ply["ground_truth"] == of_run["ground_truth"]


def test_scan_errors_are_one_line(tiny_run_pair, tiny_orbit_scene, tmp_path):
    from stealth_ns.cli import main
    from stealth_ns.method.model_cloud import cloud_of_model
    from stealth_ns.runs.loaded import load_run

    far = cloud_of_model(load_run(tiny_run_pair[1]).model)
    far.means += 1000.0
    write_gaussian_ply(tmp_path / "far.ply", far)
    far_on_scene = ["--model", str(tmp_path / "far.ply"), "--data", str(tiny_orbit_scene)]
    (tmp_path / "elsewhere").mkdir()
    cases = [
        (far_on_scene, "does not match the cameras"),
        (["--model", str(tmp_path / "far.ply")], "--data is needed with a PLY"),
        ([*far_on_scene, "--frame", "colmap"], "no such frame"),
        ([*far_on_scene, "--frame", "sideways"], "--frame must be auto or one of"),
        (["--model", str(tmp_path / "nothing")], "neither a PLY file nor a run"),
        (["--model", str(tiny_run_pair[0]), "--data", str(tmp_path / "elsewhere")], "was trained on"),
        (["--model", str(tiny_run_pair[0]), "--region-threshold", "0"], "--region-threshold must be in"),
        (["--model", str(tiny_run_pair[0]), "--group-share", "0"], "--group-share must be in (0, 1]"),
        (["--model", str(tiny_run_pair[0]), "--signals", "zscore"], "unknown signal 'zscore'"),
    ]
    for args, needle in cases:
        with pytest.raises(StealthNSError, match=re.escape(needle)) as info:
            main(["scan", *args, "--output", str(tmp_path / "o")])
        assert "\n" not in str(info.value)
    # never into the run folder nor the dataset (issue 32)
    run_dir = tiny_run_pair[0].parent
    for output, needle in (
        (run_dir / "scan", "inside the run folder"),
        (tiny_orbit_scene, "inside the dataset"),
    ):
        with pytest.raises(StealthNSError, match=re.escape(needle)):
            main(["scan", "--model", str(run_dir), "--data", str(tiny_orbit_scene), "--output", str(output)])
    assert not (run_dir / "scan").exists()
    # as the console script prints it
    proc = run_cli("stealth-ns", "scan", *far_on_scene, "--output", str(tmp_path / "o"), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("stealth-ns: error: ")


@pytest.mark.slow
def test_report_scores_a_ply_victim_of_a_poisoned_copy_as_its_run(tiny_run_pair, tiny_orbit_scene, tmp_path):
    """A victim trained on poison-dataset's copy, exported in the dataset's frame as another trainer
    writes it, gets the report numbers of the run itself."""
    from stealth_ns.datasets.frames import frame_transforms
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.method.model_cloud import cloud_of_model
    from stealth_ns.report.write import write_report
    from stealth_ns.runs.loaded import load_run

    copy = tmp_path / "copy"
    args = ["poison-dataset", "--data", str(tiny_orbit_scene), "--output", str(copy)]
    run_cli("stealth-ns", *args, in_process=False)  # the console script of poison-dataset, as a user runs it
    victim = train_tiny(copy, tmp_path / "runs", "victim", "--pipeline.attack.enabled", "False")
    run = load_run(victim)
    to_ns = frame_transforms(
        run.pipeline.datamanager.train_dataparser_outputs, inspect_folder("--data", str(copy))
    )
    cloud = cloud_of_model(run.model)
    cloud.extra.clear()  # another trainer's PLY has no poison tag
    write_gaussian_ply(tmp_path / "victim.ply", transform_cloud(cloud, np.linalg.inv(to_ns["dataset"])))
    clean = tiny_run_pair[1]
    of_run = write_report(victim, clean, tmp_path / "r1", stealth=False)
    of_ply = write_report(tmp_path / "victim.ply", clean, tmp_path / "r2", stealth=False, poisoned_data=copy)
    for key in ("v_illusory_psnr", "v_test_psnr", "v_test_drop"):
        assert of_ply[key] == pytest.approx(of_run[key], abs=0.01), key


def test_a_stock_splatfacto_run_is_read_from_its_checkpoint(tiny_run_pair, tmp_path):
    """A splatfacto run (CUDA-only to train, so made here from a stealth-ns run's checkpoint and a config
    whose method and model are stock splatfacto's) loads into a stealth-ns model and renders the same."""
    import shutil

    import yaml
    from nerfstudio.models.splatfacto import SplatfactoModelConfig

    from stealth_ns.method.safe_config import load_config
    from stealth_ns.runs.imported import load_model
    from stealth_ns.runs.loaded import render

    ours = tiny_run_pair[1]
    config = load_config(ours)
    config.method_name = "splatfacto"
    config.pipeline.model = SplatfactoModelConfig(sh_degree=config.pipeline.model.sh_degree)
    config.pipeline.datamanager.data = None  # a stock run's dataset is its dataparser's --data
    folder = tmp_path / "splatfacto-run"
    shutil.copytree(ours.parent / "nerfstudio_models", folder / "nerfstudio_models")
    (folder / "config.yml").write_text(yaml.dump(config))
    theirs = load_model(folder / "config.yml")
    assert theirs.kind == "splatfacto run (splatfacto)"
    assert theirs.run.checkpoint is not None  # the scan's cleaned run is written from it
    reference = load_model(ours)
    cameras = reference.run.pipeline.datamanager.train_dataset.cameras
    assert np.allclose(render(theirs.run, cameras, 2), render(reference.run, cameras, 2), atol=1e-5)


def test_the_verdict_counts_a_connected_region_in_front_of_an_opaque_scene():
    from stealth_ns.scan.config import ScanConfig
    from stealth_ns.scan.verdict import RenderedView, effect_mask, groups_by_view, largest_region

    rule = ScanConfig().effect_rule(0.4)  # a walk-through: the near line at 0.144 of the median depth
    assert ScanConfig().defend_config(0.4).proximity_threshold == pytest.approx(rule.near_ratio) == 0.144

    weights = np.array([[0.0, 5.0, 1.0], [2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 3.0]])
    flagged = np.array([True, True, True, False])
    groups = groups_by_view(flagged, weights)
    assert sorted(groups) == [0, 1] and groups[1].tolist() == [True, False, False, False]  # row 2 unseen
    assert groups_by_view(flagged, weights, min_size=2) == {}
    # poison seen nearly alike by two views (support views) belongs to both at share 0.5 (the 0.4
    # below it does not); an exact tie goes to the first view alone at share 1
    weights = np.array([[0.0, 5.0, 3.0], [4.0, 4.0, 0.0], [1.0, 0.0, 0.4], [0.0, 0.0, 0.0]])
    flagged = np.array([True, True, True, True])
    assert {v: g.tolist() for v, g in groups_by_view(flagged, weights).items()} == {
        0: [False, True, True, False],
        1: [True, False, False, False],
    }
    assert {v: g.tolist() for v, g in groups_by_view(flagged, weights, share=0.5).items()} == {
        0: [False, True, True, False],
        1: [True, True, False, False],
        2: [True, False, False, False],
    }
    assert sorted(groups_by_view(flagged, weights, min_size=2, share=0.5)) == [0, 1]

    h, w = 10, 12
    scene = RenderedView(np.full((h, w, 3), 0.2), np.ones((h, w)), np.full((h, w), 4.0))
    group_alpha = np.zeros((h, w))
    group_alpha[2:6, 3:7] = 1.0  # a 4x4 block...
    group_alpha[8, 10] = 1.0  # ...and a stray pixel
    full_rgb = scene.rgb.copy()
    full_rgb[group_alpha > 0] = 0.9
    full = RenderedView(full_rgb, np.ones((h, w)), scene.depth)
    near = RenderedView(full_rgb, group_alpha, np.full((h, w), 0.5))  # at 1/8 of the scene depth
    region = largest_region(effect_mask(full, scene, near, 4.0, rule))
    assert region.pixels == 16 and region.box == (3, 2, 6, 5) and region.share == pytest.approx(16 / 120)
    far = RenderedView(full_rgb, group_alpha, np.full((h, w), 3.0))  # at the scene's depth: an edge
    assert not effect_mask(full, scene, far, 4.0, rule).any()
    deeper = RenderedView(full_rgb, group_alpha, np.full((h, w), 1.8))  # 0.45 of the scene depth
    assert not effect_mask(full, scene, deeper, 4.0, rule).any()
    # a box beside a walk-through's path (0.2 of the scene depth) is not counted; where nothing comes
    # close to the cameras (near share 0.9) the line moves out to 0.729 of it
    beside = RenderedView(full_rgb, group_alpha, np.full((h, w), 0.8))
    assert not effect_mask(full, scene, beside, 4.0, rule).any()
    assert effect_mask(full, scene, deeper, 4.0, ScanConfig().effect_rule(0.9)).sum() == 17
    nothing_behind = RenderedView(scene.rgb, np.zeros((h, w)), scene.depth)
    assert not effect_mask(full, nothing_behind, near, 4.0, rule).any()
    same_colour = RenderedView(scene.rgb, np.ones((h, w)), scene.depth)
    assert not effect_mask(same_colour, scene, near, 4.0, rule).any()
    assert largest_region(np.zeros((3, 3), bool)).share == 0.0


def test_a_wide_region_of_a_few_large_gaussians_names_no_view():
    from stealth_ns.scan.config import ScanConfig
    from stealth_ns.scan.verdict import Region, is_detailed, is_targeted

    threshold, per = ScanConfig.region_threshold, ScanConfig.max_pixels_per_gaussian
    mask = np.zeros((100, 100), bool)
    mask[:40, :40] = True  # 1600 pixels, 16 % of the image
    region = Region(0.16, 1600, (0, 0, 39, 39), mask)
    assert is_targeted(region, 1600 // int(per), threshold, per)  # a picture: 64 pixels a Gaussian
    assert not is_targeted(region, 10, threshold, per)  # a floater: 160 pixels a Gaussian
    assert not is_targeted(Region(0.001, 10, (0, 0, 3, 2), mask), 1000, threshold, per)  # too small
    assert is_detailed(0, 0, per) and not is_detailed(65, 1, per)

    from pathlib import Path

    from stealth_ns.scan.command import summary_lines

    blob = {"name": "117.jpg", "gaussians": 10, "region_share": 0.013, "pixels_per_gaussian": 677.5}
    doc = {
        "verdict": "clean",
        "photos": {"used": True},
        "targeted_views": [],
        "groups": [blob],
        "config": {"region_threshold": threshold, "max_pixels_per_gaussian": per},
        "removed": 0,
        "seconds": {"total": 1.0},
    }
    said = summary_lines(doc, Path("out"))[1]
    assert "1.30% of 117.jpg" in said and "677.5 pixels each" in said and "a blob" in said


def test_bench_scan_counts_each_kind_of_model():
    from stealth_ns.bench.scan_table import confusion

    def row(poisoned, verdict, right, failed=False):
        return {"poisoned": poisoned, "verdict": verdict, "right": right, "attack_failed": failed}

    rows = [
        row(False, "clean", True),
        row(False, "suspicious", False),
        row(True, "suspicious", True),
        row(True, "suspicious", False),
        row(True, "clean", False),
        row(True, "clean", False, failed=True),
    ]
    assert confusion(rows) == {
        "clean_clean": 1, "clean_suspicious": 1, "found": 1, "wrong_view": 1, "missed": 1,
        "failed_found": 0, "failed_clean": 1,
    }  # fmt: skip
