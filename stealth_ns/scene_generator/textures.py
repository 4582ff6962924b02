"""High-frequency procedural albedo textures as pure functions of 3D hit points.

Every pattern function maps world points to a scalar field (N,) in [0, 1]: solid textures take
``p`` (N, 3) (world units); surface patterns (checker, dots, grid, bricks) take triplanar surface
coordinates ``uv`` (N, 2) from :func:`planar_coords` (points and normals), so they look the same
on faces of any orientation. :class:`Material` mixes two colours with a pattern and modulates the
result with fine value noise so no surface is a flat colour. All randomness comes from a
:class:`NoiseTable` built from a seed, so textures are deterministic.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np

TABLE_SIZE = 256


@dataclass(frozen=True)
class NoiseTable:
    """Hash permutation ``perm`` (256,) int64 and lattice values ``values`` (256,) in [0, 1)."""

    perm: np.ndarray
    values: np.ndarray


def make_noise_table(seed: int) -> NoiseTable:
    """Lattice tables for :func:`value_noise`, deterministic from ``seed`` (a non-negative int)."""
    rng = np.random.default_rng(seed)
    return NoiseTable(perm=rng.permutation(TABLE_SIZE).astype(np.int64), values=rng.random(TABLE_SIZE))


def _hash3(table: NoiseTable, ix: np.ndarray, iy: np.ndarray, iz: np.ndarray) -> np.ndarray:
    perm, m = table.perm, TABLE_SIZE - 1
    return table.values[perm[(perm[(perm[ix & m] + iy) & m] + iz) & m]]


def value_noise(p: np.ndarray, frequency: float, table: NoiseTable) -> np.ndarray:
    """Smooth 3D value noise in [0, 1] with lattice spacing ``1 / frequency`` world units.

    Parameters: p (N, 3) points; frequency (lattice cells per world unit); table from
    :func:`make_noise_table`. Returns (N,).
    """
    q = p * frequency
    i = np.floor(q)
    f = q - i
    i = i.astype(np.int64)
    u = f * f * (3.0 - 2.0 * f)
    ix, iy, iz = i[:, 0], i[:, 1], i[:, 2]
    ux, uy, uz = u[:, 0], u[:, 1], u[:, 2]
    out = np.zeros(p.shape[0])
    for dx in (0, 1):
        wx = ux if dx else 1.0 - ux
        for dy in (0, 1):
            wy = uy if dy else 1.0 - uy
            for dz in (0, 1):
                wz = uz if dz else 1.0 - uz
                out += wx * wy * wz * _hash3(table, ix + dx, iy + dy, iz + dz)
    return out


def fbm(p: np.ndarray, frequency: float, table: NoiseTable, octaves: int = 3) -> np.ndarray:
    """Fractal sum of :func:`value_noise` octaves (each double the frequency, half the weight),
    normalised to [0, 1]. Parameters as :func:`value_noise`; returns (N,)."""
    total = np.zeros(p.shape[0])
    weight, norm = 1.0, 0.0
    for k in range(octaves):
        # offset each octave so lattice points of different octaves do not line up
        total += weight * value_noise(p + 17.31 * k, frequency * 2.0**k, table)
        norm += weight
        weight *= 0.5
    return total / norm


def planar_coords(p: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Triplanar surface coordinates (N, 2): the two world coordinates across each point's
    dominant normal axis, ordered so the second is "up" on vertical faces: (z, y) on faces
    facing x, (x, y) facing z, (x, z) facing y. Inputs p, normal (N, 3)."""
    axis = np.argmax(np.abs(normal), axis=1)
    u = np.where(axis == 0, p[:, 2], p[:, 0])
    v = np.where(axis == 1, p[:, 2], p[:, 1])
    return np.stack([u, v], axis=1)


def checker(uv: np.ndarray, period: float) -> np.ndarray:
    """Checkerboard of squares with side ``period`` world units on surface coordinates uv (N, 2)
    (see :func:`planar_coords`): (N,) values in {0, 1}."""
    c = np.floor(uv / period).astype(np.int64)
    return ((c[:, 0] + c[:, 1]) & 1).astype(np.float64)


