"""SfM-like seed points of a generated scene: surface samples of the rendered training views with
depth-proportional noise, a share of them (per preset) turned into outliers along their viewing ray."""

from __future__ import annotations

import numpy as np

from stealth_ns.scene_generator.render import RenderedView

SEED_POINTS = 8000
"""Approximate number of seed points written to ``sparse_pc.ply``."""
POINT_NOISE = 0.003
"""Seed point position noise: Gaussian sigma = POINT_NOISE * z-depth (world units)."""
OUTLIER_FRACTION = {"facing": 0.02}
"""Fraction of seed points turned into SfM-like outliers, per preset (none for the others)."""


def sample_seed_points(rng: np.random.Generator, view: RenderedView, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``k`` random surface samples (xyz (k, 3) with depth-proportional noise, rgb (k, 3))
    from the pixel-centre hits of one rendered view."""
    depth = view.depth.reshape(-1)
    valid = np.flatnonzero(depth > 0)
    k = min(k, valid.size)
    pick = np.sort(rng.choice(valid, size=k, replace=False))
    xyz = view.centre_points.reshape(-1, 3)[pick]
    xyz = xyz + rng.normal(size=xyz.shape) * (POINT_NOISE * depth[pick])[:, None]
    return xyz, view.centre_colour.reshape(-1, 3)[pick]


def add_outliers(
    rng: np.random.Generator, xyz: np.ndarray, origins: np.ndarray, fraction: float
) -> tuple[np.ndarray, int]:
    """Turn a ``fraction`` of the points ``xyz`` (N, 3) into SfM-like outliers (mis-triangulated
    matches): moved along the ray from their source camera ``origins`` (N, 3) to a distance scaled
    by a log-normal factor (sigma 0.4, at least 15% off) plus lateral noise of 3% of the distance.
    Colours stay. Returns the new points and the number of outliers."""
    n = int(round(fraction * len(xyz)))
    if n == 0:
        return xyz, 0
    pick = np.sort(rng.choice(len(xyz), size=n, replace=False))
    factor = np.exp(rng.normal(size=n) * 0.4)
    factor = np.where(np.abs(factor - 1.0) < 0.15, 1.0 + np.sign(factor - 1.0 + 1e-12) * 0.15, factor)
    ray = xyz[pick] - origins[pick]
    dist = np.linalg.norm(ray, axis=1, keepdims=True)
    out = xyz.copy()
    out[pick] = origins[pick] + ray * factor[:, None] + rng.normal(size=(n, 3)) * 0.03 * dist
    return out, n
