"""Scene layouts and camera trajectories of the presets.

Render frame: +Y up, ground plane (where there is one) at y = 0, units of about one object size
(~1). Camera poses are camera-to-world 4x4 matrices in the OpenGL / nerfstudio convention (camera
looks along its -Z, +Y up, +X right). A plan's ``export`` (4, 4) maps the render frame to the frame
the poses are written in: the identity except for ``object``, whose poses are written in Blender's
Z-up frame with the object at the origin.

* ``orbit`` (Mip-NeRF 360 like): 6-8 textured objects within ~1.8 of the origin, a ring of
  background pillars at radius 7-9.5, a polygonal ring of building-like walls at radius ~13 with a
  varying skyline, sky above. Cameras on a gently undulating ring (radius ~4, height 1.0-1.9), all
  looking at ``ORBIT_CENTRE``.
* ``forward`` (Free dataset like): a street along -Z lined with facades at |x| ~ 4.2 and street
  furniture at 1.3 < |x| < 3.2. The camera walks 14 units forward with sideways sway, yaw wobble
  and a speed that varies along the path (so view density varies), always looking roughly forward.
* ``facing`` (LLFF like): a forward-facing hand-held capture of a cluttered tabletop-like scene:
  12-16 textured objects at depths 2-6 standing on a textured ground, in front of a back wall at
  depth ~7 (3 segments of different materials). The cameras lie on a jittered serpentine grid
  within a 0.5 x 0.35 rectangle (baseline ~10x smaller than the scene depth), all looking roughly
  along -Z at a common focus point at depth ~4.5, with hand-held jitter of a couple of degrees
  (yaw, pitch and roll).
* ``object`` (NeRF-synthetic / Blender like): 1-3 textured objects (boxes, spheres, cylinders),
  on a small round pedestal for most seeds, no ground and no background (rays that miss are
  transparent). Poses are written in Blender's Z-up world frame with the group centred at the
  origin and scaled so that it just fits in the unit sphere (``export``; depth maps are in the
  same units). Views are ``train`` (a jittered Fibonacci spiral covering the upper hemisphere,
  elevation 8-75 degrees), ``val`` (random on the same band) and ``test`` (an evenly spaced ring
  at 30 degrees elevation, like the Blender test sets), all at radius 4 looking at the origin,
  with Blender lego's field of view (camera_angle_x = 0.6911 rad, ~39.6 degrees).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stealth_ns.scene_generator.geometry import Geometry
from stealth_ns.scene_generator.textures import Material, NoiseTable, make_noise_table, random_material

PRESETS = ("orbit", "forward", "facing", "object")
DEFAULT_VIEWS = {"orbit": 60, "forward": 48, "facing": 24, "object": 150}
DEFAULT_RESOLUTION = {"orbit": "128x96", "forward": "128x96", "facing": "128x96", "object": "128x128"}
BLENDER_PRESETS = ("object",)
"""Presets written in the Blender (NeRF-synthetic) format; the others in nerfstudio-data format."""
HFOV_DEG = 60.0
ORBIT_CENTRE = (0.0, 0.45, 0.0)
ORBIT_CAMERA_RADIUS = 4.0
FORWARD_LENGTH = 14.0
FACING_RECT = (0.5, 0.35)
"""Width (x) and height (y) of the rectangle that holds the ``facing`` cameras (world units)."""
FACING_WALL_DEPTH = 7.0
OBJECT_CAMERA_RADIUS = 4.0
OBJECT_RADIUS = 1.0
"""Radius of the smallest origin-centred sphere around the ``object`` group (export frame)."""
OBJECT_CAMERA_ANGLE_X = 0.6911112070083618
"""Horizontal field of view of the ``object`` preset (radians): that of NeRF-synthetic's lego."""
OBJECT_TEST_ELEVATION_DEG = 30.0
BLENDER_FROM_RENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Rotation from the render frame (+Y up) to Blender's world frame (+Z up)."""


