"""The paper's KDE difficulty protocol: rank training views by the scene density inside their frustum.

StealthAttack §Evaluation Protocol, for scenes with irregular camera trajectories:

1. compute the scene's density distribution with a KDE;
2. compute each camera's density inside its field of view, with a sampling radius of 10 % (of the scene
   diagonal, per the authors' notes);
3. sort the cameras by density and pick three: **Easy** = minimum density (the least covered view, where an
   illusion has the most empty space to live in), **Median** = median density, **Hard** = maximum density.

Our reading, implemented here:

* the scene density is the attack's own KDE (:mod:`stealth_ns.attack.density`) of the dataset's seed point
  cloud (SfM points), every point with weight 1, after the same statistical outlier removal the attack
  applies, on a grid of ``grid_resolution`` voxels along the longest side of the points' bounding box,
  smoothed with a Gaussian of ``bandwidth`` voxels and normalised to a maximum of 1 (the
  :class:`~stealth_ns.attack.config.AttackConfig` defaults, read from it);
* the sampling radius is ``r = radius_fraction * diagonal`` of that (inlier) bounding box;
* a camera's density is the *volume average* of the KDE over the part of its pinhole view frustum that lies
  within distance ``r`` of the camera centre (a cone capped by a sphere). It is estimated with a fixed,
  deterministic quadrature: a regular grid of pixel directions over the image, weighted by the solid angle
  each covers, times depths at the mid-volume of equal-volume shells in ``(0, r]``; KDE values outside the
  grid count as 0 (empty space);
* the cameras are the dataparser's *training* views (the attack poisons training views), with poses and
  points as nerfstudio's dataparser outputs them (recentred, oriented and scaled consistently), so the
  ranking is in the same frame as training. Lens distortion is ignored (pinhole frustum).

Camera convention (nerfstudio / OpenGL): ``c2w`` maps camera to world; the camera looks along its local
``-Z`` axis, ``+Y`` is up and ``+X`` right; image coordinates ``(u, v)`` are continuous, with the image
covering ``[0, width] x [0, height]`` and ``v`` growing downwards.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np

from stealth_ns.attack.config import AttackConfig
from stealth_ns.errors import StealthNSError

if TYPE_CHECKING:
    from stealth_ns.attack.density import DensityGrid

__all__ = [
    "FrustumSamples",
    "RankViews",
    "ViewRanking",
    "bbox_diagonal",
    "detect_format",
    "frustum_samples",
    "plot_ranking",
    "rank",
    "rank_scene_views",
    "scene_kde",
    "view_densities",
]

_ATTACK_DEFAULTS = {f.name: f.default for f in fields(AttackConfig)}
DEFAULT_GRID_RESOLUTION: int = _ATTACK_DEFAULTS["grid_resolution"]
"""The attack's KDE grid (voxels along the longest side): the protocol ranks views by the density the
attack itself would use."""
DEFAULT_BANDWIDTH: float = _ATTACK_DEFAULTS["bandwidth"]
"""The attack's KDE bandwidth h in voxels."""
DEFAULT_RADIUS_FRACTION = 0.1
DEFAULT_N_DIRS = 32
DEFAULT_N_DEPTHS = 32

Format = Literal["nerfstudio-data", "colmap"]
_COLMAP_DIRS = ("colmap/sparse/0", "sparse/0", "sparse")


class FrustumSamples(NamedTuple):
    """Quadrature points of a camera's view frustum within a radius.

    Attributes:
        points: ``[M, 3]`` world points (scene units).
        weights: ``[M]`` non-negative weights summing to 1 (the share of the frustum volume each stands for).
    """

    points: np.ndarray
    weights: np.ndarray


