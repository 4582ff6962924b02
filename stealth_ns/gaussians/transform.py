"""Gaussians moved between world frames by a similarity transform ``p' = s R p + t``.

A model from another trainer lives in the frame its trainer worked in (the dataset's own, for the
official 3DGS code on COLMAP or Blender data), not in nerfstudio's normalised one; moving it there
changes every per-Gaussian parameter that depends on the frame:

* centres: ``s R mu + t``; log-scales: ``+ log s``; rotations: ``q_R * q`` (Hamilton product, w x y z);
* view-dependent colour: a direction ``d`` becomes ``R d``, so the SH coefficients of each degree are
  rotated so that the colour seen along ``R d`` in the new frame is the colour seen along ``d`` before
  (:func:`sh_rotation`). Opacities and the degree-0 colour do not change.
"""

from __future__ import annotations

import numpy as np
import torch

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.ply import GaussianCloud
from stealth_ns.raster.projection import sh_basis


def similarity_parts(matrix: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R [3, 3], t [3])`` of a ``[4, 4]`` or ``[3, 4]`` similarity ``[s R | t]``. StealthNSError when
    the linear part is not a positive multiple of a rotation (a reflection or a shear)."""
    m = np.asarray(matrix, dtype=np.float64)[:3]
    linear = m[:, :3]
    det = float(np.linalg.det(linear))
    if not np.isfinite(det) or det <= 0:
        raise StealthNSError(f"the frame transform is not a rotation and a scale (determinant {det:g})")
    s = det ** (1.0 / 3.0)
    rotation = linear / s
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5):
        raise StealthNSError("the frame transform is not a rotation and a uniform scale (it shears)")
    return s, rotation, m[:, 3].copy()


def rotation_quaternion(rotation: np.ndarray) -> np.ndarray:
    """``[4]`` unit quaternion w x y z of a rotation matrix ``[3, 3]`` (Shepperd's method)."""
    r = np.asarray(rotation, dtype=np.float64)
    trace = np.trace(r)
    if trace > 0:
        w = np.sqrt(1.0 + trace) / 2
        q = [w, (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        root = np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = np.zeros(4)
        q[0] = (r[k, j] - r[j, k]) / (2 * root)
        q[1 + i] = root / 2
        q[1 + j] = (r[j, i] + r[i, j]) / (2 * root)
        q[1 + k] = (r[k, i] + r[i, k]) / (2 * root)
    q = np.asarray(q, dtype=np.float64)
    return q / np.linalg.norm(q)


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions w x y z (``a`` [4] or [N, 4], ``b`` [N, 4]) -> [N, 4]."""
    aw, ax, ay, az = np.moveaxis(np.broadcast_to(a, b.shape), -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


_SH_ROWS_PER_BLOCK = 1 << 16


def sh_rotation(rotation: np.ndarray, degree: int) -> np.ndarray:
    """``[K, K]`` (K = (degree + 1)^2) matrix ``M`` such that coefficients ``c`` seen along ``d`` give the
    same colour as ``M c`` seen along ``R d``: ``B(R d) M = B(d)`` for the real SH basis ``B`` of
    :func:`~stealth_ns.raster.projection.sh_basis` (gsplat's). Each degree's functions span a
    rotation-invariant space, so the least-squares solve over sample directions is exact."""
    r = np.asarray(rotation, dtype=np.float64)
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(8 * (degree + 1) ** 2 + 16, 3))
    rotated = dirs @ r.T
    b = sh_basis(degree, torch.from_numpy(dirs)).numpy()
    b_rot = sh_basis(degree, torch.from_numpy(rotated)).numpy()
    m, *_ = np.linalg.lstsq(b_rot, b, rcond=None)
    return m


def transform_cloud(cloud: GaussianCloud, matrix: np.ndarray) -> GaussianCloud:
    """``cloud`` in the frame reached by the similarity ``matrix`` (``[4, 4]`` or ``[3, 4]``, see
    :func:`similarity_parts`). Returns a new cloud (float32); ``extra`` is shared."""
    s, rotation, t = similarity_parts(matrix)
    f32 = np.float32
    means = (cloud.means.astype(np.float64) @ (s * rotation).T + t).astype(f32)
    quats = quaternion_product(rotation_quaternion(rotation), cloud.quats.astype(np.float64)).astype(f32)
    rest = cloud.sh_rest
    if rest.shape[1] and not np.allclose(rotation, np.eye(3), rtol=0, atol=1e-12):
        m_t = np.ascontiguousarray(sh_rotation(rotation, cloud.sh_degree)[1:, 1:].T)  # degree 0 apart
        out = np.empty_like(rest, dtype=f32)
        # [rows * 3, K] @ [K, K] a block of rows at a time: one matrix product each, small float64
        # copies transposed within each row (cache friendly: each row's coefficients stay together)
        for lo in range(0, len(rest), _SH_ROWS_PER_BLOCK):
            block = rest[lo : lo + _SH_ROWS_PER_BLOCK]
            n, k, c = block.shape
            flat = np.ascontiguousarray(block.transpose(0, 2, 1), dtype=np.float64).reshape(n * c, k)
            out[lo : lo + n] = (flat @ m_t).reshape(n, c, k).transpose(0, 2, 1)
        rest = out
    return GaussianCloud(
        means=means,
        log_scales=(cloud.log_scales.astype(np.float64) + np.log(s)).astype(f32),
        quats=quats,
        opacity_logits=cloud.opacity_logits.copy(),
        sh_dc=cloud.sh_dc.copy(),
        sh_rest=rest.copy(),
        extra=cloud.extra,
    )
