"""The frames OpenSplat (``--center``) and gsplat's ``simple_trainer`` (``normalize_world_space``, its
default) train in, recomputed from the dataset (stealth_ns/datasets/trainer_frames.py): points moved
as each trainer's code moves them land back on nerfstudio's, and a model written in either frame is
found by ``--frame auto``.

The trainers' steps are written out again here, after their sources (pierotofy/OpenSplat 4800f5a:
nerfstudio.cpp ``inputDataFromNerfStudio``, tensor_math ``autoScaleAndCenterPoses``, model.cpp
``savePly``; nerfstudio-project/gsplat examples/datasets/colmap.py ``Parser`` 0714fc6, normalize.py
11909fc), not with the functions under test.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from stealth_ns.raster.projection import viewmat_from_c2w

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
TRAINER_FRAMES = ("opensplat-center", "gsplat-normalized")


# ------------------------------------------------------------------ the trainers' steps, written again
def opensplat_centred(poses_gl: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points`` as OpenSplat ``--center`` moves them (libtorch, float32): ``center = mean(origins)``,
    ``f = 1 / max(|origins - center|)``, ``(points - center) * f``."""
    poses = torch.tensor(poses_gl, dtype=torch.float32)
    origins = poses[..., :3, 3].clone()
    center = torch.mean(origins, 0)
    origins -= center
    f = np.float32(1.0) / np.float32(torch.max(torch.abs(origins)).item())
    return ((torch.tensor(points, dtype=torch.float32) - center) * float(f)).double().numpy()


def gsplat_parser(c2w_cv: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cameras ``[N, 4, 4]``, points ``[M, 3]``, ``transform`` ``[4, 4]``) as gsplat's COLMAP
    ``Parser(normalize=True)`` leaves them: camera similarity T1, principal axes of the points T2, the
    upside-down half turn T3; ``transform = T3 T2 T1``."""

    def move_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
        return p @ m[:3, :3].T + m[:3, 3]

    def move_cameras(m: np.ndarray, c2w: np.ndarray) -> np.ndarray:
        c2w = np.einsum("nij, ki -> nkj", c2w, m)
        c2w[:, :3, :3] /= np.linalg.norm(c2w[:, 0, :3], axis=1)[:, None, None]
        return c2w

    # T1: the mean camera up (-y) turned onto -y (Rodrigues), the median of each optical axis's point
    # nearest the origin to the origin, the cameras' median distance to 1
    up = np.mean(-c2w_cv[:, :3, 1], axis=0)
    up /= np.linalg.norm(up)
    target = np.array([0.0, -1.0, 0.0])
    v, c = np.cross(up, target), float(up @ target)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    turn = np.eye(3) + k + k @ k / (1 + c)
    t = c2w_cv[:, :3, 3] @ turn.T
    forward = c2w_cv[:, :3, 2] @ turn.T
    nearest = t - np.sum(forward * t, axis=1, keepdims=True) * forward
    shift = -np.median(nearest, axis=0)
    t1 = np.eye(4)
    t1[:3, :3], t1[:3, 3] = turn, shift
    t1[:3] /= np.median(np.linalg.norm(t + shift, axis=1))
    cameras, points = move_cameras(t1, c2w_cv.copy()), move_points(t1, points)
    # T2: the points' median to the origin, their principal axes (largest variance first) onto x, y, z
    median = np.median(points, axis=0)
    values, vectors = np.linalg.eigh(np.cov((points - median).T))
    vectors = vectors[:, np.argsort(values)[::-1]]
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] = -vectors[:, 0]
    t2 = np.eye(4)
    t2[:3, :3], t2[:3, 3] = vectors.T, -vectors.T @ median
    cameras, points = move_cameras(t2, cameras), move_points(t2, points)
    transform = t2 @ t1
    # T3: more points below than above (a floor), else a half turn about x
    if np.median(points[:, 2]) > np.mean(points[:, 2]):
        t3 = np.diag([1.0, -1.0, -1.0, 1.0])
        cameras, points = move_cameras(t3, cameras), move_points(t3, points)
        transform = t3 @ transform
    return cameras, points, transform


# ------------------------------------------------------------------ the tiny orbit scene, nerfstudio's frame
@pytest.fixture(scope="module")
def orbit(tiny_orbit_scene):
    """(transforms.json, seed points [M, 3] float32, frame transforms, the host run's cameras and the
    transforms.json frame of each) of the tiny orbit scene."""
    from stealth_ns.datasets.frames import frame_transforms
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.method.datamanager import dataset_image_names
    from stealth_ns.runs.imported import host_config, host_run
    from stealth_ns.scene_generator.writer import read_ply

    scene = inspect_folder("--data", str(tiny_orbit_scene))
    run = host_run(host_config(scene), tiny_orbit_scene / "x.ply")
    dm = run.pipeline.datamanager
    meta = json.loads((tiny_orbit_scene / "transforms.json").read_text())
    names = dataset_image_names(tiny_orbit_scene, dm.train_dataparser_outputs.image_filenames)
    index = [next(i for i, f in enumerate(meta["frames"]) if f["file_path"].lstrip("./") == n) for n in names]
    points = read_ply(tiny_orbit_scene / meta["ply_file_path"])[0]
    to_ns = frame_transforms(dm.train_dataparser_outputs, scene)
    return meta, points, to_ns, dm.train_dataset.cameras, index


def _move(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.asarray(p, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]


def _pixel(cameras, i: int, p_ns: np.ndarray) -> np.ndarray:
    view = viewmat_from_c2w(cameras.camera_to_worlds[i : i + 1].float())[0].double().numpy()
    k = cameras.get_intrinsics_matrices()[i].double().numpy()
    p = view[:3, :3] @ p_ns + view[:3, 3]
    return (k @ (p / p[2]))[:2]


def _poses(meta: dict) -> np.ndarray:
    return np.asarray([f["transform_matrix"] for f in meta["frames"]], dtype=np.float64)


def _on_axis(meta: dict, frame: int) -> np.ndarray:
    """The point 2 units along the optical axis of transforms.json's frame ``frame`` (dataset frame)."""
    c2w = _poses(meta)[frame]  # OpenGL: the camera looks down -z
    return c2w[:3, 3] - 2.0 * c2w[:3, 2]


