"""Scene layouts and camera trajectories for the ``orbit`` and ``forward`` presets.

World frame: +Y up, ground plane at y = 0, units of about one object size (~1). Camera poses are
camera-to-world 4x4 matrices in the OpenGL / nerfstudio convention (camera looks along its -Z,
+Y up, +X right).

* ``orbit`` (Mip-NeRF 360 like): 6-8 textured objects within ~1.8 of the origin, a ring of
  background pillars at radius 7-9.5, a polygonal ring of building-like walls at radius ~13 with a
  varying skyline, sky above. Cameras on a gently undulating ring (radius ~4, height 1.0-1.9), all
  looking at ``ORBIT_CENTRE``.
* ``forward`` (Free dataset like): a street along -Z lined with facades at |x| ~ 4.2 and street
  furniture at 1.3 < |x| < 3.2. The camera walks 14 units forward with sideways sway, yaw wobble
  and a speed that varies along the path (so view density varies), always looking roughly forward.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stealth_ns.scenes.geometry import Geometry
from stealth_ns.scenes.textures import Material, NoiseTable, make_noise_table, random_material

PRESETS = ("orbit", "forward")
DEFAULT_VIEWS = {"orbit": 60, "forward": 48}
HFOV_DEG = 60.0
ORBIT_CENTRE = (0.0, 0.45, 0.0)
ORBIT_CAMERA_RADIUS = 4.0
FORWARD_LENGTH = 14.0


@dataclass
class ScenePlan:
    """Everything needed to render a scene.

    ``materials[i]`` is the material of primitive id ``i`` of ``geometry``; ``c2w`` (V, 4, 4)
    camera-to-world poses; ``centre`` (3,) and ``radius`` describe the region of interest
    (world units); ``sky`` seeds the sky's clouds.
    """

    preset: str
    geometry: Geometry
    materials: list[Material]
    sky: NoiseTable
    c2w: np.ndarray
    centre: np.ndarray
    radius: float
    info: dict = field(default_factory=dict)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 1.0, 0.0])) -> np.ndarray:
    """OpenGL camera-to-world (4, 4) at ``eye`` (3,) looking at ``target`` (3,) (camera -Z axis)."""
    eye = np.asarray(eye, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - eye
    f /= np.linalg.norm(f)
    x = np.cross(f, up)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, -f, eye
    return c2w


class _Builder:
    """Adds primitives to a :class:`Geometry` and keeps their materials aligned with primitive ids."""

    def __init__(self) -> None:
        self.geometry = Geometry()
        self.materials: list[Material] = []

    def add(self, kind: str, material: Material, *args, **kwargs) -> int:
        pid = getattr(self.geometry, f"add_{kind}")(*args, **kwargs)
        self.materials.append(material)
        assert len(self.materials) == self.geometry.count
        return pid


def _place_objects(
    rng: np.random.Generator,
    b: _Builder,
    centres: list[tuple[float, float]],
    scale: float = 1.0,
    kinds: tuple[str, ...] | None = None,
) -> list[float]:
    """Put one random object (box, sphere or cylinder) standing on the ground at each (x, z) of
    ``centres``; returns each object's footprint radius. ``scale`` multiplies the sizes."""
    footprints = []
    for i, (x, z) in enumerate(centres):
        kind = kinds[i % len(kinds)] if kinds else ("box", "sphere", "cylinder")[rng.integers(3)]
        mat = random_material(rng)
        if kind == "box":
            hx, hy, hz = rng.uniform(0.18, 0.45, size=3) * scale
            hy = hy * rng.uniform(1.0, 1.6)
            b.add("box", mat, (x, hy, z), (hx, hy, hz), yaw=float(rng.uniform(0, np.pi)))
            footprints.append(float(np.hypot(hx, hz)))
        elif kind == "sphere":
            r = float(rng.uniform(0.22, 0.45) * scale)
            lift = float(rng.uniform(0.0, 0.3)) if rng.random() < 0.3 else 0.0
            b.add("sphere", mat, (x, r + lift, z), r)
            footprints.append(r)
        else:
            r = float(rng.uniform(0.12, 0.32) * scale)
            h = float(rng.uniform(0.5, 1.4) * scale)
            b.add("cylinder", mat, (x, z), r, 0.0, h)
            footprints.append(r)
    return footprints


