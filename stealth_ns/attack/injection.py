"""Density-guided injection of poison Gaussians (paper §3.3), on top of the pure functions.

``place_poison`` turns the current Gaussians plus the poisoned views into new Gaussians:
opacity-weighted voxel density -> KDE -> for every illusion pixel, the best point on its ray
up to the rendered depth and never within two near planes of the camera: the least dense one
from ``t_min`` on (``placement="kde"``, the paper), or (``placement="view-aware"``,
:mod:`stealth_ns.attack.visibility`) the one seen by the fewest innocent training cameras, the
density breaking ties; with ``t_min_fraction`` above ``unseen_t_min_fraction``, points no
innocent camera sees are searched from the nearer bound. Two stealth-aware variants
(docs/design/stealth.md): with support views (``support_views``) the view-aware search prefers the
samples the poisoned view's neighbours see; ``placement="surface"`` puts each poison Gaussian on
the surface its pixel shows. An adaptive variant (``depth_floor``) keeps every poison Gaussian at
least a share of each camera's scene depth away from the cameras that have it in view. The model
appends them (``StealthSplatModel.append_gaussians``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch
from torch import Tensor

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.density import DensityGrid, gaussian_kde_grid, voxel_density
from stealth_ns.attack.ray_search import RaySearchResult, min_density_points, pixel_rays, zdepth_to_ray_t
from stealth_ns.attack.record import Injection, PoisonView
from stealth_ns.attack.visibility import (
    SURFACE_ALPHA,
    CameraDepths,
    FlooredPenalty,
    SeenPenalty,
    count_seeing_cameras,
    proximity_cameras,
)
from stealth_ns.raster.cpp_backend import load_extension
from stealth_ns.raster.projection import viewmat_from_c2w

# Pixels whose rendered opacity is below SURFACE_ALPHA see no reconstructed surface (sky, empty
# background): their ray is searched up to where it leaves the density grid instead.


@dataclass
class PoisonPlacement:
    """New Gaussians (world units) and what was measured while placing them."""

    means: Tensor  # [M, 3]
    colors: Tensor  # [M, 3] RGB in [0, 1]
    scales: Tensor  # [M] std-dev in world units
    per_view: dict[str, int] = field(default_factory=dict)  # view name -> Gaussians placed
    invalid_rays: dict[str, int] = field(default_factory=dict)  # view name -> rays with t_max < t_min
    t_min: dict[str, float] = field(default_factory=dict)  # view name -> near bound used (scene units)
    # view-aware: view name -> near bound for poison no innocent camera sees (scene units)
    t_min_unseen: dict[str, float] = field(default_factory=dict)
    # view-aware: view name -> fraction of its poison Gaussians that no innocent camera sees
    unseen_fraction: dict[str, float] = field(default_factory=dict)
    # view name -> mean number of innocent cameras that see a placed poison Gaussian (view-aware)
    seen_by: dict[str, float] = field(default_factory=dict)
    # support views: view name -> mean number of its support views that see a placed poison Gaussian
    support_seen: dict[str, float] = field(default_factory=dict)
    # depth_floor > 0: view name -> illusion pixels left without poison, no sample of their ray being
    # at the floor from every camera that has it in view
    below_floor: dict[str, int] = field(default_factory=dict)
    grid: DensityGrid | None = None
    kde: DensityGrid | None = None
    timings: dict[str, float] = field(default_factory=dict)


def remove_outliers(points: np.ndarray, neighbours: int = 20, std_ratio: float = 2.0) -> np.ndarray:
    """[N] bool inliers by open3d's statistical outlier removal (the authors' setting)."""
    import open3d as o3d

    if len(points) <= neighbours:
        return np.ones(len(points), dtype=bool)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=neighbours, std_ratio=std_ratio)
    inliers = np.zeros(len(points), dtype=bool)
    inliers[np.asarray(kept, dtype=np.int64)] = True
    return inliers


def ray_exit_distance(origins: Tensor, directions: Tensor, lower: Tensor, upper: Tensor) -> Tensor:
    """[M] distance along each ray to where it leaves the box [lower, upper] (0 if it never is inside)."""
    inv = 1.0 / directions  # +-inf on axis-parallel rays; the slab max/min handles them
    t1 = torch.nan_to_num((lower - origins) * inv, nan=float("inf"))
    t2 = torch.nan_to_num((upper - origins) * inv, nan=float("inf"))
    return torch.maximum(t1, t2).amin(-1).clamp(min=0.0)


def build_density(
    means: np.ndarray, opacities: np.ndarray, cfg: AttackConfig
) -> tuple[DensityGrid, DensityGrid]:
    """Voxel density of the current Gaussians and its KDE (normalised to max 1)."""
    keep = remove_outliers(means) if cfg.outlier_removal else np.ones(len(means), dtype=bool)
    if cfg.voxel_size is not None:
        grid = voxel_density(means[keep], opacities[keep], voxel_size=cfg.voxel_size)
    else:
        grid = voxel_density(means[keep], opacities[keep], resolution=cfg.grid_resolution)
    return grid, gaussian_kde_grid(grid, cfg.bandwidth)


def _illusion_rays(
    view: PoisonView, depth: Tensor, alpha: Tensor, lower: Tensor, upper: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The rays of a view's illusion pixels and how far along each the search may go.

    Returns:
        ``rows``, ``cols`` [M] pixel indices; ``origins``, ``dirs`` [M, 3] (unit directions, scene units);
        ``cos`` [M] cosine to the optical axis (ray t = z / cos); ``t_max`` [M]: the rendered surface, or
        where the ray leaves the density grid [``lower``, ``upper``] on pixels that show none.
    """
    rows, cols = torch.nonzero(view.mask, as_tuple=True)
    pixels = torch.stack([cols, rows], dim=-1)
    rays = pixel_rays(view.c2w, view.fx, view.fy, view.cx, view.cy, pixels)
    origins = torch.as_tensor(rays.origins, dtype=torch.float32)
    dirs = torch.as_tensor(rays.directions, dtype=torch.float32)
    cos = torch.as_tensor(rays.cos_theta, dtype=torch.float32)
    t_surface = torch.as_tensor(zdepth_to_ray_t(depth[rows, cols].float(), cos))
    t_exit = ray_exit_distance(origins, dirs, lower, upper)
    t_max = torch.where(alpha[rows, cols] >= SURFACE_ALPHA, t_surface, t_exit)
    return rows, cols, origins, dirs, cos, t_max