def frustum_samples(
    c2w: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: float,
    height: float,
    radius: float,
    n_dirs: int = DEFAULT_N_DIRS,
    n_depths: int = DEFAULT_N_DEPTHS,
) -> FrustumSamples:
    """Deterministic volume samples of a pinhole camera's frustum, up to distance ``radius`` from its centre.

    Directions go through the centres of an ``n_rows x n_dirs`` grid of cells tiling the image
    (``n_rows = max(1, round(n_dirs * height / width))``); a direction at angle ``theta`` to the optical
    axis is weighted by its cell's solid angle, ``cos(theta)^3``. Along each direction, the distances
    ``t_k = radius * ((k + 0.5) / n_depths)^(1/3)``, ``k = 0..n_depths-1``, are the mid-volume points of
    ``n_depths`` equal-volume spherical shells, so all samples on a direction weigh the same.

    Args:
        c2w: ``[3, 4]`` or ``[4, 4]`` camera-to-world matrix (OpenGL axes, see the module docstring).
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels.
        width, height: image size in pixels.
        radius: sampling radius in scene units (> 0).
        n_dirs: directions across the image width (>= 1).
        n_depths: samples along each direction (>= 1).

    Returns:
        :class:`FrustumSamples` with ``M = n_rows * n_dirs * n_depths`` points, every one inside the image's
        field of view and at a distance in ``(0, radius]`` from the camera centre.
    """
    m = np.asarray(c2w, dtype=np.float64)
    if m.shape not in ((3, 4), (4, 4)):
        raise ValueError(f"c2w must be [3, 4] or [4, 4], got {m.shape}")
    intr = (fx, fy, cx, cy, width, height)
    if not all(math.isfinite(float(v)) for v in intr) or fx == 0 or fy == 0 or width <= 0 or height <= 0:
        raise ValueError(f"bad intrinsics fx={fx}, fy={fy}, cx={cx}, cy={cy}, width={width}, height={height}")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a positive number, got {radius!r}")
    if int(n_dirs) != n_dirs or n_dirs < 1 or int(n_depths) != n_depths or n_depths < 1:
        raise ValueError(f"n_dirs and n_depths must be positive integers, got {n_dirs!r}, {n_depths!r}")
    n_cols, n_rows = int(n_dirs), max(1, round(n_dirs * height / width))
    u = (np.arange(n_cols) + 0.5) * (width / n_cols)
    v = (np.arange(n_rows) + 0.5) * (height / n_rows)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    d_cam = np.stack([(uu - cx) / fx, -(vv - cy) / fy, -np.ones_like(uu)], axis=-1).reshape(-1, 3)
    norm = np.linalg.norm(d_cam, axis=-1)
    d_cam /= norm[:, None]
    dirs = d_cam @ m[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)  # c2w may carry a slight scale
    t = radius * ((np.arange(n_depths) + 0.5) / n_depths) ** (1.0 / 3.0)
    points = m[:3, 3] + dirs[:, None, :] * t[None, :, None]
    w_dir = norm**-3.0  # cos(theta)^3: solid angle of an image cell at angle theta off-axis
    weights = np.repeat(w_dir / (w_dir.sum() * n_depths), n_depths)
    return FrustumSamples(points.reshape(-1, 3), weights)