def test_opensplat_center_points_land_on_nerfstudios(orbit):
    """The seed points and a point on a camera's optical axis, moved as OpenSplat --center moves them,
    map back onto nerfstudio's frame (to 1e-6) and the axis point onto that camera's principal point."""
    meta, points, to_ns, cameras, index = orbit
    p = np.vstack([points, _on_axis(meta, index[3])])
    centred = opensplat_centred(_poses(meta), p)
    assert np.abs(centred[:, :3]).max() < 10  # in OpenSplat's unit box, not the dataset's frame
    assert np.allclose(
        _move(to_ns["opensplat-center"], centred), _move(to_ns["dataset"], p), atol=1e-6, rtol=0
    )
    uv = _pixel(cameras, 3, _move(to_ns["opensplat-center"], centred[-1]))
    assert np.allclose(uv, [meta["cx"], meta["cy"]], atol=1e-3)


def test_gsplat_normalized_points_and_cameras_land_on_nerfstudios(orbit):
    """The seed points, a point on a camera's optical axis and the cameras, moved as gsplat's Parser
    moves them, map back onto nerfstudio's frame (points to 1e-6; cameras to nerfstudio's float32)."""
    meta, points, to_ns, cameras, index = orbit
    moved_cameras, moved, transform = gsplat_parser(_poses(meta) @ GL_TO_CV, points)
    m = to_ns["gsplat-normalized"]
    assert np.allclose(_move(m, moved), _move(to_ns["dataset"], points), atol=1e-6, rtol=0)
    axis = _move(transform, _on_axis(meta, index[3]))  # any other point: by the parser's transform
    assert np.allclose(_pixel(cameras, 3, _move(m, axis)), [meta["cx"], meta["cy"]], atol=1e-3)
    ns_c2w = cameras.camera_to_worlds.double().numpy()
    s = np.cbrt(np.linalg.det(m[:3, :3]))
    assert np.allclose(_move(m, moved_cameras[index, :3, 3]), ns_c2w[:, :3, 3], atol=1e-5)
    assert np.allclose(
        m[:3, :3] / s @ moved_cameras[index, :3, :3] @ GL_TO_CV[:3, :3], ns_c2w[:, :3, :3], atol=1e-5
    )