#: Placements that count the innocent cameras seeing a point (and so need their rendered depth).
CAMERA_PLACEMENTS = ("view-aware", "surface")
#: ``surface``: how far in front of the rendered surface a poison Gaussian sits, as a fraction of
#: its depth (within ``visibility_margin``, so every camera that sees the surface sees it).
SURFACE_OFFSET = 0.01


class _TimedCounts:
    """:func:`count_seeing_cameras`, with the seconds spent in it summed (kept in the attack record's
    timings as ``visibility_s``: the counts the ray search's torch path asks for and those of the
    placement's figures; the compiled search counts inside its own pass)."""

    def __init__(self) -> None:
        self.seconds = 0.0

    def __call__(self, points: Tensor, cameras: CameraDepths, margin: float) -> Tensor:
        start = time.perf_counter()
        try:
            return count_seeing_cameras(points, cameras, margin=margin)
        finally:
            self.seconds += time.perf_counter() - start


def _seen_penalty(
    cfg: AttackConfig,
    innocent: CameraDepths | None,
    support: CameraDepths | None = None,
    count: Callable[..., Tensor] = count_seeing_cameras,
) -> SeenPenalty | None:
    """The ray search's per-sample cost (None: the KDE density alone, ``kde`` and ``surface``).

    ``view-aware``: the number of innocent cameras that see the sample, plus, with support views
    (``support_views``), the number of support cameras that do not (:class:`SeenPenalty`). ``count``
    counts them where the search calls the penalty (``count_seeing_cameras``'s contract)."""
    innocent = innocent if innocent is not None and len(innocent) else None
    support = support if support is not None and len(support) else None
    if cfg.placement != "view-aware" or (innocent is None and support is None):
        return None
    return SeenPenalty(innocent, support, cfg.visibility_margin, count)


def on_surface(origins: Tensor, dirs: Tensor, t_max: Tensor, t_min: Tensor) -> RaySearchResult:
    """``placement="surface"``: each ray's point just in front of its far bound ``t_max`` (the
    surface its pixel shows; ``[M]``, scene units), :data:`SURFACE_OFFSET` of the depth nearer,
    as a :class:`RaySearchResult` (density and penalty 0; invalid where below ``t_min``)."""
    t = t_max * (1.0 - SURFACE_OFFSET)
    valid = torch.isfinite(t) & (t >= t_min)
    nan = torch.full_like(t, float("nan"))
    t = torch.where(valid, t, nan)
    zero = torch.where(valid, torch.zeros_like(t), nan)
    return RaySearchResult(origins + t[:, None] * dirs, t, zero, valid, zero)


