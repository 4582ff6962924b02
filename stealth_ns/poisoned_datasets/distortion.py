"""Changes made in nerfstudio's undistorted training images, mapped back onto the dataset's pixels.

nerfstudio's full-image datamanager undistorts the images of cameras with lens distortion before
training (``_undistort_image``: OpenCV's ``getOptimalNewCameraMatrix`` with alpha 0, ``undistort``,
then a crop to the valid region, e.g. the fox capture's 135x240 images train at 134x239). The
attacks compute their images in that training frame; a poisoned dataset must hold them in the
dataset's own (distorted) frame. :func:`change_in_source_frame` maps a change ``poisoned - clean``
back: for every source pixel, where nerfstudio's undistortion puts it, sampled bilinearly (0 for
pixels the crop drops). The source image plus that change is what the file gets, so pixels the
attack did not change stay byte-identical and an L-infinity bound of the change still holds.
"""

from __future__ import annotations

import numpy as np

from stealth_ns.foundation.errors import StealthNSError


def opencv_distortion(params: np.ndarray) -> np.ndarray:
    """nerfstudio's distortion parameters ``(k1, k2, k3, k4, p1, p2)`` in OpenCV's order
    ``(k1, k2, p1, p2, k3, k4, 0, 0)``, as nerfstudio's undistortion reorders them."""
    k1, k2, k3, k4, p1, p2 = (float(v) for v in params[:6])
    return np.array([k1, k2, p1, p2, k3, k4, 0.0, 0.0])


def change_in_source_frame(
    change: np.ndarray, K: np.ndarray, distortion: np.ndarray, width: int, height: int
) -> np.ndarray:
    """A change made in nerfstudio's undistorted, cropped training image, on the source image's pixels.

    Args:
        change: ``[h, w, C]`` float, the training frame (``h, w`` after nerfstudio's crop).
        K: ``[3, 3]`` the dataset's intrinsics (pixels, nerfstudio's convention: centre at +0.5).
        distortion: nerfstudio's ``[6]`` perspective distortion parameters ``(k1, k2, k3, k4, p1, p2)``.
        width, height: the source image's size in pixels.

    Returns:
        ``[height, width, C]`` float32: the change at every source pixel (0 where the crop dropped it).
    """
    import cv2

    dist = opencv_distortion(distortion)
    K0 = np.asarray(K, dtype=np.float64).copy()
    K0[0, 2] -= 0.5  # OpenCV's pixel coordinates start at the top-left corner (as nerfstudio shifts)
    K0[1, 2] -= 0.5
    new_K, (x, y, w, h) = cv2.getOptimalNewCameraMatrix(K0, dist, (width, height), 0)
    if (h, w) != change.shape[:2]:
        raise StealthNSError(
            f"the training image is {change.shape[1]}x{change.shape[0]} but undistorting the "
            f"{width}x{height} source gives {w}x{h}: cannot map the change back"
        )
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    points = np.stack([u.ravel(), v.ravel()], axis=-1)[:, None, :]
    undistorted = cv2.undistortPoints(points, K0, dist, P=new_K).reshape(height, width, 2)
    map_x = (undistorted[..., 0] - x).astype(np.float32)
    map_y = (undistorted[..., 1] - y).astype(np.float32)
    out = cv2.remap(
        np.ascontiguousarray(change, dtype=np.float32),
        map_x,
        map_y,
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    return out.reshape(height, width, -1)


def camera_distortion(cameras, index: int) -> tuple[np.ndarray, np.ndarray, int, int] | None:
    """``(K, distortion, width, height)`` of a dataparser's camera with lens distortion, None without.

    ``cameras`` must be the dataparser's (nerfstudio's datamanager overwrites its datasets' copies
    with the undistorted intrinsics). Fisheye cameras are refused: their undistortion is not mapped
    back here."""
    from nerfstudio.cameras.cameras import CameraType

    camera = cameras[index]
    params = camera.distortion_params
    if params is None or not bool(params.abs().gt(0).any()):
        return None
    if int(camera.camera_type.item()) != CameraType.PERSPECTIVE.value:
        raise StealthNSError(
            "poisoned copies of datasets with fisheye distortion are not supported: nerfstudio trains on "
            "undistorted images and only perspective (OPENCV) distortion is mapped back to the files"
        )
    K = camera.get_intrinsics_matrices().numpy()
    return K, params.numpy(), int(camera.width.item()), int(camera.height.item())