def test_the_trainer_similarities_on_three_cameras():
    """Hand-computed. OpenSplat centres cameras at (0,0,0), (2,0,0), (1,4,0) on their mean (1, 4/3, 0)
    and scales by 1 / (8/3) (the largest centred coordinate). gsplat, for three cameras looking along +x
    with z up, at (0,0,1), (1,2,3), (5,4,2): turns z onto -y (a quarter turn about x: t = (x, -z, y)),
    moves the median (0, -2, 2) of the points of the optical axes nearest the origin ((0,-1,0),
    (0,-3,2), (0,-2,4)) to it, and scales by one over the median distance to it then (sqrt 5)."""
    from stealth_ns.datasets.trainer_frames import gsplat_similarity_from_cameras, opensplat_center

    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = [[0, 0, 0], [2, 0, 0], [1, 4, 0]]
    expected = np.eye(4)
    expected[:3, :3] *= 3 / 8
    expected[:3, 3] = -3 / 8 * np.array([1, 4 / 3, 0])
    assert np.allclose(opensplat_center(c2w), expected, atol=1e-7)

    right, down, forward = [0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]  # OpenCV axes
    c2w[:, :3, :3] = np.array([right, down, forward]).T
    c2w[:, :3, 3] = [[0, 0, 1], [1, 2, 3], [5, 4, 2]]
    turn = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    expected[:3, :3] = turn / np.sqrt(5)
    expected[:3, 3] = np.array([0.0, 2.0, -2.0]) / np.sqrt(5)
    assert np.allclose(gsplat_similarity_from_cameras(c2w), expected, atol=1e-12)


def _write_points(path: Path, xyz: np.ndarray) -> None:
    from stealth_ns.scene_generator.writer import write_ply

    write_ply(path, xyz, np.full((len(xyz), 3), 0.5))


def test_colmap_and_converted_datasets_give_the_same_trainer_frames(tiny_orbit_scene, tmp_path):
    """The frames come from the dataset's files: the scene as a COLMAP model (read with pycolmap) gives
    the transforms.json's; converted by an ns-process-data-like ``applied_transform`` A, OpenSplat's is
    computed in the converted frame (its transforms.json) and gsplat's in the COLMAP model's."""
    pycolmap = pytest.importorskip("pycolmap")
    from stealth_ns.datasets.frames import trainer_frame_transforms
    from stealth_ns.datasets.source import SceneSource, inspect_folder
    from stealth_ns.datasets.trainer_frames import dataset_views
    from stealth_ns.scene_generator.writer import read_ply

    meta = json.loads((tiny_orbit_scene / "transforms.json").read_text())
    points = read_ply(tiny_orbit_scene / meta["ply_file_path"])[0]
    c2w = _poses(meta) @ GL_TO_CV
    rec = pycolmap.Reconstruction()
    params = [meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]]
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(camera_id=1, model="PINHOLE", width=meta["w"], height=meta["h"], params=params)
    )
    for image_id, cam in enumerate(c2w, start=1):
        image = pycolmap.Image(name=f"{image_id}.png", camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.linalg.inv(cam)[:3, :4]))
    for p in points.astype(np.float64):
        rec.add_point3D(p, pycolmap.Track(), np.array([128, 128, 128], dtype=np.uint8))
    (tmp_path / "colmap" / "sparse" / "0").mkdir(parents=True)
    rec.write_binary(str(tmp_path / "colmap" / "sparse" / "0"))
    colmap = SceneSource("c", tmp_path / "colmap", "c", "colmap", "colmap", "sparse/0")
    views = dataset_views(colmap)
    order = np.argsort(views.c2w[:, 0, 3])  # pycolmap's order of the images is its own
    assert np.allclose(views.c2w[order], c2w[np.argsort(c2w[:, 0, 3])], atol=1e-7)
    assert np.array_equal(np.sort(views.points, axis=0), np.sort(points, axis=0))
    identity = {"dataset": np.eye(4)}
    ours = trainer_frame_transforms(inspect_folder("--data", str(tiny_orbit_scene)), identity, None)
    assert set(ours) == set(TRAINER_FRAMES)
    for name, m in trainer_frame_transforms(colmap, identity, None).items():
        assert np.allclose(m, ours[name], atol=1e-5), name  # COLMAP stores rotations as quaternions

    a = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])  # ns-process-data's
    converted = tmp_path / "converted"
    converted.mkdir()
    frames = [
        {**f, "transform_matrix": (a @ np.asarray(f["transform_matrix"])).tolist()} for f in meta["frames"]
    ]
    (converted / "transforms.json").write_text(
        json.dumps({**meta, "frames": frames, "applied_transform": a[:3].tolist()})
    )
    converted_points = _move(a, points).astype(np.float32)  # a signed permutation: exact
    _write_points(converted / meta["ply_file_path"], converted_points)
    d, c = np.diag([2.0, 2.0, 2.0, 1.0]), np.diag([3.0, 3.0, 3.0, 1.0])  # stand-ins for the real ones
    theirs = trainer_frame_transforms(
        inspect_folder("--data", str(converted)), {"dataset": d, "colmap": c}, a
    )
    opensplat = fitted(lambda p: opensplat_centred(a @ _poses(meta), p), converted_points)
    assert np.allclose(theirs["opensplat-center"], d @ np.linalg.inv(opensplat), atol=1e-5)
    gsplat = gsplat_parser(c2w, points)[2]
    assert np.allclose(theirs["gsplat-normalized"], c @ np.linalg.inv(gsplat), atol=1e-9)