def _proximity(
    cfg: AttackConfig,
    views: list[PoisonView],
    depths: list[Tensor],
    alphas: list[Tensor],
    groups: Sequence[CameraDepths | None],
    centre: Tensor,
) -> CameraDepths | None:
    """``depth_floor``: every training camera that might have poison in view -- the poisoned views
    and the cameras of ``groups`` (innocent, support) -- as :func:`proximity_cameras` at the floor,
    each camera's scene depth its median rendered depth; None without a floor."""
    if cfg.depth_floor <= 0.0:
        return None
    viewmats, Ks, sizes, scene_depths = [], [], [], []
    for view, depth, alpha in zip(views, depths, alphas, strict=True):
        viewmats.append(viewmat_from_c2w(view.c2w[None].float()))
        Ks.append(torch.tensor([[[view.fx, 0.0, view.cx], [0.0, view.fy, view.cy], [0.0, 0.0, 1.0]]]))
        sizes.append(tuple(depth.shape))
        fallback = float(torch.linalg.norm(centre - view.c2w[:3, 3].float()))
        scene_depths.append(median_scene_depth(depth, alpha, fallback))
    for group in (g for g in groups if g is not None):
        viewmats.append(group.viewmats.float())
        Ks.append(group.Ks.float())
        for j, (depth, alpha) in enumerate(zip(group.depths, group.alphas, strict=True)):
            sizes.append(tuple(depth.shape))
            eye = -group.viewmats[j, :3, :3].float().T @ group.viewmats[j, :3, 3].float()
            scene_depths.append(median_scene_depth(depth, alpha, float(torch.linalg.norm(centre - eye))))
    return proximity_cameras(
        torch.cat(viewmats), torch.cat(Ks).float(), sizes, torch.tensor(scene_depths), cfg.depth_floor
    )


def _floored(
    cfg: AttackConfig,
    penalty: SeenPenalty | None,
    near: CameraDepths | None,
    *seeing: CameraDepths | None,
) -> Callable[[Tensor], Tensor] | None:
    """``penalty`` with the depth floor's cost (:class:`FlooredPenalty`) when there is one: a camera too
    near outweighs all the ``seeing`` cameras (innocent, support) that ``penalty`` counts."""
    if near is None or cfg.placement == "surface":
        return penalty
    count = penalty.count if penalty is not None else count_seeing_cameras
    return FlooredPenalty(penalty, near, 1 + sum(len(g) for g in seeing if g is not None), count)


def _seeing(
    points: Tensor, margin: float, count: Callable[..., Tensor], *groups: CameraDepths | None
) -> list[Tensor | None]:
    """Per camera group, how many of its cameras see each of ``points`` (None: no such cameras, or
    no points)."""
    return [
        count(points, g, margin=margin) if g is not None and len(g) and points.shape[0] else None
        for g in groups
    ]


def surface_depths(depth: Tensor, alpha: Tensor) -> Tensor:
    """``[M]``: the rendered z-depths (scene units) of the pixels that show a surface (opacity at least
    ``SURFACE_ALPHA``, a finite positive depth)."""
    return depth[(alpha >= SURFACE_ALPHA) & torch.isfinite(depth) & (depth > 0)]


def median_scene_depth(depth: Tensor, alpha: Tensor, fallback: float) -> float:
    """Median rendered z-depth (scene units) of the pixels that show a surface (``fallback``,
    e.g. the distance to the density grid's centre, when none does)."""
    surface = surface_depths(depth, alpha)
    return float(surface.median()) if surface.numel() else fallback