def _ground(rng: np.random.Generator, b: _Builder) -> None:
    mat = random_material(
        rng, period_range=(0.25, 0.45), patterns=("checker", "grid", "dots", "marble", "bricks")
    )
    b.add("plane", mat, (0.0, 1.0, 0.0), 0.0)


def orbit_plan(seed: int, views: int) -> ScenePlan:
    """The ``orbit`` preset: inward-facing 360-degree ring of ``views`` cameras (see module doc)."""
    rng = np.random.default_rng([seed, 101])
    b = _Builder()
    _ground(rng, b)

    # central group: rejection-sample non-overlapping footprints within radius 1.6
    n_obj = int(rng.integers(6, 9))
    kinds = ("box", "sphere", "cylinder")
    bound = {"box": 0.64, "sphere": 0.45, "cylinder": 0.32}  # largest footprint radius of each kind
    placed: list[tuple[float, float, float]] = []
    for i in range(n_obj):
        kind = kinds[i % 3] if i < 6 else kinds[int(rng.integers(3))]
        for _ in range(200):
            rad, ang = 1.6 * np.sqrt(rng.random()), rng.uniform(0, 2 * np.pi)
            x, z = float(rad * np.cos(ang)), float(rad * np.sin(ang))
            if all(np.hypot(x - px, z - pz) > bound[kind] + pb + 0.05 for px, pz, pb in placed):
                break
        placed.append((x, z, bound[kind]))
        _place_objects(rng, b, [(x, z)], kinds=(kind,))

    # background pillars at radius 7-9.5
    n_pillars = int(rng.integers(9, 13))
    for k in range(n_pillars):
        ang = 2 * np.pi * (k + rng.uniform(-0.25, 0.25)) / n_pillars
        rad = rng.uniform(7.0, 9.5)
        x, z = rad * np.cos(ang), rad * np.sin(ang)
        mat = random_material(rng, period_range=(0.2, 0.45))
        h = float(rng.uniform(1.2, 3.5))
        if rng.random() < 0.5:
            b.add("cylinder", mat, (x, z), float(rng.uniform(0.3, 0.6)), 0.0, h)
        else:
            w = rng.uniform(0.3, 0.7, size=2)
            b.add("box", mat, (x, h / 2, z), (w[0], h / 2, w[1]), yaw=float(rng.uniform(0, np.pi)))

    # ring of wall segments (a skyline) at radius 13
    n_walls = 16
    wall_r = 13.0
    seg = 2 * wall_r * np.tan(np.pi / n_walls) + 0.3
    for k in range(n_walls):
        ang = 2 * np.pi * k / n_walls
        h = float(rng.uniform(1.8, 4.5))
        mat = random_material(
            rng, period_range=(0.35, 0.7), patterns=("bricks", "grid", "stripes", "checker")
        )
        x, z = wall_r * np.cos(ang), wall_r * np.sin(ang)
        # box local x runs along the wall: yaw so that local x is perpendicular to the radius
        b.add("box", mat, (x, h / 2, z), (seg / 2, h / 2, 0.4), yaw=float(np.pi / 2 - ang))

    # cameras: gently undulating ring looking at the centre
    centre = np.array(ORBIT_CENTRE)
    phase = rng.uniform(0, 2 * np.pi)
    c2w = []
    for i in range(views):
        th = 2 * np.pi * i / views + phase
        rad = ORBIT_CAMERA_RADIUS + 0.15 * np.sin(3 * th)
        height = 1.45 + 0.45 * np.sin(2 * th + 0.7)
        eye = np.array([rad * np.cos(th), height, rad * np.sin(th)])
        c2w.append(look_at(eye, centre))
    return ScenePlan(
        preset="orbit",
        geometry=b.geometry,
        materials=b.materials,
        sky=make_noise_table(int(rng.integers(2**31))),
        c2w=np.stack(c2w),
        centre=centre,
        radius=2.0,
        info={"camera_radius": ORBIT_CAMERA_RADIUS, "wall_radius": wall_r},
    )


