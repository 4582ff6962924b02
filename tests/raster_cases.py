"""Small rasterization scenes shared by the backend tests (reference vs torch vs compiled)."""

from __future__ import annotations

import math

import torch


def look_at_viewmat(eye, target=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """World-to-camera (OpenCV axes: x right, y down, z forward) looking from eye at target."""
    eye = torch.tensor(eye, dtype=torch.float32)
    fwd = torch.tensor(target, dtype=torch.float32) - eye
    fwd = fwd / fwd.norm()
    up = torch.tensor([0.0, 1.0, 0.0])
    right = torch.linalg.cross(fwd, up)
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    rot = torch.stack([right, down, fwd])  # rows: camera axes in world
    vm = torch.eye(4)
    vm[:3, :3] = rot
    vm[:3, 3] = -rot @ eye
    return vm


def intrinsics(width: int, height: int, fov_deg: float = 60.0) -> torch.Tensor:
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def random_gaussians(
    n: int,
    seed: int = 0,
    spread: float = 1.0,
    scale: tuple[float, float] = (0.03, 0.15),
    sh_degree: int | None = None,
):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * 2 * spread
    quats = torch.randn(n, 4, generator=g)
    scales = scale[0] + torch.rand(n, 3, generator=g) * (scale[1] - scale[0])
    opacities = 0.2 + 0.79 * torch.rand(n, generator=g)
    if sh_degree is None:
        colors = torch.rand(n, 3, generator=g)
    else:
        colors = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g) * 0.3
    return means, quats, scales, opacities, colors


def make_case(name: str) -> dict:
    """Keyword arguments for ``rasterization`` (and the brute-force reference)."""
    W, H, C = 40, 30, 1
    eyes = [(0.0, 0.3, -4.0)]
    n, kw = 40, {}
    if name == "basic":
        pass
    elif name == "two_cameras_sh3":
        C, eyes, kw = 2, [(0.0, 0.3, -4.0), (3.0, 0.5, -2.5)], {"sh_degree": 3}
    elif name == "non_square_odd":
        W, H = 53, 21  # not multiples of the 16 px tile
    elif name == "one":
        n = 1
    elif name == "zero":
        n = 0
    elif name == "anisotropic":
        kw = {"scale": (0.002, 0.6)}
    elif name == "dense_opaque":  # many overlapping opaque Gaussians: early termination matters
        n, kw = 120, {"scale": (0.2, 0.4), "spread": 0.5}
    else:
        raise KeyError(name)
    sh_degree = kw.pop("sh_degree", None)
    means, quats, scales, opacities, colors = random_gaussians(
        n, seed=hash(name) % 1000, sh_degree=sh_degree, **kw
    )
    if name == "dense_opaque":
        opacities = torch.full_like(opacities, 0.95)
        opacities[::3] = 0.9999  # above the 0.999 alpha clamp
    if name == "anisotropic":
        scales[:, 1:] = 0.003
    viewmats = torch.stack([look_at_viewmat(e) for e in eyes[:C]])
    Ks = intrinsics(W, H)[None].repeat(C, 1, 1)
    return dict(
        means=means,
        quats=quats,
        scales=scales,
        opacities=opacities,
        colors=colors,
        viewmats=viewmats,
        Ks=Ks,
        width=W,
        height=H,
        sh_degree=sh_degree,
    )


CASES = ["basic", "two_cameras_sh3", "non_square_odd", "one", "zero", "anisotropic", "dense_opaque"]


def behind_and_outside_case() -> dict:
    """Gaussians behind the camera, beyond the image border and straddling it."""
    case = make_case("basic")
    means = case["means"].clone()
    means[:5, 2] = -6.0  # behind the camera (camera at z=-4 looking at +z)
    means[5:10, 0] = 8.0  # far outside the image to the right
    means[10:13, 0] = 1.3  # straddling the border
    case["means"] = means
    return case
