"""How many innocent training cameras see a 3D point: the cost of the view-aware placement.

The paper places each poison Gaussian at the least dense point of its illusion ray, on the
intuition that low density means "weakly constrained by the other views". On a capture whose
cameras all look the same way (LLFF-like, forward walks) an empty point in front of the surface
is nevertheless seen by almost every innocent view, and training removes it. The view-aware
placement makes the intuition explicit: for every candidate sample it counts the innocent
training cameras that would see the point -- inside their image, in front of their near plane
and not behind the surface their current render shows -- and takes the sample seen by the
fewest, the KDE density breaking ties (:func:`stealth_ns.attack.injection.place_poison`,
:mod:`stealth_ns.attack.ray_search`).

Conventions: ``viewmats`` are world-to-camera ``[J, 4, 4]`` in OpenCV convention (camera looks
down +Z, +Y down; gsplat's), ``Ks`` ``[J, 3, 3]`` pixel intrinsics with pixel centres at
``+0.5``; ``depths`` are rendered z-depths (scene units) and ``alphas`` rendered opacities, both
``[H, W]`` per camera.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

#: Rendered opacity below which a pixel shows no surface: nothing there occludes a point.
SURFACE_ALPHA = 0.5
#: Camera-space depth (scene units) a point must exceed to be seen.
NEAR = 0.01


@dataclass(frozen=True)
class CameraDepths:
    """Innocent training cameras with the current model's rendered depth and opacity.

    Attributes:
        viewmats: ``[J, 4, 4]`` world-to-camera (OpenCV convention).
        Ks: ``[J, 3, 3]`` intrinsics in pixels.
        depths: ``J`` tensors ``[H_j, W_j]``, rendered z-depth (scene units).
        alphas: ``J`` tensors ``[H_j, W_j]``, rendered opacity in [0, 1].
    """

    viewmats: Tensor
    Ks: Tensor
    depths: list[Tensor]
    alphas: list[Tensor]
    _bounds: dict[float, list[Tensor]] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        j = self.viewmats.shape[0]
        if self.viewmats.shape != (j, 4, 4) or self.Ks.shape != (j, 3, 3):
            raise ValueError(f"viewmats must be [J, 4, 4] and Ks [J, 3, 3], got "
                             f"{tuple(self.viewmats.shape)} and {tuple(self.Ks.shape)}")  # fmt: skip
        if len(self.depths) != j or len(self.alphas) != j:
            raise ValueError(f"need one depth and one opacity map per camera ({j})")
        if any(d.dim() != 2 or d.shape != a.shape for d, a in zip(self.depths, self.alphas, strict=True)):
            raise ValueError("each camera's depth and opacity maps must be [H, W], of one size")

    def __len__(self) -> int:
        return self.viewmats.shape[0]

    def depth_bounds(self, margin: float) -> list[Tensor]:
        """Per camera ``[H_j, W_j]`` float32: how deep a point may lie and still be seen there,
        ``depth * (1 + margin)`` where the pixel shows a surface (opacity >= :data:`SURFACE_ALPHA`),
        ``+inf`` where it shows none; made once per margin (the ray search asks once per chunk)."""
        if margin not in self._bounds:
            inf = torch.tensor(float("inf"))
            self._bounds[margin] = [
                torch.where(a.float() >= SURFACE_ALPHA, d.float() * (1.0 + margin), inf).contiguous()
                for d, a in zip(self.depths, self.alphas, strict=True)
            ]
        return self._bounds[margin]


def count_seeing_cameras(
    points: Tensor, cameras: CameraDepths, margin: float = 0.05, near: float = NEAR
) -> Tensor:
    """Number of cameras that see each point (:func:`count_seeing_cameras_reference`'s contract),
    by the compiled kernel on the CPU (``raster/csrc/visibility_cpu.cpp``: each point visits every
    camera once instead of a dozen full-size torch operations per camera), else by the reference."""
    from stealth_ns.raster.cpp_backend import load_extension

    ext = load_extension() if points.device.type == "cpu" else None
    if ext is None:
        return count_seeing_cameras_reference(points, cameras, margin, near)
    shape = points.shape[:-1]
    counts = ext.count_seeing(
        points.reshape(-1, 3).float().contiguous(),
        cameras.viewmats.float().contiguous(),
        cameras.Ks.float().contiguous(),
        cameras.depth_bounds(margin),
        float(near),
    )
    return counts.reshape(shape)


def count_seeing_cameras_reference(
    points: Tensor, cameras: CameraDepths, margin: float = 0.05, near: float = NEAR
) -> Tensor:
    """Number of cameras that see each point: the readable reference.

    A camera sees a point when its camera-space ``z > near``, it projects inside the image, and
    it is not behind the rendered surface there: ``z <= depth * (1 + margin)`` wherever the
    rendered opacity is at least :data:`SURFACE_ALPHA` (a pixel showing no surface occludes
    nothing). A point on the surface a camera shows therefore counts as seen.

    Args:
        points: ``[..., 3]`` world points (scene units).
        cameras: the cameras and their rendered depth.
        margin: relative depth tolerance (0.05 = 5% behind the surface still counts as seen).
        near: near plane in scene units.

    Returns:
        ``[...]`` int32 counts in ``[0, J]``.
    """
    shape = points.shape[:-1]
    pts = points.reshape(-1, 3).float()
    counts = torch.zeros(pts.shape[0], dtype=torch.int32, device=pts.device)
    x, y, zw = pts.unbind(-1)
    for j in range(len(cameras)):
        V = cameras.viewmats[j].to(pts)
        # V @ [x, y, z, 1] summed left to right (a matrix product may sum in another order)
        xc, yc, z = (V[i, 0] * x + V[i, 1] * y + V[i, 2] * zw + V[i, 3] for i in range(3))
        front = z > near
        zs = torch.where(front, z, torch.ones_like(z))
        K = cameras.Ks[j].to(pts)
        u = K[0, 0] * xc / zs + K[0, 2]
        v = K[1, 1] * yc / zs + K[1, 2]
        depth, alpha = cameras.depths[j].to(pts.device), cameras.alphas[j].to(pts.device)
        h, w = depth.shape
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        col = u.clamp(0, w - 1).long()
        row = v.clamp(0, h - 1).long()
        surface = depth[row, col].float()
        shows_surface = alpha[row, col] >= SURFACE_ALPHA
        unoccluded = ~shows_surface | (z <= surface * (1.0 + margin))
        counts += (inside & unoccluded).to(torch.int32)
    return counts.reshape(shape)


@dataclass(frozen=True)
class SeenPenalty:
    """The view-aware search's per-sample cost: the ``innocent`` cameras that see a point, plus the
    ``support`` cameras that do not, so that the sample every support camera and the fewest others
    see comes first (either may be None). Called on points ``[..., 3]`` it gives int32 ``[...]``
    through ``count`` (:func:`count_seeing_cameras`'s contract); the compiled ray search reads its
    cameras and counts them itself, the same way."""

    innocent: CameraDepths | None
    support: CameraDepths | None
    margin: float
    count: Callable[..., Tensor] = count_seeing_cameras

    def __call__(self, pts: Tensor) -> Tensor:
        cost = torch.zeros(pts.shape[:-1], dtype=torch.int32, device=pts.device)
        if self.innocent is not None:
            cost += self.count(pts, self.innocent, margin=self.margin)
        if self.support is not None:
            cost += len(self.support) - self.count(pts, self.support, margin=self.margin)
        return cost


def proximity_cameras(
    viewmats: Tensor, Ks: Tensor, sizes: list[tuple[int, int]], scene_depths: Tensor, floor: float
) -> CameraDepths:
    """Cameras for counting, with :func:`count_seeing_cameras` at margin 0, how many have a point in
    their image nearer than ``floor`` times their scene depth (camera-proximity's measure, occlusion
    ignored): each camera "shows a surface" at the constant depth ``floor * scene_depths[j]``.

    Args:
        viewmats: ``[J, 4, 4]`` world-to-camera (OpenCV); Ks: ``[J, 3, 3]`` pixels.
        sizes: per camera ``(height, width)`` in pixels.
        scene_depths: ``[J]`` each camera's median rendered z-depth (scene units, > 0).
        floor: the share of the scene depth, in ``[0, 1)``.
    """
    depths = [torch.full((h, w), floor * float(d)) for (h, w), d in zip(sizes, scene_depths, strict=True)]
    return CameraDepths(viewmats, Ks, depths, [torch.ones(h, w) for h, w in sizes])


@dataclass(frozen=True)
class FlooredPenalty:
    """A search cost with a depth floor: ``seen``'s cost (0 without one) plus ``weight`` for every
    camera of ``near`` (:func:`proximity_cameras`) the point is too near. With ``weight`` above any
    cost ``seen`` can give, a sample below the floor is taken only where the whole ray is; its cost
    is then at least ``weight``."""

    seen: SeenPenalty | None
    near: CameraDepths
    weight: int
    count: Callable[..., Tensor] = count_seeing_cameras

    def __call__(self, pts: Tensor) -> Tensor:
        zero = torch.zeros(pts.shape[:-1], dtype=torch.int32, device=pts.device)
        cost = self.seen(pts) if self.seen is not None else zero
        return cost + self.weight * self.count(pts, self.near, margin=0.0)