def place_poison(
    means: np.ndarray,
    opacities: np.ndarray,
    views: list[PoisonView],
    depths: list[Tensor],
    alphas: list[Tensor],
    cfg: AttackConfig,
    innocent: CameraDepths | None = None,
    near_plane: float = 0.0,
    supports: Sequence[CameraDepths] | None = None,
) -> PoisonPlacement:
    """Poison Gaussians for every illusion pixel of every poisoned view.

    Args:
        means: [N, 3] current Gaussian centres (scene units); opacities: [N] in [0, 1].
        views: the poisoned views.
        depths: per view, [H, W] rendered z-depth of the current model (scene units).
        alphas: per view, [H, W] rendered opacity (accumulation).
        cfg: the attack config (KDE, placement, t_min, samples, tie-break, poison scale).
        innocent: the innocent training cameras with their rendered depth; required by
            ``placement="view-aware"``.
        near_plane: the rasterizer's near plane (camera-space z, scene units); every poison
            Gaussian stays at least twice as far from the camera, where it is still drawn.
        supports: per poisoned view, its support views (``support_views``; not in ``innocent``)
            with their rendered depth: ``view-aware`` prefers the samples they all see.
    """
    if cfg.placement in CAMERA_PLACEMENTS and innocent is None:
        raise ValueError(f"{cfg.placement} placement needs the innocent cameras' rendered depth")
    count = _TimedCounts()
    t0 = time.perf_counter()
    grid, kde = build_density(means, opacities, cfg)
    timings = {"density_kde_s": time.perf_counter() - t0}
    lower = torch.as_tensor(grid.origin, dtype=torch.float32)
    upper = torch.as_tensor(grid.upper, dtype=torch.float32)
    out_means, out_colors, out_scales = [], [], []
    out = PoisonPlacement(
        torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(0), grid=grid, kde=kde, timings=timings
    )
    centre = torch.as_tensor((grid.origin + grid.upper) / 2, dtype=torch.float32)
    t1 = time.perf_counter()
    load_extension()  # the search's and the counts' kernels: loaded by the renders on the CPU, not on CUDA
    timings["cpu_kernels_load_s"] = time.perf_counter() - t1
    near_cameras = _proximity(cfg, views, depths, alphas, [innocent, *(supports or [])], centre)
    for i, (view, depth, alpha) in enumerate(zip(views, depths, alphas, strict=True)):
        support = supports[i] if supports else None
        penalty = _floored(cfg, _seen_penalty(cfg, innocent, support, count), near_cameras, innocent, support)
        rows, cols, origins, dirs, cos, t_max = _illusion_rays(view, depth, alpha, lower, upper)
        scene_depth = median_scene_depth(
            depth, alpha, fallback=float(torch.linalg.norm(centre - view.c2w[:3, 3]))
        )
        t_min = float(cfg.t_min) if cfg.t_min is not None else cfg.t_min_fraction * scene_depth
        search = partial(
            min_density_points,
            kde,
            origins,
            dirs,
            t_max=t_max,
            n_samples=cfg.samples_per_ray,
            tie_break=cfg.tie_break,
            penalty=penalty,
        )
        # per ray: never nearer than 2 near planes in camera z (t = z / cos_theta): still drawn
        drawn = 2.0 * near_plane / cos
        if cfg.placement == "surface":
            found = on_surface(origins, dirs, t_max, torch.clamp(drawn, min=t_min))
        else:
            found = search(torch.clamp(drawn, min=t_min))
        if cfg.placement == "view-aware" and penalty is not None:
            t_unseen = min(t_min, cfg.unseen_t_min_fraction * scene_depth)
            out.t_min_unseen[view.name] = t_unseen
            if t_unseen < t_min:  # equal bounds (the defaults): the first search already prefers unseen
                unseen = search(torch.clamp(drawn, min=t_unseen))
                use = torch.as_tensor(unseen.valid) & (torch.as_tensor(unseen.penalty) == 0)
                found = found.where(use, unseen)
        valid = torch.as_tensor(found.valid)
        out.invalid_rays[view.name], out.t_min[view.name] = int((~valid).sum()), t_min
        if near_cameras is not None:  # the floor is a hard bound: rays whose best sample breaks it get none
            below = valid & (count(torch.as_tensor(found.points).float(), near_cameras, margin=0.0) > 0)
            out.below_floor[view.name], valid = int(below.sum()), valid & ~below
        pts = torch.as_tensor(found.points)[valid]
        zdepth = torch.as_tensor(found.t)[valid] * cos[valid]
        out_means.append(pts)
        out_colors.append(view.target[rows[valid], cols[valid]].float())
        out_scales.append(cfg.poison_scale * zdepth / math.sqrt(view.fx * view.fy))
        out.per_view[view.name] = int(valid.sum())
        seeing = _seeing(pts, cfg.visibility_margin, count, innocent, support)
        if seeing[0] is not None:
            out.seen_by[view.name] = float(seeing[0].float().mean())
            out.unseen_fraction[view.name] = float((seeing[0] == 0).float().mean())
        if seeing[1] is not None:
            out.support_seen[view.name] = float(seeing[1].float().mean())
    timings.update(ray_search_s=time.perf_counter() - t1, visibility_s=count.seconds)
    if out_means:
        out.means, out.colors, out.scales = torch.cat(out_means), torch.cat(out_colors), torch.cat(out_scales)
    return out


def injection_entry(
    placement: PoisonPlacement, step: int, n_before: int, support_views: dict[str, list[str]] | None = None
) -> Injection:
    """The record's entry for ``placement`` injected at ``step`` into a model of ``n_before`` Gaussians
    (``support_views``: each poisoned view's support views, by name)."""
    assert placement.grid is not None
    return Injection(
        injected_at_step=step,
        n_gaussians_before=n_before,
        n_poison_gaussians=int(placement.means.shape[0]),
        poison_per_view=placement.per_view,
        invalid_rays_per_view=placement.invalid_rays,
        t_min_per_view=placement.t_min,
        t_min_unseen_per_view=placement.t_min_unseen,
        innocent_views_seeing_poison=placement.seen_by,
        poison_unseen_fraction=placement.unseen_fraction,
        support_views=support_views or {},
        support_views_seeing_poison=placement.support_seen,
        rays_below_depth_floor_per_view=placement.below_floor,
        density_grid={
            "shape": list(placement.grid.shape),
            "voxel_size": placement.grid.voxel_size,
            "origin": [float(x) for x in placement.grid.origin],
        },
        timings_s=placement.timings,
    )
