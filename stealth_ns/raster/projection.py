"""Gaussian projection and view-dependent colour: the O(N) part of 3DGS rasterization.

Pure PyTorch and differentiable; shared by every CPU backend. The math is gsplat 1.4.0's
(``gsplat/cuda/_torch_impl.py``): EWA splatting of a 3D covariance through the pinhole
Jacobian (with gsplat's clamping of the Jacobian to 1.3x the field of view), a 0.3 px²
screen-space low-pass on the 2D covariance, and a 3-sigma pixel radius.

Conventions: world-to-camera ``viewmats`` in OpenCV axes (x right, y down, z forward),
intrinsics ``Ks`` in pixels, pixel centres at integer + 0.5.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

# SH coefficients: one ``[N, K, 3]`` tensor, or nerfstudio's split storage ``(dc [N, 3], rest [N, K - 1, 3])``
# (the compiled CPU kernels read the pair as it is, sparing a join forward and a split backward every step).
SHCoefficients = Tensor | tuple[Tensor, Tensor]


def join_sh(coeffs: SHCoefficients) -> Tensor:
    """``[N, K, 3]`` (or ``[..., K, 3]``) coefficients from either form of :data:`SHCoefficients`."""
    if isinstance(coeffs, Tensor):
        return coeffs
    sh_dc, sh_rest = coeffs
    return torch.cat((sh_dc[..., None, :], sh_rest), dim=-2)


def viewmat_from_c2w(camera_to_worlds: Tensor) -> Tensor:
    """[C, 3, 4] OpenGL camera-to-world -> [C, 4, 4] OpenCV world-to-camera (gsplat's convention)."""
    rot = camera_to_worlds[:, :3, :3] * torch.tensor([1.0, -1.0, -1.0], device=camera_to_worlds.device)
    trans = camera_to_worlds[:, :3, 3:4]
    rot_inv = rot.transpose(1, 2)
    viewmat = torch.zeros(rot.shape[0], 4, 4, device=rot.device, dtype=rot.dtype)
    viewmat[:, 3, 3] = 1.0
    viewmat[:, :3, :3] = rot_inv
    viewmat[:, :3, 3:4] = -rot_inv @ trans
    return viewmat


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices of (w, x, y, z) quaternions, normalised first.

    Args:
        quats: [..., 4].

    Returns:
        [..., 3, 3].
    """
    w, x, y, z = F.normalize(quats, p=2, dim=-1).unbind(-1)
    rot = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return rot.reshape(quats.shape[:-1] + (3, 3))


def quat_scale_to_covar(quats: Tensor, scales: Tensor) -> Tensor:
    """3D covariances ``R S S^T R^T``.

    Args:
        quats: [N, 4] rotations (w, x, y, z), any norm.
        scales: [N, 3] standard deviations along the local axes (scene units, not log).

    Returns:
        [N, 3, 3] covariances (scene units²).
    """
    m = quat_to_rotmat(quats) * scales[..., None, :]
    return m @ m.transpose(-1, -2)


def project_gaussians(
    means: Tensor,
    covars: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    eps2d: float = 0.3,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """EWA projection of 3D Gaussians into C pinhole cameras.

    Args:
        means: [N, 3] centres in world units.
        covars: [N, 3, 3] world-space covariances.
        viewmats: [C, 4, 4] world-to-camera (OpenCV axes).
        Ks: [C, 3, 3] intrinsics in pixels.
        width, height: image size in pixels.
        eps2d: low-pass added to the 2D covariance diagonal (px²).
        near_plane, far_plane: camera-space depth range that is rendered.
        radius_clip: Gaussians whose radius is at most this (px) are skipped.

    Returns:
        radii: [C, N] int32 3-sigma radius in pixels; 0 marks a Gaussian that is not rendered
            (behind the near plane, beyond the far plane, degenerate or off screen).
        means2d: [C, N, 2] projected centres in pixels.
        depths: [C, N] camera-space z.
        conics: [C, N, 3] upper triangle (a, b, c) of the inverse 2D covariance.
    """
    rot = viewmats[:, :3, :3]
    trans = viewmats[:, :3, 3]
    means_c = torch.einsum("cij,nj->cni", rot, means) + trans[:, None, :]
    covars_c = torch.einsum("cij,njk,clk->cnil", rot, covars, rot)

    tx, ty, tz = means_c.unbind(-1)
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    # The Jacobian is evaluated at a point clamped to 1.3x the field of view, so that
    # Gaussians far off screen do not get huge, unstable footprints (gsplat / 3DGS).
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    txc = tz * torch.clamp(tx / tz, min=-lim_x_neg, max=lim_x_pos)
    tyc = tz * torch.clamp(ty / tz, min=-lim_y_neg, max=lim_y_pos)
    zero = torch.zeros_like(tz)
    jac = torch.stack([fx / tz, zero, -fx * txc / tz**2, zero, fy / tz, -fy * tyc / tz**2], dim=-1).reshape(
        tz.shape + (2, 3)
    )
    cov2d = jac @ covars_c @ jac.transpose(-1, -2)
    means2d = torch.stack([fx * tx / tz + cx, fy * ty / tz + cy], dim=-1)

    a = cov2d[..., 0, 0] + eps2d
    b = 0.5 * (cov2d[..., 0, 1] + cov2d[..., 1, 0])
    c = cov2d[..., 1, 1] + eps2d
    det = (a * c - b * b).clamp(min=1e-10)
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)

    with torch.no_grad():
        half_trace = 0.5 * (a + c)
        lam_max = half_trace + torch.sqrt(torch.clamp(half_trace**2 - det, min=0.01))
        radius = torch.ceil(3.0 * torch.sqrt(lam_max))
        valid = (det > 0) & (tz > near_plane) & (tz < far_plane) & (radius > radius_clip)
        inside = (
            (means2d[..., 0] + radius > 0)
            & (means2d[..., 0] - radius < width)
            & (means2d[..., 1] + radius > 0)
            & (means2d[..., 1] - radius < height)
        )
        radii = torch.where(valid & inside, radius, torch.zeros_like(radius)).int()
    return radii, means2d, tz, conics


# Real spherical-harmonics constants (degree 0..3), as in gsplat and the 3DGS reference.
_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Real SH basis functions evaluated at unit directions.

    Args:
        degree: 0..3.
        dirs: [..., 3] directions (normalised here).

    Returns:
        [..., (degree + 1)²].
    """
    if not 0 <= degree <= 3:
        raise ValueError(f"sh degree must be in 0..3, got {degree}")
    x, y, z = F.normalize(dirs, p=2, dim=-1).unbind(-1)
    out = [torch.full_like(x, _C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [
            _C2[0] * xy,
            _C2[1] * yz,
            _C2[2] * (2.0 * zz - xx - yy),
            _C2[3] * xz,
            _C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            _C3[0] * y * (3 * xx - yy),
            _C3[1] * xy * z,
            _C3[2] * y * (4 * zz - xx - yy),
            _C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            _C3[4] * x * (4 * zz - xx - yy),
            _C3[5] * z * (xx - yy),
            _C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)


def spherical_harmonics(degree: int, dirs: Tensor, coeffs: Tensor) -> Tensor:
    """Evaluate SH colour (without the +0.5 offset 3DGS adds afterwards).

    Args:
        degree: active degree, 0..3; only the first (degree + 1)² coefficients are used.
        dirs: [..., 3] viewing directions (camera to Gaussian), any length.
        coeffs: [..., K, 3] SH coefficients, K >= (degree + 1)².

    Returns:
        [..., 3].
    """
    k = (degree + 1) ** 2
    if coeffs.shape[-2] < k:
        raise ValueError(f"sh degree {degree} needs {k} coefficients, got {coeffs.shape[-2]}")
    basis = sh_basis(degree, dirs)
    return (basis[..., None] * coeffs[..., :k, :]).sum(dim=-2)
