"""Triangulation of SIFT matches with known, fixed camera poses (pycolmap):
:mod:`stealth_ns.datasets.seed_points`.

The images are staged in a scratch folder, SIFT features extracted, every pair matched with two-view
verification, and the points triangulated and bundle-adjusted with the poses and intrinsics held
fixed; single-threaded, so the same seed gives the same points. Cameras in COLMAP's models and
OpenCV world-to-camera convention (see :mod:`stealth_ns.datasets.seed_points`).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import image_info, read_image, save_png, split_alpha

PYCOLMAP_HINT = "pip install 'pycolmap>=4.0,<5'"
MIN_INLIERS = 15
"""Verified matches an image pair needs to take part in triangulation (COLMAP's default)."""
LINKABLE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
"""Image files COLMAP reads as they are, when 8-bit grey or RGB; others are staged as RGB PNG copies."""


@dataclass(frozen=True)
class Camera:
    """A COLMAP camera: model name, size in pixels and COLMAP's parameter list."""

    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class Frame:
    """One view: its ``file_path`` as written in the transforms file, the image, pose, camera."""

    file_path: str
    image: Path
    c2w: np.ndarray = field(compare=False)
    camera: Camera


@dataclass(frozen=True)
class Points:
    """Triangulated points: ``xyz`` [P, 3] in the poses' frame, ``rgb`` [P, 3] uint8, reprojection
    ``error`` [P] in pixels and ``track`` [P] (number of images that see each point)."""

    xyz: np.ndarray
    rgb: np.ndarray
    error: np.ndarray
    track: np.ndarray


def _import_pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise StealthNSError(f"seed-points needs pycolmap: {PYCOLMAP_HINT}") from None
    if not hasattr(pycolmap, "match_image_pairs") or not hasattr(pycolmap.Reconstruction, "add_rig"):
        raise StealthNSError(f"pycolmap {pycolmap.__version__} is too old: {PYCOLMAP_HINT}")
    return pycolmap


def _stage_images(frames: list[Frame], folder: Path) -> list[str]:
    """Put the images in ``folder`` as ``00000.png``, ...: links to 8-bit grey / RGB PNG, JPEG, BMP
    and TIFF files, RGB PNG copies (transparency composited on white) of anything else."""
    folder.mkdir()
    names = []
    for k, fr in enumerate(frames):
        info = image_info(fr.image)
        suffix = fr.image.suffix.lower()
        if suffix in LINKABLE_SUFFIXES and info.dtype == np.uint8 and info.channels in (1, 3):
            name = f"{k:05d}{suffix}"
            try:
                os.symlink(fr.image.resolve(), folder / name)
            except OSError:
                shutil.copyfile(fr.image, folder / name)
        else:
            name = f"{k:05d}.png"
            rgb, alpha = split_alpha(read_image(fr.image))
            if alpha is not None:
                rgb = rgb * alpha[..., None] + (1.0 - alpha[..., None])
            save_png(folder / name, rgb)
        names.append(name)
    return names


def _chunks(items: list, n_chunks: int) -> list[list]:
    size = max(1, math.ceil(len(items) / max(1, n_chunks)))
    return [items[i : i + size] for i in range(0, len(items), size)]


def triangulate(frames: list[Frame], seed: int) -> tuple[Points, dict[str, int]]:
    """SIFT + exhaustive matching + triangulation with fixed poses, single-threaded (deterministic)."""
    from tqdm import tqdm

    if len(frames) < 2:
        raise StealthNSError(f"need at least 2 images to triangulate (got {len(frames)})")
    pycolmap = _import_pycolmap()
    old_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2  # errors only: no glog chatter
    try:
        with tempfile.TemporaryDirectory(prefix="stealth-ns-seed-") as tmp:
            return _run_colmap(pycolmap, tqdm, frames, Path(tmp), seed)
    finally:
        pycolmap.logging.minloglevel = old_level


def _run_colmap(pycolmap, tqdm, frames: list[Frame], work: Path, seed: int) -> tuple[Points, dict[str, int]]:
    """Stage the images in the scratch folder ``work``, then SIFT features, matching of every pair
    and triangulation with the known poses; returns the points and the match statistics."""
    t = time.perf_counter()
    images = work / "images"
    names = _stage_images(frames, images)
    by_name = dict(zip(names, frames, strict=True))
    db_path = work / "database.db"
    pycolmap.set_random_seed(seed)
    db_images, n_kp = _extract_features(pycolmap, tqdm, db_path, images, by_name)
    print(f"features: {n_kp} SIFT features in {len(names)} images ({time.perf_counter() - t:.1f} s)")
    cameras, stats = _match_all_pairs(pycolmap, tqdm, db_path, work, db_images, by_name, seed)
    points = _triangulate_known_poses(pycolmap, db_path, work, db_images, cameras, by_name, seed)
    return points, {"keypoints": n_kp, **stats}


def _extract_features(pycolmap, tqdm, db_path: Path, images: Path, by_name: dict[str, Frame]):
    """SIFT features of the staged images (file name -> frame), one camera per image while
    extracting, then each image's known intrinsics; returns the database's images (by id) and the
    number of keypoints."""
    names = list(by_name)
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = 1
    with tqdm(total=len(names), desc="features", unit="img", leave=False) as bar:
        for chunk in _chunks(names, 20):
            pycolmap.extract_features(
                db_path,
                images,
                image_names=chunk,
                camera_mode=pycolmap.CameraMode.PER_IMAGE,
                extraction_options=ext,
                device=pycolmap.Device.cpu,
            )
            bar.update(len(chunk))
    with pycolmap.Database.open(db_path) as db:
        db_images = sorted(db.read_all_images(), key=lambda im: im.image_id)
        for im in db_images:
            c = by_name[im.name].camera
            db.update_camera(
                pycolmap.Camera(
                    camera_id=im.camera_id,
                    model=c.model,
                    width=c.width,
                    height=c.height,
                    params=list(c.params),
                    has_prior_focal_length=True,
                )
            )
        n_kp = int(db.num_keypoints())
    return db_images, n_kp


def _match_all_pairs(pycolmap, tqdm, db_path: Path, work: Path, db_images: list, by_name: dict, seed: int):
    """Match every image pair (in chunks, for the progress bar) with two-view verification, RANSAC
    seeded; returns the database's cameras (by id) and ``{"pairs", "inliers"}`` of the pairs with at
    least :data:`MIN_INLIERS` verified matches, with ``pose_error_px``, how far those matches lie from
    the epipolar lines of the given poses (:func:`epipolar_distances`)."""
    t = time.perf_counter()
    match = pycolmap.FeatureMatchingOptions()
    match.num_threads = 1
    verify = pycolmap.TwoViewGeometryOptions()
    verify.ransac.random_seed = seed
    pairs = [(a.name, b.name) for i, a in enumerate(db_images) for b in db_images[i + 1 :]]
    pair_file = work / "pairs.txt"
    with tqdm(total=len(pairs), desc="matching", unit="pair", leave=False) as bar:
        for chunk in _chunks(pairs, 20):
            pair_file.write_text("".join(f"{a} {b}\n" for a, b in chunk), encoding="utf-8")
            pairing = pycolmap.ImportedPairingOptions()
            pairing.match_list_path = pair_file
            pycolmap.match_image_pairs(
                db_path,
                matching_options=match,
                pairing_options=pairing,
                verification_options=verify,
                device=pycolmap.Device.cpu,
            )
            bar.update(len(chunk))
    with pycolmap.Database.open(db_path) as db:
        geoms = db.read_two_view_geometries()[1]
        cameras = sorted(db.read_all_cameras(), key=lambda c: c.camera_id)
        pair_ids = db.read_two_view_geometries()[0]
        keypoints = {im.image_id: np.asarray(db.read_keypoints(im.image_id))[:, :2] for im in db_images}
    good = [len(g.inlier_matches) for g in geoms if len(g.inlier_matches) >= MIN_INLIERS]
    stats: dict[str, float] = {"pairs": len(good), "inliers": int(sum(good))}
    stats["pose_error_px"] = _pose_error(pycolmap, pair_ids, geoms, keypoints, db_images, cameras, by_name)
    print(
        f"matching: {len(pairs)} pairs, {stats['pairs']} with >= {MIN_INLIERS} verified matches, "
        f"{stats['inliers']} matches, median distance to the given poses' epipolar lines "
        f"{stats['pose_error_px']:.2f} px ({time.perf_counter() - t:.1f} s)"
    )
    return cameras, stats


def _pose_error(pycolmap, pair_ids, geoms, keypoints, db_images, cameras, by_name) -> float:
    """Median distance (px) of the verified matches of the good pairs to the epipolar lines the given
    poses and intrinsics draw (nan without any): well under a pixel when the poses fit the images."""
    intrinsics = {c.camera_id: c.calibration_matrix() for c in cameras}
    image = {im.image_id: im for im in db_images}
    errors = []
    for pair_id, geom in zip(pair_ids, geoms, strict=True):
        if len(geom.inlier_matches) < MIN_INLIERS:
            continue
        a, b = (image[i] for i in pycolmap.pair_id_to_image_pair(pair_id))
        m = np.asarray(geom.inlier_matches)
        errors.append(
            epipolar_distances(
                keypoints[a.image_id][m[:, 0]], keypoints[b.image_id][m[:, 1]],
                intrinsics[a.camera_id], intrinsics[b.camera_id], by_name[a.name].c2w, by_name[b.name].c2w,
            )
        )  # fmt: skip
    return float(np.median(np.concatenate(errors))) if errors else float("nan")


def epipolar_distances(
    x1: np.ndarray, x2: np.ndarray, k1: np.ndarray, k2: np.ndarray, c2w1: np.ndarray, c2w2: np.ndarray
) -> np.ndarray:
    """Symmetric distance (px) of matches ``x1`` <-> ``x2`` ([M, 2] pixels) to each other's epipolar
    lines under intrinsics ``k1``, ``k2`` [3, 3] and OpenGL camera-to-world poses ``c2w1``, ``c2w2``
    [4, 4] (lens distortion ignored) -> [M]."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c1, w2c2 = np.linalg.inv(c2w1 @ flip), np.linalg.inv(c2w2 @ flip)
    rel = w2c2 @ np.linalg.inv(w2c1)
    r, t = rel[:3, :3], rel[:3, 3]
    cross = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    f = np.linalg.inv(k2).T @ cross @ r @ np.linalg.inv(k1)
    h1, h2 = np.c_[x1, np.ones(len(x1))], np.c_[x2, np.ones(len(x2))]
    line2, line1 = h1 @ f.T, h2 @ f  # lines in image 2 and image 1
    d2 = np.abs(np.sum(line2 * h2, axis=1)) / np.maximum(np.hypot(line2[:, 0], line2[:, 1]), 1e-12)
    d1 = np.abs(np.sum(line1 * h1, axis=1)) / np.maximum(np.hypot(line1[:, 0], line1[:, 1]), 1e-12)
    return (d1 + d2) / 2


def _triangulate_known_poses(
    pycolmap, db_path: Path, work: Path, db_images: list, cameras: list, by_name: dict[str, Frame], seed: int
) -> Points:
    """Triangulate the verified matches with every image at its known pose (OpenGL camera-to-world
    turned into OpenCV world-to-camera), bundle-adjusting the points only."""
    t = time.perf_counter()
    rec = pycolmap.Reconstruction()
    for cam in cameras:
        rec.add_camera_with_trivial_rig(cam)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    for im in db_images:
        w2c = np.linalg.inv(by_name[im.name].c2w @ flip)
        image = pycolmap.Image(name=im.name, camera_id=im.camera_id, image_id=im.image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c[:3, :4]))
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = 1
    opts.random_seed = seed
    opts.min_num_matches = MIN_INLIERS
    opts.triangulation.ignore_two_view_tracks = False
    (work / "sparse").mkdir()
    pycolmap.set_random_seed(seed)
    out = pycolmap.triangulate_points(rec, db_path, work / "images", work / "sparse", options=opts)
    ids = sorted(out.points3D)
    pts = [out.points3D[i] for i in ids]
    points = Points(
        xyz=np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3),
        rgb=np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3),
        error=np.array([p.error for p in pts], dtype=np.float64),
        track=np.array([p.track.length() for p in pts], dtype=np.int64),
    )
    mean = float(points.error.mean()) if len(pts) else float("nan")
    print(
        f"triangulation: {len(pts)} points, mean reprojection error {mean:.2f} px "
        f"({time.perf_counter() - t:.1f} s)"
    )
    return points