def view_densities(
    kde: DensityGrid,
    c2ws: np.ndarray,
    fx: float | np.ndarray,
    fy: float | np.ndarray,
    cx: float | np.ndarray,
    cy: float | np.ndarray,
    width: float | np.ndarray,
    height: float | np.ndarray,
    radius: float,
    n_dirs: int = DEFAULT_N_DIRS,
    n_depths: int = DEFAULT_N_DEPTHS,
    mode: Literal["nearest", "trilinear"] = "nearest",
) -> np.ndarray:
    """Mean scene density inside each camera's frustum, within ``radius`` of its centre.

    Args:
        kde: the scene's KDE grid (e.g. from :func:`scene_kde`, normalised to a maximum of 1).
        c2ws: ``[N, 3, 4]`` (or ``[N, 4, 4]``) camera-to-world matrices (OpenGL axes).
        fx, fy, cx, cy, width, height: intrinsics in pixels, scalars or ``[N]`` (any shape with N elements).
        radius: sampling radius in scene units.
        n_dirs, n_depths: quadrature size, see :func:`frustum_samples`.
        mode: grid lookup, see :func:`stealth_ns.attack.density.sample_grid` (the attack uses ``"nearest"``).

    Returns:
        ``[N]`` float64 volume-weighted mean KDE value per camera (in the KDE's units; ``[0, 1]`` for a
        normalised KDE).
    """
    from stealth_ns.attack.density import sample_grid

    c2ws = np.asarray(c2ws, dtype=np.float64)
    if c2ws.ndim != 3 or c2ws.shape[1:] not in ((3, 4), (4, 4)):
        raise ValueError(f"c2ws must be [N, 3, 4] or [N, 4, 4], got {c2ws.shape}")
    n = c2ws.shape[0]
    intr = []
    for name, value in zip(
        ("fx", "fy", "cx", "cy", "width", "height"), (fx, fy, cx, cy, width, height), strict=True
    ):
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
        if arr.size not in (1, n):
            raise ValueError(f"{name} must be a scalar or have {n} values, got {arr.size}")
        intr.append(np.broadcast_to(arr, (n,)))
    out = np.empty(n, dtype=np.float64)
    for i in range(n):
        params = [float(a[i]) for a in intr]
        samples = frustum_samples(c2ws[i], *params, radius=radius, n_dirs=n_dirs, n_depths=n_depths)
        out[i] = float(np.dot(sample_grid(kde, samples.points, mode=mode), samples.weights))
    return out


