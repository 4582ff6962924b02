"""Camera poses between nerfstudio and the viewer's viser scene: camera jumps, view matching, frusta.

Conventions: nerfstudio camera-to-world matrices are ``[3, 4]`` (or ``[N, 3, 4]``) in OpenGL axes (camera
looks down ``-Z``, ``+Y`` up) in nerfstudio's rescaled scene units. viser cameras follow OpenCV axes (look
down ``+Z``, ``-Y`` up) and the viewer's viser scene is nerfstudio's scaled by
``VISER_NERFSTUDIO_SCALE_RATIO`` (10). Quaternions are ``wxyz``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import viser
import viser.transforms as vtf
from nerfstudio.cameras.cameras import Cameras

#: World scale between nerfstudio and the viewer's viser scene (``nerfstudio.viewer.viewer``'s constant).
VISER_SCALE = 10.0


@dataclass(frozen=True)
class ViewPose:
    """A dataset camera as the panel uses it.

    Attributes:
        c2w: ``[3, 4]`` float64 camera-to-world (OpenGL axes, scene units).
        fy: vertical focal length, pixels.
        width: image width, pixels.
        height: image height, pixels.
    """

    c2w: np.ndarray
    fy: float
    width: float
    height: float


def view_poses(cameras: Cameras) -> list[ViewPose]:
    """The :class:`ViewPose` of every camera of a dataset, in dataset order."""
    c2ws = cameras.camera_to_worlds.detach().cpu().double().numpy()
    return [
        ViewPose(c2ws[i, :3, :4], float(cameras.fy[i]), float(cameras.width[i]), float(cameras.height[i]))
        for i in range(len(cameras))
    ]


def viser_pose_from_c2w(c2w: np.ndarray, scale: float = VISER_SCALE) -> tuple[np.ndarray, np.ndarray]:
    """nerfstudio camera-to-world (OpenGL) -> viser camera orientation and position (OpenCV, scaled).

    Args:
        c2w: ``[3, 4]`` or ``[4, 4]`` camera-to-world, OpenGL axes, scene units.
        scale: viser units per scene unit.

    Returns:
        ``wxyz`` ``[4]`` (camera -> world rotation, OpenCV camera axes) and ``position`` ``[3]`` (viser).
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    rot = vtf.SO3.from_matrix(c2w[:3, :3]) @ vtf.SO3.from_x_radians(np.pi)
    return np.asarray(rot.wxyz), c2w[:3, 3] * scale


def c2w_from_viser_pose(
    wxyz: Sequence[float], position: Sequence[float], scale: float = VISER_SCALE
) -> np.ndarray:
    """Inverse of :func:`viser_pose_from_c2w`, exactly as nerfstudio's viewer builds its render camera.

    Args:
        wxyz: ``[4]`` viser camera orientation.
        position: ``[3]`` viser camera position (viser units).
        scale: viser units per scene unit.

    Returns:
        ``[3, 4]`` camera-to-world, OpenGL axes, scene units.
    """
    rot = (vtf.SO3(wxyz=np.asarray(wxyz, dtype=np.float64)) @ vtf.SO3.from_x_radians(np.pi)).as_matrix()
    return np.concatenate([rot, np.asarray(position, dtype=np.float64)[:, None] / scale], axis=1)


def vertical_fov(fy: float, height: float) -> float:
    """Vertical field of view in radians of a pinhole camera with focal ``fy`` and ``height`` (pixels)."""
    return 2.0 * math.atan(0.5 * float(height) / float(fy))


@dataclass(frozen=True)
class CameraJump:
    """Where to put a viser client camera to see exactly a dataset view.

    Attributes:
        wxyz: ``[4]`` orientation (OpenCV camera axes).
        position: ``[3]`` viser units.
        look_at: ``[3]`` orbit centre in viser units, on the optical axis.
        fov: vertical field of view, radians (the viewer renders with ``fy = (H / 2) / tan(fov / 2)`` and a
            centred principal point, so the jump reproduces the view's vertical extent).
    """

    wxyz: np.ndarray
    position: np.ndarray
    look_at: np.ndarray
    fov: float