@dataclass
class ScenePlan:
    """Everything needed to render a scene.

    ``materials[i]`` is the material of primitive id ``i`` of ``geometry``; ``c2w`` (V, 4, 4)
    camera-to-world poses in the render frame; ``centre`` (3,) and ``radius`` describe the region
    of interest (world units of the export frame); ``sky`` seeds the sky's clouds (None: no sky,
    black); ``hfov_deg`` is the horizontal field of view; ``export`` (4, 4), a similarity transform,
    maps render-frame points to the frame the poses are written in (:meth:`exported_c2w`);
    ``splits`` holds the view index ranges [start, stop) of a Blender preset's train, val and test
    views, empty for the nerfstudio-data presets.
    """

    preset: str
    geometry: Geometry
    materials: list[Material]
    sky: NoiseTable | None
    c2w: np.ndarray
    centre: np.ndarray
    radius: float
    info: dict = field(default_factory=dict)
    hfov_deg: float = HFOV_DEG
    export: np.ndarray = field(default_factory=lambda: np.eye(4))
    splits: dict[str, tuple[int, int]] = field(default_factory=dict)

    @property
    def export_scale(self) -> float:
        """Scale factor of ``export`` (a similarity transform): export-frame units per render unit."""
        return float(np.cbrt(np.linalg.det(self.export[:3, :3])))

    def exported_c2w(self) -> np.ndarray:
        """Camera-to-world poses (V, 4, 4) in the export frame: positions mapped by ``export``,
        rotations by its rotation part (so they stay orthonormal)."""
        out = np.einsum("ij,vjk->vik", self.export, self.c2w)
        out[:, :3, :3] /= self.export_scale
        return out


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