def rank(densities: np.ndarray) -> tuple[int, int, int]:
    """The Easy, Median and Hard views of a list of view densities.

    Views are sorted ascending by ``(density, position)``, so ties go to the earlier view in the ascending
    order (a stable sort). Easy is the first (minimum density), Hard the last (maximum), Median the one at
    position ``(N - 1) // 2`` of the sorted list (the lower median for even ``N``).

    Args:
        densities: ``[N]`` finite view densities, ``N >= 1``.

    Returns:
        ``(easy, median, hard)`` positions into ``densities``.
    """
    d = np.asarray(densities, dtype=np.float64)
    if d.ndim != 1 or d.size == 0:
        raise ValueError(f"densities must be a non-empty 1-D array, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError("densities contain non-finite values")
    order = np.argsort(d, kind="stable")
    return int(order[0]), int(order[(d.size - 1) // 2]), int(order[-1])


def bbox_diagonal(points: np.ndarray) -> float:
    """Length of the diagonal of the axis-aligned bounding box of ``[N, 3]`` points (scene units)."""
    pts = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def scene_kde(
    points: np.ndarray,
    grid_resolution: int = DEFAULT_GRID_RESOLUTION,
    voxel_size: float | None = None,
    bandwidth: float = DEFAULT_BANDWIDTH,
) -> DensityGrid:
    """Normalised KDE of a point cloud, every point weighing 1 (the attack's density, §3.3).

    Args:
        points: ``[N, 3]`` scene points (scene units).
        grid_resolution: voxels along the longest side of the points' bounding box (used when
            ``voxel_size`` is None).
        voxel_size: voxel edge in scene units, or None.
        bandwidth: Gaussian kernel standard deviation in voxels.

    Returns:
        The KDE as a :class:`~stealth_ns.attack.density.DensityGrid` with values in ``[0, 1]``.
    """
    from stealth_ns.attack.density import gaussian_kde_grid, voxel_density

    pts = np.asarray(points, dtype=np.float64)
    ones = np.ones(len(pts), dtype=np.float64)
    if voxel_size is not None:
        grid = voxel_density(pts, ones, voxel_size=voxel_size)
    else:
        grid = voxel_density(pts, ones, resolution=grid_resolution)
    return gaussian_kde_grid(grid, bandwidth, normalize=True)


@dataclass
class ViewRanking:
    """Training views ranked by the density of the scene in their frustum.

    Attributes:
        names: image file names (``Path(filename).name``, e.g. ``frame_00012.png``), in training order.
        indices: ``[N]`` training-view indices of those images (dataparser train split).
        densities: ``[N]`` float64 mean normalised KDE in each view's frustum (unitless, ``[0, 1]``).
        radius: sampling radius in scene units (the dataparser's rescaled units).
        diagonal: diagonal of the seed points' bounding box (scene units), ``radius / radius_fraction``.
        data: the dataset folder.
        dataparser: ``"nerfstudio-data"`` or ``"colmap"``.
        settings: the protocol's parameters (radius fraction, KDE grid and bandwidth, sample counts, ...).
    """

    names: list[str]
    indices: list[int]
    densities: np.ndarray
    radius: float
    diagonal: float = float("nan")
    data: Path | None = None
    dataparser: str = ""
    settings: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.densities = np.asarray(self.densities, dtype=np.float64).reshape(-1)
        self.names = [str(n) for n in self.names]
        self.indices = [int(i) for i in self.indices]
        if not (len(self.names) == len(self.indices) == self.densities.size):
            raise ValueError(
                f"names ({len(self.names)}), indices ({len(self.indices)}) and densities "
                f"({self.densities.size}) must have the same length"
            )
        self._picks = rank(self.densities)

    @property
    def order(self) -> np.ndarray:
        """``[N]`` positions sorted by ascending density (ties: earlier position first)."""
        return np.argsort(self.densities, kind="stable")

    @property
    def easy_index(self) -> int:
        """Training index of the Easy view (minimum density)."""
        return self.indices[self._picks[0]]

    @property
    def median_index(self) -> int:
        """Training index of the Median view."""
        return self.indices[self._picks[1]]

    @property
    def hard_index(self) -> int:
        """Training index of the Hard view (maximum density)."""
        return self.indices[self._picks[2]]

    @property
    def easy(self) -> str:
        """Image name of the Easy view (usable as ``--pipeline.attack.views NAME``)."""
        return self.names[self._picks[0]]

    @property
    def median(self) -> str:
        """Image name of the Median view."""
        return self.names[self._picks[1]]

    @property
    def hard(self) -> str:
        """Image name of the Hard view."""
        return self.names[self._picks[2]]

    def labels(self) -> dict[int, str]:
        """Position in the lists -> ``"Easy"``/``"Median"``/``"Hard"`` (one view can carry several)."""
        out: dict[int, list[str]] = {}
        for label, pos in zip(("Easy", "Median", "Hard"), self._picks, strict=True):
            out.setdefault(pos, []).append(label)
        return {pos: "/".join(labels) for pos, labels in out.items()}

    def to_json(self) -> dict[str, Any]:
        """JSON-ready summary: the three picks, every view's density and rank, and the settings."""
        ranks = np.empty(len(self.names), dtype=np.int64)
        ranks[self.order] = np.arange(len(self.names))

        def pick(pos: int) -> dict[str, Any]:
            return {
                "name": self.names[pos],
                "index": self.indices[pos],
                "density": float(self.densities[pos]),
            }

        return {
            "protocol": "KDE difficulty: mean scene KDE in each training view's frustum within the radius",
            "data": str(self.data) if self.data is not None else None,
            "dataparser": self.dataparser,
            "radius": float(self.radius),
            "diagonal": float(self.diagonal),
            "settings": dict(self.settings),
            "easy": pick(self._picks[0]),
            "median": pick(self._picks[1]),
            "hard": pick(self._picks[2]),
            "views": [
                {"index": idx, "name": name, "density": float(d), "rank": int(r)}
                for idx, name, d, r in zip(self.indices, self.names, self.densities, ranks, strict=True)
            ],
        }

    def table(self) -> str:
        """A text table of the views sorted by ascending density, with the Easy/Median/Hard rows marked."""
        labels = self.labels()
        width = max(len("view"), *(len(n) for n in self.names))
        where = f" of {self.data}" if self.data is not None else ""
        parser = f" ({self.dataparser})" if self.dataparser else ""
        radius = f"sampling radius {self.radius:.4g} scene units"
        fraction = self.settings.get("radius_fraction")
        if fraction is not None and math.isfinite(self.diagonal):
            radius += f" = {fraction:g} x seed-point diagonal {self.diagonal:.4g}"
        lines = [
            f"KDE difficulty ranking: {len(self.names)} training views{where}{parser}",
            radius,
            "density = mean normalised scene KDE in the view's frustum; rank 0 = emptiest",
            "",
            f"{'rank':>4}  {'index':>5}  {'view':<{width}}  {'density':>9}",
        ]
        for r, pos in enumerate(self.order):
            mark = f"  <- {labels[pos]}" if pos in labels else ""
            name, density = self.names[pos], self.densities[pos]
            lines.append(f"{r:>4}  {self.indices[pos]:>5}  {name:<{width}}  {density:>9.5f}{mark}")
        lines += ["", f"Easy: {self.easy}   Median: {self.median}   Hard: {self.hard}"]
        return "\n".join(lines)

    def save(self, folder: Path) -> tuple[Path, Path]:
        """Write ``view_ranking.json`` and ``view_ranking.png`` into ``folder`` (created); return them."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        json_path = folder / "view_ranking.json"
        json_path.write_text(json.dumps(self.to_json(), indent=2) + "\n", encoding="utf-8")
        return json_path, plot_ranking(self, folder / "view_ranking.png")


def plot_ranking(ranking: ViewRanking, path: Path) -> Path:
    """Bar chart of the view densities in capture (training) order, Easy/Median/Hard highlighted; a PNG.

    Args:
        ranking: the ranking to draw.
        path: the PNG file to write (its folder must exist).

    Returns:
        ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    colours = {"Easy": "tab:green", "Median": "tab:orange", "Hard": "tab:red"}
    labels = ranking.labels()
    n = len(ranking.names)
    x = np.arange(n)
    bar_colours = [colours[labels[i].split("/")[0]] if i in labels else "0.75" for i in range(n)]
    fig, ax = plt.subplots(figsize=(max(6.0, min(16.0, 0.22 * n + 2.0)), 3.6), dpi=120)
    try:
        ax.bar(x, ranking.densities, color=bar_colours, width=0.85)
        for pos, label in sorted(labels.items()):
            ax.annotate(
                f"{label}\n{ranking.names[pos]}",
                (pos, ranking.densities[pos]),
                xytext=(0, 4),
                textcoords="offset points",
                ha="center",
                va="bottom",
                fontsize=7,
                color=colours[label.split("/")[0]],
            )
        ax.set_xlabel("training view (capture order)")
        ax.set_ylabel("mean KDE density in frustum")
        ax.set_xlim(-0.6, n - 0.4)
        top = float(ranking.densities.max()) if n else 1.0
        ax.set_ylim(0.0, (top if top > 0 else 1.0) * 1.3)
        ticks = x if n <= 30 else x[:: math.ceil(n / 30)]
        ax.set_xticks(ticks, [str(ranking.indices[i]) for i in ticks], fontsize=7)
        fraction = ranking.settings.get("radius_fraction")
        radius = f"r = {ranking.radius:.3g}" + (f" ({fraction:g} x diagonal)" if fraction is not None else "")
        title = f"KDE difficulty: {Path(ranking.data).name if ranking.data else 'views'}, {radius}"
        ax.set_title(title, fontsize=9)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return Path(path)


def detect_format(data: Path) -> tuple[Format, Path]:
    """The dataparser for a dataset folder: ``("nerfstudio-data", folder or json)`` or ``("colmap", rel)``
    with ``rel`` the COLMAP reconstruction folder relative to ``data``. StealthNSError otherwise."""
    data = Path(data)
    if not data.exists():
        raise StealthNSError(f"dataset {data} does not exist")
    if data.is_file():
        if data.suffix == ".json":
            return "nerfstudio-data", data
        raise StealthNSError(f"dataset {data} is a file; give the dataset folder (or its transforms.json)")
    if (data / "transforms.json").is_file():
        return "nerfstudio-data", data
    for rel in _COLMAP_DIRS:
        if any((data / rel / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return "colmap", Path(rel)
    if any((data / f"transforms_{s}.json").is_file() for s in ("train", "val", "test")):
        raise StealthNSError(
            f"{data} is a blender-format dataset without a seed point cloud: the KDE difficulty protocol "
            "needs seed points (nerfstudio-data with ply_file_path, or a COLMAP reconstruction)"
        )
    raise StealthNSError(
        f"{data} has no transforms.json (nerfstudio-data) and no COLMAP reconstruction "
        f"({', '.join(r + '/cameras.bin' for r in _COLMAP_DIRS)})"
    )


def _check_seed_points(json_path: Path) -> None:
    """Refuse a transforms.json without a readable ``ply_file_path`` (nerfstudio would fall back to random
    points, or ask an interactive question when a colmap/ folder is present)."""
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise StealthNSError(f"cannot read {json_path}: {err}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise StealthNSError(f"{json_path} is not a nerfstudio transforms.json (no 'frames' list)")
    ply = meta.get("ply_file_path")
    if not ply:
        raise StealthNSError(
            f"{json_path} has no ply_file_path: the KDE difficulty protocol needs the scene's seed points"
        )
    if not (json_path.parent / ply).is_file():
        raise StealthNSError(f"seed point file {json_path.parent / ply} (ply_file_path) does not exist")
    _check_frame_poses(json_path, meta["frames"])


def _check_frame_poses(json_path: Path, frames: list[Any]) -> None:
    """Refuse a frame whose transform_matrix is not a 4x4 matrix of finite numbers, naming it: one NaN
    turns every pose NaN in nerfstudio's orientation step (and the seed points with them)."""
    for i, frame in enumerate(frames):
        name = frame.get("file_path", f"#{i}") if isinstance(frame, dict) else f"#{i}"
        try:
            matrix = np.asarray(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, KeyError, ValueError):
            raise StealthNSError(
                f"{json_path}: frame {i} ({name}) has no transform_matrix of numbers"
            ) from None
        if matrix.shape != (4, 4):
            raise StealthNSError(
                f"{json_path}: the transform_matrix of frame {i} ({name}) is {matrix.shape}, not 4x4"
            )
        if not np.all(np.isfinite(matrix)):
            raise StealthNSError(
                f"{json_path}: the camera pose (transform_matrix) of frame {i} ({name}) is not finite "
                "(NaN or infinity)"
            )


def _load_train_split(data: Path) -> tuple[Any, np.ndarray, str]:
    """Training cameras, seed points ``[P, 3]`` and dataparser name, from nerfstudio's dataparser."""
    fmt, where = detect_format(data)
    if fmt == "nerfstudio-data":
        from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

        _check_seed_points(where if where.suffix == ".json" else where / "transforms.json")
        # downscale_factor=1: poses only, no image is opened (the FOV does not depend on the downscale).
        config: Any = NerfstudioDataParserConfig(data=where, load_3D_points=True, downscale_factor=1)
    else:
        from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig

        # downscale_factor=1 also keeps the parser from offering to downscale images interactively.
        config = ColmapDataParserConfig(data=data, colmap_path=where, load_3D_points=True, downscale_factor=1)
    from nerfstudio.utils.rich_utils import CONSOLE

    quiet = CONSOLE.quiet
    CONSOLE.quiet = True  # the parser's progress notes ("overriding train_indices ...") would bury the table
    try:
        outputs = config.setup().get_dataparser_outputs(split="train")
    except (AssertionError, ValueError, KeyError, IndexError, RuntimeError, OSError) as err:
        raise StealthNSError(f"nerfstudio's {fmt} dataparser cannot read {data}: {err}") from None
    finally:
        CONSOLE.quiet = quiet
    c2w = outputs.cameras.camera_to_worlds.reshape(len(outputs.image_filenames), -1)
    bad = np.flatnonzero(~np.all(np.isfinite(c2w.double().numpy()), axis=1))
    if len(bad):  # a COLMAP model (nerfstudio-data frames are checked before parsing)
        raise StealthNSError(
            f"{data}: the camera pose of {Path(outputs.image_filenames[bad[0]]).name} is not finite "
            f"(NaN or infinity) after nerfstudio's {fmt} dataparser ({len(bad)} such views)"
        )
    points = outputs.metadata.get("points3D_xyz")
    if points is None or len(points) == 0:
        raise StealthNSError(f"{data} has no seed points: the KDE difficulty protocol needs a point cloud")
    return outputs, np.asarray(points, dtype=np.float64).reshape(-1, 3), fmt


def rank_scene_views(
    data: Path,
    radius_fraction: float = DEFAULT_RADIUS_FRACTION,
    grid_resolution: int = DEFAULT_GRID_RESOLUTION,
    voxel_size: float | None = None,
    bandwidth: float = DEFAULT_BANDWIDTH,
    outlier_removal: bool = True,
    n_dirs: int = DEFAULT_N_DIRS,
    n_depths: int = DEFAULT_N_DEPTHS,
) -> ViewRanking:
    """Rank a dataset's training views by the KDE difficulty protocol (see the module docstring).

    Args:
        data: a nerfstudio-data folder (``transforms.json`` with ``ply_file_path``; or the json itself) or a
            COLMAP folder (``colmap/sparse/0``, ``sparse/0`` or ``sparse`` with points3D).
        radius_fraction: sampling radius as a fraction of the seed points' bounding-box diagonal.
        grid_resolution: KDE voxels along the longest side of the bounding box (if ``voxel_size`` is None).
        voxel_size: KDE voxel edge in scene units (overrides ``grid_resolution``).
        bandwidth: KDE bandwidth in voxels.
        outlier_removal: drop statistical outliers (20 neighbours, 2 std) before the KDE, as the attack does.
        n_dirs, n_depths: frustum quadrature size (:func:`frustum_samples`).

    Returns:
        The :class:`ViewRanking`; ``.easy``, ``.median``, ``.hard`` are image names.

    Raises:
        StealthNSError: missing or unrecognised dataset, no seed points, bad parameters.
    """
    if not (math.isfinite(radius_fraction) and radius_fraction > 0):
        raise StealthNSError(f"radius fraction must be a positive number, got {radius_fraction!r}")
    if isinstance(grid_resolution, bool) or int(grid_resolution) != grid_resolution or grid_resolution < 1:
        raise StealthNSError(f"grid resolution must be a positive integer, got {grid_resolution!r}")
    if voxel_size is not None and not (math.isfinite(voxel_size) and voxel_size > 0):
        raise StealthNSError(f"voxel size must be a positive number, got {voxel_size!r}")
    if not (math.isfinite(bandwidth) and bandwidth >= 0):
        raise StealthNSError(f"bandwidth must be a non-negative number (voxels), got {bandwidth!r}")
    if min(n_dirs, n_depths) < 1:
        raise StealthNSError(f"n_dirs and n_depths must be at least 1, got {n_dirs} and {n_depths}")

    data = Path(data).expanduser()
    outputs, points, fmt = _load_train_split(data)
    points = points[np.all(np.isfinite(points), axis=1)]
    if outlier_removal:
        from stealth_ns.attack.injection import remove_outliers

        points = points[remove_outliers(points)]
    diagonal = bbox_diagonal(points) if len(points) else 0.0
    if not diagonal > 0:
        raise StealthNSError(f"the seed points of {data} all coincide: no scene extent to measure")
    try:
        kde = scene_kde(points, grid_resolution=grid_resolution, voxel_size=voxel_size, bandwidth=bandwidth)
    except ValueError as err:
        raise StealthNSError(f"cannot build the scene KDE: {err}") from None

    from nerfstudio.cameras.cameras import CameraType

    cams = outputs.cameras
    kinds = {int(k) for k in cams.camera_type.reshape(-1).tolist()}
    if kinds != {CameraType.PERSPECTIVE.value}:
        raise StealthNSError(f"{data}: only perspective (pinhole) cameras are supported by this protocol")
    radius = radius_fraction * diagonal
    intr = [
        getattr(cams, k).reshape(-1).double().numpy() for k in ("fx", "fy", "cx", "cy", "width", "height")
    ]
    densities = view_densities(
        kde, cams.camera_to_worlds.double().numpy(), *intr, radius=radius, n_dirs=n_dirs, n_depths=n_depths
    )
    names = [Path(p).name for p in outputs.image_filenames]
    settings = {
        "radius_fraction": radius_fraction,
        "grid_resolution": grid_resolution,
        "voxel_size": voxel_size,
        "kde_voxel_size": kde.voxel_size,
        "kde_shape": list(kde.shape),
        "bandwidth": bandwidth,
        "outlier_removal": outlier_removal,
        "seed_points": len(points),
        "n_dirs": n_dirs,
        "n_depths": n_depths,
    }
    return ViewRanking(
        names=names,
        indices=list(range(len(names))),
        densities=densities,
        radius=radius,
        diagonal=diagonal,
        data=data,
        dataparser=fmt,
        settings=settings,
    )


@dataclass
class RankViews:
    """Rank training views by scene density in their frustum (the paper's Easy/Median/Hard protocol)."""

    data: Path
    """Dataset folder: nerfstudio-data (transforms.json with ply_file_path) or COLMAP (sparse/0, points3D)."""
    output: Path | None = None
    """Folder for view_ranking.json and view_ranking.png (created); default: print the table only."""
    radius_fraction: float = DEFAULT_RADIUS_FRACTION
    """Sampling radius as a fraction of the seed point cloud's bounding-box diagonal (paper: 10%)."""
    grid_resolution: int = DEFAULT_GRID_RESOLUTION
    """KDE voxels along the longest side of the point cloud's bounding box (the attack's default)."""
    voxel_size: float | None = None
    """KDE voxel edge in scene units; overrides --grid-resolution."""
    bandwidth: float = DEFAULT_BANDWIDTH
    """KDE bandwidth h in voxels (the attack's default)."""
    outlier_removal: bool = True
    """Drop statistical outliers (20 neighbours, 2 std) from the seed points first, as the attack does."""
    n_dirs: int = DEFAULT_N_DIRS
    """Frustum samples: directions across the image width (rows follow the aspect ratio)."""
    n_depths: int = DEFAULT_N_DEPTHS
    """Frustum samples: depths per direction, in (0, radius]."""

    def main(self) -> None:
        if self.output is not None and self.output.exists() and not self.output.is_dir():
            raise StealthNSError(f"--output {self.output} exists and is not a folder")
        ranking = rank_scene_views(
            self.data,
            radius_fraction=self.radius_fraction,
            grid_resolution=self.grid_resolution,
            voxel_size=self.voxel_size,
            bandwidth=self.bandwidth,
            outlier_removal=self.outlier_removal,
            n_dirs=self.n_dirs,
            n_depths=self.n_depths,
        )
        print(ranking.table())
        if self.output is not None:
            try:
                json_path, png_path = ranking.save(self.output)
            except OSError as err:
                raise StealthNSError(f"cannot write to {self.output}: {err}") from None
            print(f"Wrote {json_path} and {png_path}")