def stripes(p: np.ndarray, direction: np.ndarray, period: float, duty: float = 0.5) -> np.ndarray:
    """Parallel slabs across unit ``direction`` (3,), ``period`` world units apart (a solid
    texture of points p (N, 3)); the fraction ``duty`` of each period is 1, the rest 0. Returns (N,)."""
    s = (p[:, 0] * direction[0] + p[:, 1] * direction[1] + p[:, 2] * direction[2]) / period
    return ((s - np.floor(s)) < duty).astype(np.float64)


def dots(uv: np.ndarray, period: float, radius: float = 0.3) -> np.ndarray:
    """Polka dots on surface coordinates uv (N, 2): 1 within ``radius * period`` of a square
    lattice point of spacing ``period``, odd rows shifted by half a period. Returns (N,)."""
    q = uv / period
    q = q + np.stack([0.5 * (np.floor(q[:, 1] + 0.5).astype(np.int64) & 1), np.zeros(len(q))], axis=1)
    d = q - np.round(q)
    return ((d * d).sum(axis=1) < radius * radius).astype(np.float64)


def grid_lines(uv: np.ndarray, period: float, width: float = 0.15) -> np.ndarray:
    """Tile grout on surface coordinates uv (N, 2): 1 within ``width * period / 2`` of a line
    u or v = k * period. Returns (N,)."""
    q = uv / period
    d = np.abs(q - np.round(q))
    return (d.min(axis=1) < width * 0.5).astype(np.float64)


def bricks(uv: np.ndarray, width: float, height: float, mortar: float = 0.08) -> np.ndarray:
    """Running-bond bricks on surface coordinates uv (N, 2) (rows along v, every other row shifted
    by half a brick); ``width``/``height`` in world units, ``mortar`` a fraction of the brick
    height. Returns (N,), 1 on mortar."""
    row = np.floor(uv[:, 1] / height)
    fy = uv[:, 1] / height - row
    h = uv[:, 0] / width + 0.5 * (row.astype(np.int64) & 1)
    fx = h - np.floor(h)
    return ((fy < mortar) | (fx < mortar * height / width)).astype(np.float64)


def marble(p: np.ndarray, period: float, table: NoiseTable, turbulence: float = 4.0) -> np.ndarray:
    """Marble veins: ``0.5 + 0.5 sin`` of a coordinate sum warped by :func:`fbm`. Returns (N,)."""
    s = (p[:, 0] + 0.7 * p[:, 1] + 0.4 * p[:, 2]) * (2.0 * np.pi / period)
    return 0.5 + 0.5 * np.sin(s + turbulence * fbm(p, 2.0 / period, table))


def blotches(p: np.ndarray, period: float, table: NoiseTable) -> np.ndarray:
    """Thresholded fractal noise (camouflage-like blobs about ``period`` across), values in [0, 1]."""
    return np.clip((fbm(p, 1.0 / period, table) - 0.5) * 3.5 + 0.5, 0.0, 1.0)


PATTERNS = ("checker", "stripes", "dots", "grid", "bricks", "marble", "blotches")
SURFACE_PATTERNS = ("checker", "dots", "grid", "bricks")
"""Patterns drawn in 2D surface coordinates (:func:`planar_coords`); the others are solid textures."""