def _roll(c2w: np.ndarray, angle: float) -> np.ndarray:
    """``c2w`` (4, 4) rolled by ``angle`` radians about its own viewing axis."""
    c, s = np.cos(angle), np.sin(angle)
    out = c2w.copy()
    out[:3, :3] = c2w[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return out


def facing_plan(seed: int, views: int) -> ScenePlan:
    """The ``facing`` preset: ``views`` forward-facing hand-held cameras (see module doc)."""
    rng = np.random.default_rng([seed, 404])
    b = _Builder()
    _ground(rng, b)
    tan_half = np.tan(np.deg2rad(HFOV_DEG) / 2)

    # back wall: three segments of different materials and slightly different depths
    wall_patterns = ("bricks", "grid", "stripes", "checker", "marble", "blotches")
    edges = np.array([-8.0, float(rng.uniform(-2.2, -0.8)), float(rng.uniform(0.8, 2.2)), 8.0])
    for k in range(3):
        mat = random_material(rng, period_range=(0.25, 0.5), patterns=wall_patterns)
        front = FACING_WALL_DEPTH + float(rng.uniform(0.0, 0.4))
        half_w = (edges[k + 1] - edges[k]) / 2
        b.add("box", mat, ((edges[k] + edges[k + 1]) / 2, 3.5, -front - 0.5), (half_w, 3.5, 0.5))

    # clutter: non-overlapping objects at depths 2.2-6 inside the view frustum, a few thin posts
    bound = {"box": 0.64, "sphere": 0.45, "cylinder": 0.32}
    placed: list[tuple[float, float, float]] = []
    n_obj = int(rng.integers(12, 17))
    for i in range(n_obj):
        kind = (
            ("box", "sphere", "cylinder")[i % 3] if i < 9 else ("box", "sphere", "cylinder")[rng.integers(3)]
        )
        scale = float(rng.uniform(0.6, 1.1))
        for _ in range(200):
            d = float(rng.uniform(2.2, 6.0))
            x = float(rng.uniform(-0.85, 0.85) * d * tan_half)
            r = bound[kind] * scale
            if all(np.hypot(x - px, -d - pz) > r + pr + 0.03 for px, pz, pr in placed):
                break
        placed.append((x, -d, r))
        _place_objects(rng, b, [(x, -d)], scale=scale, kinds=(kind,))
    for _ in range(int(rng.integers(2, 4))):
        d = float(rng.uniform(3.0, 6.5))
        x = float(rng.uniform(-0.9, 0.9) * d * tan_half)
        mat = random_material(rng, period_range=(0.06, 0.12))
        b.add("cylinder", mat, (x, -d), float(rng.uniform(0.05, 0.09)), 0.0, float(rng.uniform(1.6, 2.6)))

    # cameras: jittered serpentine grid (hand-held), all looking at a common focus point
    width, height = FACING_RECT
    cols = max(1, int(np.ceil(np.sqrt(views * width / height))))
    rows = int(np.ceil(views / cols))
    focus = np.array([0.0, 0.8, -4.5])
    centre_cam = np.array([0.0, 1.1, 0.0])
    c2w = []
    for i in range(views):
        r, c = divmod(i, cols)
        c = c if r % 2 == 0 else cols - 1 - c
        gx = (c + 0.5 + rng.uniform(-0.25, 0.25)) / cols - 0.5
        gy = (r + 0.5 + rng.uniform(-0.25, 0.25)) / rows - 0.5
        eye = centre_cam + np.array([gx * width, -gy * height, float(rng.uniform(-0.03, 0.03))])
        target = focus + rng.normal(size=3) * np.array([0.12, 0.08, 0.0])
        c2w.append(_roll(look_at(eye, target), float(rng.normal() * np.deg2rad(1.0))))
    return ScenePlan(
        preset="facing",
        geometry=b.geometry,
        materials=b.materials,
        sky=make_noise_table(int(rng.integers(2**31))),
        c2w=np.stack(c2w),
        centre=np.array([0.0, 1.0, -4.5]),
        radius=3.5,
        info={
            "camera_rect": list(FACING_RECT),
            "camera_grid": [cols, rows],
            "wall_depth": FACING_WALL_DEPTH,
            "n_objects": n_obj,
        },
    )


def object_splits(views: int) -> dict[str, tuple[int, int]]:
    """Index ranges [start, stop) of the ``object`` preset's train, val and test views: val and
    test get ``views // 6`` views each (25 of the default 150), train the rest."""
    n = views // 6
    return {"train": (0, views - 2 * n), "val": (views - 2 * n, views - n), "test": (views - n, views)}


def _object_extent(geometry: Geometry) -> tuple[np.ndarray, float]:
    """Centre (3,) of the axis-aligned bounding box of ``geometry``'s boxes, spheres and vertical
    cylinders (planes are not allowed), and the largest distance from it to any of their points."""
    a = geometry.arrays()
    lo, hi = [], []  # per-kind AABB corners
    if "box" in a:
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        local = signs[None] * a["box"]["half"][:, None]  # (P, 8, 3)
        corners = (np.einsum("pij,pkj->pki", a["box"]["rot"], local) + a["box"]["centre"][:, None]).reshape(
            -1, 3
        )
        lo.append(corners.min(axis=0))
        hi.append(corners.max(axis=0))
    if "sphere" in a:
        sc, sr = a["sphere"]["centre"], a["sphere"]["radius"]
        lo.append((sc - sr[:, None]).min(axis=0))
        hi.append((sc + sr[:, None]).max(axis=0))
    if "cylinder" in a:
        cxz, r, yr = a["cylinder"]["centre_xz"], a["cylinder"]["radius"], a["cylinder"]["y_range"]
        lo.append(np.array([(cxz[:, 0] - r).min(), yr[:, 0].min(), (cxz[:, 1] - r).min()]))
        hi.append(np.array([(cxz[:, 0] + r).max(), yr[:, 1].max(), (cxz[:, 1] + r).max()]))
    centre = (np.min(lo, axis=0) + np.max(hi, axis=0)) / 2
    extent = 0.0
    if "box" in a:  # farthest point of a box: a corner
        extent = max(extent, float(np.linalg.norm(corners - centre, axis=1).max()))
    if "sphere" in a:
        extent = max(extent, float((np.linalg.norm(sc - centre, axis=1) + sr).max()))
    if "cylinder" in a:  # farthest point of a vertical cylinder: on the rim of a cap
        horiz = np.hypot(cxz[:, 0] - centre[0], cxz[:, 1] - centre[2]) + r
        vert = np.abs(yr - centre[1]).max(axis=1)
        extent = max(extent, float(np.hypot(horiz, vert).max()))
    return centre, extent


def _hemisphere_eye(elevation: float, azimuth: float) -> np.ndarray:
    """Render-frame (+Y up) camera position at ``OBJECT_CAMERA_RADIUS`` (radians in, (3,) out)."""
    return OBJECT_CAMERA_RADIUS * np.array(
        [np.cos(elevation) * np.cos(azimuth), np.sin(elevation), np.cos(elevation) * np.sin(azimuth)]
    )


def object_plan(seed: int, views: int) -> ScenePlan:
    """The ``object`` preset: 1-3 objects on a transparent background (see module doc)."""
    rng = np.random.default_rng([seed, 505])
    b = _Builder()
    n_obj = int(rng.integers(1, 4))
    pedestal = bool(rng.random() < 0.6)
    if n_obj == 1:
        centres, scale = [(0.0, 0.0)], 1.1
    else:
        ring = 0.5 if n_obj == 2 else 0.56
        phase = rng.uniform(0, 2 * np.pi)
        angles = phase + 2 * np.pi * np.arange(n_obj) / n_obj
        centres = [(float(ring * np.cos(a)), float(ring * np.sin(a))) for a in angles]
        scale = 0.8
    footprints = _place_objects(rng, b, centres, scale=scale)
    if pedestal:  # a thin disc just larger than the group's footprint
        reach = max(np.hypot(x, z) + f for (x, z), f in zip(centres, footprints, strict=True))
        mat = random_material(
            rng, period_range=(0.08, 0.16), patterns=("checker", "grid", "marble", "bricks")
        )
        b.add("cylinder", mat, (0.0, 0.0), float(min(reach + 0.12, 1.05)), -0.12, 0.0)

    # centre the group at the origin and scale it to a radius of OBJECT_RADIUS in the export frame
    centre_render, extent = _object_extent(b.geometry)
    scale = OBJECT_RADIUS / extent
    export = np.eye(4)
    export[:3, :3] = scale * BLENDER_FROM_RENDER
    export[:3, 3] = -scale * BLENDER_FROM_RENDER @ centre_render

    splits = object_splits(views)
    n_train = splits["train"][1]
    n_val = splits["val"][1] - splits["val"][0]
    n_test = splits["test"][1] - splits["test"][0]
    lo_el, hi_el = np.deg2rad(8.0), np.deg2rad(75.0)
    eyes = []
    # train: Fibonacci spiral, uniform in area over the elevation band, jittered
    golden = np.pi * (3.0 - np.sqrt(5.0))
    phase = rng.uniform(0, 2 * np.pi)
    for k in range(n_train):
        h = np.sin(lo_el) + (np.sin(hi_el) - np.sin(lo_el)) * (k + rng.uniform(0.2, 0.8)) / n_train
        eyes.append(_hemisphere_eye(float(np.arcsin(h)), phase + golden * k + rng.uniform(-0.1, 0.1)))
    # val: random, uniform in area over the same band
    for _ in range(n_val):
        h = rng.uniform(np.sin(lo_el), np.sin(hi_el))
        eyes.append(_hemisphere_eye(float(np.arcsin(h)), rng.uniform(0, 2 * np.pi)))
    # test: an evenly spaced ring at a fixed elevation
    phase = rng.uniform(0, 2 * np.pi)
    for k in range(n_test):
        eyes.append(
            _hemisphere_eye(np.deg2rad(OBJECT_TEST_ELEVATION_DEG), phase + 2 * np.pi * k / max(n_test, 1))
        )
    c2w = np.stack([look_at(eye / scale + centre_render, centre_render) for eye in eyes])
    return ScenePlan(
        preset="object",
        geometry=b.geometry,
        materials=b.materials,
        sky=None,
        c2w=c2w,
        centre=np.zeros(3),
        radius=OBJECT_RADIUS,
        info={
            "camera_radius": OBJECT_CAMERA_RADIUS,
            "camera_angle_x": OBJECT_CAMERA_ANGLE_X,
            "n_objects": n_obj,
            "pedestal": pedestal,
            "world_up": [0.0, 0.0, 1.0],
            "blender_from_render": export,
            "export_scale": scale,
        },
        hfov_deg=float(np.rad2deg(OBJECT_CAMERA_ANGLE_X)),
        export=export,
        splits=splits,
    )


def scene_plan(preset: str, seed: int, views: int) -> ScenePlan:
    """Build the :class:`ScenePlan` of ``preset`` (one of :data:`PRESETS`)."""
    if preset == "orbit":
        return orbit_plan(seed, views)
    if preset == "forward":
        return forward_plan(seed, views)
    if preset == "facing":
        return facing_plan(seed, views)
    if preset == "object":
        return object_plan(seed, views)
    raise ValueError(f"unknown preset {preset!r}")