def camera_jump(
    c2w: np.ndarray,
    fy: float,
    height: float,
    center: Sequence[float] = (0.0, 0.0, 0.0),
    scale: float = VISER_SCALE,
) -> CameraJump:
    """The viser camera state that shows a dataset view.

    Args:
        c2w: ``[3, 4]`` camera-to-world of the view (OpenGL axes, scene units).
        fy: its vertical focal length, pixels.
        height: its image height, pixels.
        center: ``[3]`` scene point (scene units) to orbit around afterwards; the look-at point is its
            projection on the optical axis (at least 0.1 scene units in front of the camera).
        scale: viser units per scene unit.

    Returns:
        The :class:`CameraJump`.
    """
    wxyz, position = viser_pose_from_c2w(c2w, scale)
    c2w = np.asarray(c2w, dtype=np.float64)
    forward = -c2w[:3, 2] / np.linalg.norm(c2w[:3, 2])
    depth = max(float((np.asarray(center, dtype=np.float64) - c2w[:3, 3]) @ forward), 0.1)
    return CameraJump(
        wxyz=wxyz, position=position, look_at=position + forward * depth * scale, fov=vertical_fov(fy, height)
    )


def apply_camera_jump(camera: viser.CameraHandle, jump: CameraJump) -> None:
    """Move a client's camera (viser's orbit camera keeps ``look_at`` and ``up_direction`` consistent)."""
    with camera.client.atomic():
        camera.fov = jump.fov
        camera.position = jump.position
        camera.wxyz = jump.wxyz  # also sets up_direction to the camera's up and a look-at on the axis
        camera.look_at = jump.look_at  # same direction, orbit distance to the scene centre


def match_view(
    c2w: np.ndarray, candidates: np.ndarray, pos_tol: float = 0.01, rot_tol_deg: float = 1.0
) -> int | None:
    """The candidate pose the camera sits on, if any.

    Args:
        c2w: ``[3, 4]`` query camera-to-world (scene units).
        candidates: ``[N, 3, 4]`` (or ``[N, 4, 4]``) camera-to-worlds.
        pos_tol: largest centre distance, scene units.
        rot_tol_deg: largest relative rotation angle, degrees.

    Returns:
        Index of the nearest candidate (by centre distance) within both tolerances, else None.
    """
    cands = np.asarray(candidates, dtype=np.float64).reshape(-1, *np.shape(candidates)[-2:])[:, :3, :4]
    if cands.shape[0] == 0:
        return None
    q = np.asarray(c2w, dtype=np.float64)[:3, :4]
    dist = np.linalg.norm(cands[:, :, 3] - q[:, 3], axis=1)
    trace = np.einsum("nij,ij->n", cands[:, :, :3], q[:, :3])  # trace(R_n^T R_q)
    angle = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
    ok = (dist <= pos_tol) & (angle <= rot_tol_deg)
    if not ok.any():
        return None
    return int(np.flatnonzero(ok)[np.argmin(dist[ok])])


@dataclass(frozen=True)
class FrustumSpec:
    """Arguments of ``viser``'s ``add_camera_frustum`` for a dataset camera (viser units)."""

    fov: float
    aspect: float
    wxyz: np.ndarray
    position: np.ndarray


def frustum_spec(
    c2w: np.ndarray, fy: float, width: float, height: float, scale: float = VISER_SCALE
) -> FrustumSpec:
    """Frustum of a pinhole camera: vertical fov (radians), aspect ``W / H`` and the viser pose."""
    wxyz, position = viser_pose_from_c2w(c2w, scale)
    return FrustumSpec(vertical_fov(fy, height), float(width) / float(height), wxyz, position)
