"""Render a :class:`~stealth_ns.scene_generator.presets.ScenePlan` view: supersampled colour, z-depth and
per-pixel surface samples (for seed points).

Pinhole camera, OpenGL convention: pixel (u, v) (column, row) with sub-pixel offset (a, b) in
[0, 1) looks along the camera-space direction ((u + a - cx) / fl_x, -(v + b - cy) / fl_y, -1);
the pixel centre is a = b = 0.5. Shading is view-independent: albedo * (AMBIENT + DIFFUSE *
max(0, n . LIGHT_DIR)); rays that hit nothing see the sky (black without one), or are transparent
in the RGBA output (:attr:`RenderedView.alpha`, :attr:`RenderedView.foreground`) of the
Blender-format presets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stealth_ns.scene_generator.geometry import cast_rays
from stealth_ns.scene_generator.presets import HFOV_DEG, ScenePlan
from stealth_ns.scene_generator.textures import sky_colour

LIGHT_DIR = np.array([0.45, 0.8, 0.35]) / np.linalg.norm([0.45, 0.8, 0.35])
"""Unit direction towards the sun (world)."""
AMBIENT = 0.35
DIFFUSE = 0.65


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; ``cx = width / 2``, ``cy = height / 2``, square pixels."""

    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float = HFOV_DEG) -> Intrinsics:
        """Intrinsics with horizontal field of view ``hfov_deg`` degrees."""
        f = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2)
        return cls(width, height, float(f), float(f), width / 2.0, height / 2.0)

    def camera_dirs(self, offsets: list[tuple[float, float]]) -> np.ndarray:
        """Unnormalised camera-space directions (S, H, W, 3) with z = -1 for sub-pixel ``offsets``
        (S pairs (a, b) in [0, 1), e.g. (0.5, 0.5) for pixel centres)."""
        u = np.arange(self.width, dtype=np.float64)
        v = np.arange(self.height, dtype=np.float64)
        out = np.empty((len(offsets), self.height, self.width, 3))
        for s, (a, b) in enumerate(offsets):
            out[s, :, :, 0] = ((u + a - self.cx) / self.fl_x)[None, :]
            out[s, :, :, 1] = (-(v + b - self.cy) / self.fl_y)[:, None]
            out[s, :, :, 2] = -1.0
        return out


def supersample_offsets(n: int) -> list[tuple[float, float]]:
    """Regular n x n grid of sub-pixel offsets, e.g. n = 2 gives 0.25 and 0.75."""
    g = (np.arange(n) + 0.5) / n
    return [(float(a), float(b)) for b in g for a in g]


def to_world(c2w: np.ndarray, cam_dirs: np.ndarray) -> np.ndarray:
    """Rotate camera-space vectors (..., 3) to world space with c2w (4, 4) (no BLAS)."""
    r = c2w[:3, :3]
    return cam_dirs[..., 0:1] * r[:, 0] + cam_dirs[..., 1:2] * r[:, 1] + cam_dirs[..., 2:3] * r[:, 2]


def shade_rays(
    plan: ScenePlan, origin: np.ndarray, dirs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour of rays from ``origin`` (3,) along unit ``dirs`` (N, 3).

    Returns: colour (N, 3) in [0, 1], hit distance t (N,) (``inf`` for sky), hit points (N, 3).
    """
    hits = cast_rays(plan.geometry, origin, dirs)
    colour = sky_colour(dirs, plan.sky) if plan.sky is not None else np.zeros_like(dirs)
    hit = hits.prim >= 0
    if np.any(hit):
        idx = np.nonzero(hit)[0]
        prim = hits.prim[idx]
        order = np.argsort(prim, kind="stable")
        idx, prim = idx[order], prim[order]
        bounds = np.flatnonzero(np.diff(prim)) + 1
        lambert = AMBIENT + DIFFUSE * np.clip((hits.normal[idx] * LIGHT_DIR).sum(axis=1), 0.0, None)
        for group in np.split(np.arange(len(idx)), bounds):
            rows = idx[group]
            albedo = plan.materials[int(prim[group[0]])].albedo(hits.points[rows], hits.normal[rows])
            colour[rows] = albedo * lambert[group, None]
    return np.clip(colour, 0.0, 1.0), hits.t, hits.points


@dataclass
class RenderedView:
    """One rendered view.

    ``image`` (H, W, 3) float in [0, 1] (supersampled); ``depth`` (H, W) float32 z-depth along the
    camera's -Z axis in world units for the pixel-centre ray (0 where the ray sees sky);
    ``centre_colour`` (H, W, 3) shaded colour of the pixel-centre hit; ``centre_points`` (H, W, 3)
    world position of the pixel-centre hit (undefined where depth is 0); ``alpha`` (H, W) fraction
    of the supersampled rays that hit a surface (0 = background only, 1 = fully covered);
    ``foreground`` (H, W, 3) mean colour of the supersampled rays that hit a surface (straight,
    not premultiplied, alpha; 0 where alpha is 0).
    """

    image: np.ndarray
    depth: np.ndarray
    centre_colour: np.ndarray
    centre_points: np.ndarray
    alpha: np.ndarray
    foreground: np.ndarray

    def rgba(self) -> np.ndarray:
        """(H, W, 4) float RGBA in [0, 1] with straight alpha, background transparent black."""
        return np.concatenate([self.foreground, self.alpha[..., None]], axis=-1)


def render_view(plan: ScenePlan, intr: Intrinsics, c2w: np.ndarray, supersample: int = 2) -> RenderedView:
    """Render view ``c2w`` (4, 4) of ``plan`` with ``supersample`` x ``supersample`` anti-aliasing
    plus one pixel-centre ray per pixel (for depth and seed points)."""
    offsets = supersample_offsets(supersample) + [(0.5, 0.5)]
    cam = intr.camera_dirs(offsets)  # (S+1, H, W, 3)
    world = to_world(c2w, cam).reshape(-1, 3)
    norm = np.sqrt((world * world).sum(axis=1))
    dirs = world / norm[:, None]
    colour, t, points = shade_rays(plan, c2w[:3, 3], dirs)
    s1, h, w = len(offsets), intr.height, intr.width
    colour = colour.reshape(s1, h, w, 3)
    # camera-space z of an unnormalised direction is -1, so z-depth = distance / |direction|
    z = (t / norm).reshape(s1, h, w)[-1]
    depth = np.where(np.isfinite(z), z, 0.0).astype(np.float32)
    hit = np.isfinite(t).reshape(s1, h, w)[:-1]
    n_hit = hit.sum(axis=0)
    fg = (colour[:-1] * hit[..., None]).sum(axis=0) / np.maximum(n_hit, 1)[..., None]
    return RenderedView(
        image=colour[:-1].mean(axis=0),
        depth=depth,
        centre_colour=colour[-1],
        centre_points=points.reshape(s1, h, w, 3)[-1],
        alpha=n_hit / hit.shape[0],
        foreground=fg,
    )