def forward_plan(seed: int, views: int) -> ScenePlan:
    """The ``forward`` preset: ``views`` cameras walking down a street (see module doc)."""
    rng = np.random.default_rng([seed, 202])
    b = _Builder()
    _ground(rng, b)
    length = FORWARD_LENGTH
    z_far = -length - 22.0
    z_back = 5.0

    # facades on both sides: consecutive boxes of random length and height
    facade_patterns = ("bricks", "grid", "stripes", "checker", "dots")
    for side in (-1.0, 1.0):
        z = z_back
        while z > z_far:
            seg = float(rng.uniform(2.5, 5.5))
            h = float(rng.uniform(2.5, 6.0))
            mat = random_material(rng, period_range=(0.25, 0.55), patterns=facade_patterns)
            depth = float(rng.uniform(0.0, 0.5))
            b.add("box", mat, (side * (4.7 + depth), h / 2, z - seg / 2), (0.5, h / 2, seg / 2))
            z -= seg
    for zc in (z_far - 0.5, z_back + 0.5):
        mat = random_material(rng, period_range=(0.3, 0.6), patterns=facade_patterns)
        b.add("box", mat, (0.0, 3.0, zc), (6.0, 3.0, 0.5))

    # street furniture along both kerbs, some thin posts
    z = -1.0
    side = 1.0 if rng.random() < 0.5 else -1.0
    while z > -length - 14.0:
        x = side * rng.uniform(1.4, 3.2)
        if rng.random() < 0.2:
            mat = random_material(rng, period_range=(0.08, 0.15))
            b.add("cylinder", mat, (x, z), float(rng.uniform(0.07, 0.12)), 0.0, float(rng.uniform(1.8, 2.8)))
        else:
            _place_objects(rng, b, [(x, z)], scale=float(rng.uniform(1.1, 1.7)))
        z -= float(rng.uniform(0.8, 1.6))
        side = -side if rng.random() < 0.75 else side

    # camera path: varying speed s(u) = u + 0.09 sin(2 pi u) (density ratio ~3.6 along the path)
    ph = rng.uniform(0, 2 * np.pi, size=4)
    c2w = []
    for i in range(views):
        u = i / (views - 1)
        s = u + 0.09 * np.sin(2 * np.pi * u)
        eye = np.array(
            [
                0.35 * np.sin(2 * np.pi * 1.3 * s + ph[0]),
                1.35 + 0.08 * np.sin(2 * np.pi * 2.1 * s + ph[1]),
                -length * s,
            ]
        )
        yaw = 0.22 * np.sin(2 * np.pi * 1.7 * s + ph[2])
        pitch = -0.06 + 0.03 * np.sin(2 * np.pi * 2.9 * s + ph[3])
        fwd = np.array([-np.sin(yaw) * np.cos(pitch), np.sin(pitch), -np.cos(yaw) * np.cos(pitch)])
        c2w.append(look_at(eye, eye + fwd))
    return ScenePlan(
        preset="forward",
        geometry=b.geometry,
        materials=b.materials,
        sky=make_noise_table(int(rng.integers(2**31))),
        c2w=np.stack(c2w),
        centre=np.array([0.0, 1.2, -length / 2 - 2.0]),
        radius=length / 2 + 6.0,
        info={"path_length": length},
    )


def make_plan(preset: str, seed: int, views: int) -> ScenePlan:
    """Build the :class:`ScenePlan` of ``preset`` (one of :data:`PRESETS`)."""
    if preset == "orbit":
        return orbit_plan(seed, views)
    if preset == "forward":
        return forward_plan(seed, views)
    raise ValueError(f"unknown preset {preset!r}")
