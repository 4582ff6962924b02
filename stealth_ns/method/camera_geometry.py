"""The training cameras as camera-proximity reads them, with the depth of what each one shows.

Used by the defence (:func:`stealth_ns.defences.scores.frustum_depth_ratios`) and by the white-box
adaptive attack that trains against it (:mod:`stealth_ns.attack.proximity_term`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from stealth_ns.attack.injection import median_scene_depth
from stealth_ns.method.model import StealthSplatModel
from stealth_ns.raster.projection import viewmat_from_c2w


@dataclass(frozen=True)
class CameraGeometry:
    """The training cameras as :func:`stealth_ns.defences.scores.frustum_depth_ratios` reads them."""

    viewmats: np.ndarray
    """``[V, 4, 4]`` world-to-camera (OpenCV)."""
    Ks: np.ndarray
    """``[V, 3, 3]`` intrinsics (pixels)."""
    sizes: np.ndarray
    """``[V, 2]`` image width and height (pixels)."""
    scene_depths: np.ndarray
    """``[V]`` median rendered z-depth of the pixels that show a surface (scene units)."""


def camera_matrices(cameras: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(viewmats [V, 4, 4] world-to-camera OpenCV, Ks [V, 3, 3], sizes [V, 2] width and height)``
    of a nerfstudio ``Cameras``, float64 numpy, as :func:`stealth_ns.defences.scores.frustum_depth_ratios`
    reads them."""
    return (
        viewmat_from_c2w(cameras.camera_to_worlds.float()).double().cpu().numpy(),
        cameras.get_intrinsics_matrices().double().cpu().numpy(),
        torch.stack([cameras.width[:, 0], cameras.height[:, 0]], dim=1).double().cpu().numpy(),
    )


def geometry_of(cameras: object, depths: np.ndarray) -> CameraGeometry:
    """The cameras of ``cameras`` (V views) with ``depths`` ``[V]`` as their scene depths; a NaN depth
    (a view that shows no surface) takes the median of the other views' (1.0 scene unit when none
    shows one)."""
    depths = np.array(depths, dtype=np.float64)
    known = depths[np.isfinite(depths)]
    depths[~np.isfinite(depths)] = float(np.median(known)) if known.size else 1.0
    viewmats, ks, sizes = camera_matrices(cameras)
    return CameraGeometry(viewmats=viewmats, Ks=ks, sizes=sizes, scene_depths=depths)


@torch.no_grad()
def camera_geometry(model: StealthSplatModel, cameras: object, desc: str = "scene depth") -> CameraGeometry:
    """The cameras of ``cameras`` (V views) with each one's median rendered depth
    (:func:`geometry_of`)."""
    depths = np.full(len(cameras), np.nan)
    with tqdm(total=len(cameras), desc=desc, unit="view", leave=False, disable=None) as bar:
        for v in range(len(cameras)):
            out = model.render_view(cameras[v : v + 1])
            depths[v] = median_scene_depth(out["depth"][..., 0], out["accumulation"][..., 0], np.nan)
            bar.update(1)
    return geometry_of(cameras, depths)