@dataclass(frozen=True)
class Material:
    """Albedo = mix(colour_a, colour_b, pattern) * (1 + detail * (2 * fine_noise - 1)).

    ``pattern`` is one of :data:`PATTERNS`; ``period`` its feature size (world units);
    ``direction`` (3,) is used by stripes; colours are linear RGB in [0, 1].
    """

    pattern: str
    colour_a: tuple[float, float, float]
    colour_b: tuple[float, float, float]
    period: float
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    detail: float = 0.25
    table: NoiseTable | None = None

    def field(self, p: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """The pattern's scalar field (N,) in [0, 1] at surface points p (N, 3) with unit normals
        ``normal`` (N, 3) (used by the surface patterns through :func:`planar_coords`)."""
        table = self.table if self.table is not None else make_noise_table(0)
        if self.pattern in SURFACE_PATTERNS:
            uv = planar_coords(p, normal)
            if self.pattern == "checker":
                return checker(uv, self.period)
            if self.pattern == "dots":
                return dots(uv, self.period)
            if self.pattern == "grid":
                return grid_lines(uv, self.period)
            return bricks(uv, self.period, self.period * 0.45)
        if self.pattern == "stripes":
            return stripes(p, np.asarray(self.direction), self.period)
        if self.pattern == "marble":
            return marble(p, self.period * 1.2, table)
        if self.pattern == "blotches":
            return blotches(p, self.period, table)
        raise ValueError(f"unknown pattern {self.pattern!r}")

    def albedo(self, p: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Albedo (N, 3) in [0, 1] at world points p (N, 3) with unit normals (N, 3)."""
        table = self.table if self.table is not None else make_noise_table(0)
        w = self.field(p, normal)[:, None]
        base = (1.0 - w) * np.asarray(self.colour_a) + w * np.asarray(self.colour_b)
        grain = fbm(p + 3.7, 1.5 / self.period, table, octaves=2)
        return np.clip(base * (1.0 + self.detail * (2.0 * grain[:, None] - 1.0)), 0.0, 1.0)


def random_colour(
    rng: np.random.Generator, sat: tuple[float, float] = (0.35, 0.9), val: tuple[float, float] = (0.45, 0.95)
) -> tuple[float, float, float]:
    """A random saturated RGB colour (3 floats in [0, 1]) drawn from ``rng``."""
    h, s, v = rng.random(), rng.uniform(*sat), rng.uniform(*val)
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h, s, v))


def contrasting_colour(
    rng: np.random.Generator, colour: tuple[float, float, float]
) -> tuple[float, float, float]:
    """A colour clearly different from ``colour`` in hue and brightness (3 floats in [0, 1])."""
    h, s, v = colorsys.rgb_to_hsv(*colour)
    h2 = (h + rng.uniform(0.25, 0.75)) % 1.0
    v2 = v - 0.35 if v > 0.6 else v + 0.35
    s2 = float(np.clip(s + rng.uniform(-0.3, 0.3), 0.15, 0.95))
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h2, s2, float(np.clip(v2, 0.1, 1.0))))


def random_material(
    rng: np.random.Generator,
    period_range: tuple[float, float] = (0.12, 0.3),
    patterns: tuple[str, ...] = PATTERNS,
) -> Material:
    """A material with a random pattern, contrasting colour pair, feature size and noise table."""
    pattern = str(patterns[rng.integers(len(patterns))])
    a = random_colour(rng)
    b = contrasting_colour(rng, a)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return Material(
        pattern=pattern,
        colour_a=a,
        colour_b=b,
        period=float(rng.uniform(*period_range)),
        direction=tuple(float(x) for x in direction),
        detail=float(rng.uniform(0.15, 0.35)),
        table=make_noise_table(int(rng.integers(2**31))),
    )


def sky_colour(dirs: np.ndarray, table: NoiseTable) -> np.ndarray:
    """Sky radiance (N, 3) in [0, 1] for unit view directions ``dirs`` (N, 3): a horizon-to-zenith
    gradient with fractal clouds (a pure function of direction, i.e. infinitely far away)."""
    up = np.clip(dirs[:, 1], 0.0, 1.0)[:, None]
    horizon = np.array([0.86, 0.88, 0.92])
    zenith = np.array([0.28, 0.48, 0.82])
    base = horizon + (zenith - horizon) * np.sqrt(up)
    proj = dirs / np.maximum(dirs[:, 1:2], 0.08) * np.array([1.0, 0.0, 1.0])
    cloud = fbm(proj * 0.8, 1.5, table, octaves=4)
    cover = np.clip((cloud - 0.45) * 3.0, 0.0, 1.0)[:, None]
    return np.clip(base * (1.0 - cover) + np.array([0.97, 0.97, 0.98]) * cover, 0.0, 1.0)