def fitted(move, points: np.ndarray) -> np.ndarray:
    """The ``[4, 4]`` affine map taking ``points`` ``[M, 3]`` where ``move`` puts them (least squares)."""
    solution = np.linalg.lstsq(np.hstack([points, np.ones((len(points), 1))]), move(points), rcond=None)[0]
    out = np.eye(4)
    out[:3] = solution.T
    return out


# ------------------------------------------------------------------ a model in a trainer's frame
@pytest.mark.parametrize("frame", TRAINER_FRAMES)
def test_a_model_in_a_trainer_frame_is_found_by_auto(frame, tiny_run_pair, tiny_orbit_scene, tmp_path):
    """The tiny clean run's Gaussians written in the trainer's frame (no poison tag, as the trainer
    writes them) are found in that frame by --frame auto, and render as the run does."""
    from stealth_ns.datasets.frames import frame_transforms
    from stealth_ns.datasets.source import inspect_folder
    from stealth_ns.gaussians.ply import write_gaussian_ply
    from stealth_ns.gaussians.transform import transform_cloud
    from stealth_ns.method.model_cloud import cloud_of_model
    from stealth_ns.runs.imported import load_model
    from stealth_ns.runs.loaded import load_run, render

    run = load_run(tiny_run_pair[1])
    to_ns = frame_transforms(
        run.pipeline.datamanager.train_dataparser_outputs, inspect_folder("--data", str(tiny_orbit_scene))
    )
    cloud = cloud_of_model(run.model)
    cloud.extra.clear()
    write_gaussian_ply(tmp_path / "theirs.ply", transform_cloud(cloud, np.linalg.inv(to_ns[frame])))
    imported = load_model(tmp_path / "theirs.ply", tiny_orbit_scene)
    assert imported.frame == frame
    assert set(imported.frame_match) == {"nerfstudio", "dataset", *TRAINER_FRAMES}
    others = [m["psnr"] for name, m in imported.frame_match.items() if name != frame]
    assert imported.frame_match[frame]["psnr"] > max(others) + 1.0
    cameras = run.pipeline.datamanager.train_dataset.cameras
    assert np.allclose(render(imported.run, cameras, 2), render(run, cameras, 2), atol=1e-3)


def test_a_model_in_no_known_frame_is_refused_naming_every_frame(tiny_orbit_scene, tmp_path):
    """Far from every camera in every frame tried, a model is refused in one line naming each frame
    with its render match and share of Gaussians in view, and the flat image's PSNR."""
    import re

    from stealth_ns.foundation.errors import StealthNSError
    from stealth_ns.gaussians.ply import GaussianCloud, write_gaussian_ply
    from stealth_ns.runs.imported import load_model

    rng = np.random.default_rng(0)
    n = 50
    means = rng.normal(size=(n, 3)).astype(np.float32) + 1000.0
    quats = np.tile(np.float32([1, 0, 0, 0]), (n, 1))
    colours = rng.normal(size=(n, 3)).astype(np.float32)
    scales, opacities, rest = np.full((n, 3), -3.0, np.float32), np.zeros(n, np.float32), np.zeros((n, 0, 3))
    cloud = GaussianCloud(means, scales, quats, opacities, colours, rest.astype(np.float32), {})
    write_gaussian_ply(tmp_path / "far.ply", cloud)
    with pytest.raises(StealthNSError, match="does not match the cameras") as info:
        load_model(tmp_path / "far.ply", tiny_orbit_scene)
    message = str(info.value)
    assert "\n" not in message
    for frame in ("nerfstudio", "dataset", *TRAINER_FRAMES):
        assert re.search(rf"{frame} \(render match \d+\.\d dB, 0% of the Gaussians in view\)", message), frame
    assert re.search(r"a flat image of each photo's mean colour scores \d+\.\d dB", message)
