"""The "StealthAttack" panel of nerfstudio's viewer (viser): inspect poisoned vs innocent views.

One object, :class:`StealthAttackPanel`, is a public attribute of the pipeline (``pipeline.stealth_attack``).
nerfstudio's viewer discovers it twice, during ``ns-train`` (viewer on) and ``ns-viewer --load-config``:

* as a ``ViewerElement``: ``install(server)`` builds the panel's GUI inside the "Custom Elements" folder;
* as a ``ViewerControl``: ``_setup(viewer)`` hands it the viewer (viser server, train lock, run folder).

The panel offers a view dropdown (jump to any poisoned, innocent-training or held-out view, with the view's
role), a poison-Gaussian render filter (shown / hidden / only poison, applied to the viewer's renders only),
3D overlays (poison centres, the thresholded KDE density as voxels coloured by density, the poisoned cameras'
frusta) and, while the camera sits on a poisoned view, that view's masked PSNR against its illusion target.

The pure functions below (view lists, viser <-> nerfstudio poses, view matching, overlay point clouds) are
what the unit tests exercise; the glue keeps everything heavy out of the viewer's render path: targets,
masks and voxel clouds are cached, the PSNR render runs in a worker thread and is cached per
(view, filter, step).

Conventions: nerfstudio camera-to-world matrices are ``[3, 4]`` (or ``[N, 3, 4]``) in OpenGL axes (camera
looks down ``-Z``, ``+Y`` up) in nerfstudio's rescaled scene units. viser cameras follow OpenCV axes (look
down ``+Z``, ``-Y`` up) and the viewer's viser scene is nerfstudio's scaled by
``VISER_NERFSTUDIO_SCALE_RATIO`` (10). Quaternions are ``wxyz``.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
import viser
import viser.transforms as vtf
from nerfstudio.viewer.viewer_elements import ViewerControl, ViewerElement

from stealth_ns.attack.density import DensityGrid, load_density_npz
from stealth_ns.metrics import masked_psnr

if TYPE_CHECKING:
    from nerfstudio.viewer.viewer import Viewer

    from stealth_ns.pipeline import StealthPipeline

#: World scale between nerfstudio and the viewer's viser scene (``nerfstudio.viewer.viewer``'s constant).
VISER_SCALE = 10.0

Role = Literal["poisoned", "innocent", "held-out"]

ROLE_TEXT: dict[str, str] = {
    "poisoned": "poisoned training view: trained on the illusion composite, the illusion should appear here",
    "innocent": "innocent training view: trained on its clean image, the illusion should not be visible",
    "held-out": "held-out view: never trained on, the illusion should not be visible",
}

#: Dropdown label -> ``StealthSplatModel.render_filter``.
FILTER_OPTIONS: dict[str, str] = {
    "shown": "all",
    "hidden": "hide_poison",
    "only poison": "only_poison",
}

NO_VIEW = "(free camera)"
POISON_COLOR = (255, 0, 255)
#: Poison-centre point size in viser units (0.004 scene units; nerfstudio scales cameras to ~unit distance).
POISON_POINT_SIZE = 0.04
POISONED_FRUSTUM_COLOR = (255, 48, 48)


# ----------------------------------------------------------------------------------------------- view lists
@dataclass(frozen=True)
class ViewEntry:
    """One entry of the view dropdown.

    Attributes:
        label: the dropdown option (unique), e.g. ``"poisoned: frame_00009.png"``.
        role: ``"poisoned"``, ``"innocent"`` (training) or ``"held-out"``.
        split: ``"train"`` or ``"eval"``: which dataset ``index`` refers to.
        index: index of the camera in that dataset.
        name: the image name shown to the user.
    """

    label: str
    role: Role
    split: Literal["train", "eval"]
    index: int
    name: str


def display_names(paths: Sequence[str | Path], base: str | Path | None = None) -> list[str]:
    """Short, unique names for image paths: relative to ``base`` when inside it, else the file name.

    Args:
        paths: image paths (absolute or relative).
        base: dataset folder; a file (e.g. ``transforms.json``) means its folder.

    Returns:
        One name per path, e.g. ``"images/frame_00009.png"``.
    """
    base_dir = None
    if base is not None:
        base_dir = Path(base)
        base_dir = base_dir.parent if base_dir.suffix else base_dir
    names: list[str] = []
    for p in paths:
        path = Path(p)
        if base_dir is not None and path.is_relative_to(base_dir):
            names.append(str(path.relative_to(base_dir)))
        else:
            names.append(path.name)
    if len(set(names)) < len(names):  # clashes: fall back to longer tails
        names = [str(p) for p in paths]
    return names


def build_view_entries(
    train_names: Sequence[str], eval_names: Sequence[str], poisoned: Sequence[int]
) -> list[ViewEntry]:
    """All views for the dropdown: the poisoned ones first (in attack order), then the innocent training
    views, then the held-out views (each in dataset order).

    Args:
        train_names: training image names, by training index.
        eval_names: held-out image names, by eval index.
        poisoned: training indices of the poisoned views.

    Returns:
        The entries; labels are ``"<role>: <name>"`` (unique).

    Raises:
        ValueError: a poisoned index is out of range.
    """
    n = len(train_names)
    bad = [i for i in poisoned if not 0 <= int(i) < n]
    if bad:
        raise ValueError(f"poisoned view indices {bad} are out of range: {n} training views")
    entries = [
        ViewEntry(f"poisoned: {train_names[i]}", "poisoned", "train", int(i), train_names[i])
        for i in poisoned
    ]
    chosen = {int(i) for i in poisoned}
    entries += [
        ViewEntry(f"innocent: {nm}", "innocent", "train", i, nm)
        for i, nm in enumerate(train_names)
        if i not in chosen
    ]
    entries += [ViewEntry(f"held-out: {nm}", "held-out", "eval", i, nm) for i, nm in enumerate(eval_names)]
    return entries


# ----------------------------------------------------------------------------------------------- poses
def viser_pose_from_c2w(c2w: np.ndarray, scale: float = VISER_SCALE) -> tuple[np.ndarray, np.ndarray]:
    """nerfstudio camera-to-world (OpenGL) -> viser camera orientation and position (OpenCV, scaled).

    Args:
        c2w: ``[3, 4]`` or ``[4, 4]`` camera-to-world, OpenGL axes, scene units.
        scale: viser units per scene unit.

    Returns:
        ``wxyz`` ``[4]`` (camera -> world rotation, OpenCV camera axes) and ``position`` ``[3]`` (viser).
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    rot = vtf.SO3.from_matrix(c2w[:3, :3]) @ vtf.SO3.from_x_radians(np.pi)
    return np.asarray(rot.wxyz), c2w[:3, 3] * scale


def c2w_from_viser_pose(
    wxyz: Sequence[float], position: Sequence[float], scale: float = VISER_SCALE
) -> np.ndarray:
    """Inverse of :func:`viser_pose_from_c2w`, exactly as nerfstudio's viewer builds its render camera.

    Args:
        wxyz: ``[4]`` viser camera orientation.
        position: ``[3]`` viser camera position (viser units).
        scale: viser units per scene unit.

    Returns:
        ``[3, 4]`` camera-to-world, OpenGL axes, scene units.
    """
    rot = (vtf.SO3(wxyz=np.asarray(wxyz, dtype=np.float64)) @ vtf.SO3.from_x_radians(np.pi)).as_matrix()
    return np.concatenate([rot, np.asarray(position, dtype=np.float64)[:, None] / scale], axis=1)


def vertical_fov(fy: float, height: float) -> float:
    """Vertical field of view in radians of a pinhole camera with focal ``fy`` and ``height`` (pixels)."""
    return 2.0 * math.atan(0.5 * float(height) / float(fy))


@dataclass(frozen=True)
class CameraJump:
    """Where to put a viser client camera to see exactly a dataset view.

    Attributes:
        wxyz: ``[4]`` orientation (OpenCV camera axes).
        position: ``[3]`` viser units.
        look_at: ``[3]`` orbit centre in viser units, on the optical axis.
        fov: vertical field of view, radians (the viewer renders with ``fy = (H / 2) / tan(fov / 2)`` and a
            centred principal point, so the jump reproduces the view's vertical extent).
    """

    wxyz: np.ndarray
    position: np.ndarray
    look_at: np.ndarray
    fov: float


def camera_jump(
    c2w: np.ndarray,
    fy: float,
    height: float,
    center: Sequence[float] = (0.0, 0.0, 0.0),
    scale: float = VISER_SCALE,
) -> CameraJump:
    """The viser camera state that shows a dataset view.

    Args:
        c2w: ``[3, 4]`` camera-to-world of the view (OpenGL axes, scene units).
        fy: its vertical focal length, pixels.
        height: its image height, pixels.
        center: ``[3]`` scene point (scene units) to orbit around afterwards; the look-at point is its
            projection on the optical axis (at least 0.1 scene units in front of the camera).
        scale: viser units per scene unit.

    Returns:
        The :class:`CameraJump`.
    """
    wxyz, position = viser_pose_from_c2w(c2w, scale)
    c2w = np.asarray(c2w, dtype=np.float64)
    forward = -c2w[:3, 2] / np.linalg.norm(c2w[:3, 2])
    depth = max(float((np.asarray(center, dtype=np.float64) - c2w[:3, 3]) @ forward), 0.1)
    return CameraJump(
        wxyz=wxyz, position=position, look_at=position + forward * depth * scale, fov=vertical_fov(fy, height)
    )


def apply_camera_jump(camera: viser.CameraHandle, jump: CameraJump) -> None:
    """Move a client's camera (viser's orbit camera keeps ``look_at`` and ``up_direction`` consistent)."""
    with camera.client.atomic():
        camera.fov = jump.fov
        camera.position = jump.position
        camera.wxyz = jump.wxyz  # also sets up_direction to the camera's up and a look-at on the axis
        camera.look_at = jump.look_at  # same direction, orbit distance to the scene centre


def match_view(
    c2w: np.ndarray, candidates: np.ndarray, pos_tol: float = 0.01, rot_tol_deg: float = 1.0
) -> int | None:
    """The candidate pose the camera sits on, if any.

    Args:
        c2w: ``[3, 4]`` query camera-to-world (scene units).
        candidates: ``[N, 3, 4]`` (or ``[N, 4, 4]``) camera-to-worlds.
        pos_tol: largest centre distance, scene units.
        rot_tol_deg: largest relative rotation angle, degrees.

    Returns:
        Index of the nearest candidate (by centre distance) within both tolerances, else None.
    """
    cands = np.asarray(candidates, dtype=np.float64).reshape(-1, *np.shape(candidates)[-2:])[:, :3, :4]
    if cands.shape[0] == 0:
        return None
    q = np.asarray(c2w, dtype=np.float64)[:3, :4]
    dist = np.linalg.norm(cands[:, :, 3] - q[:, 3], axis=1)
    trace = np.einsum("nij,ij->n", cands[:, :, :3], q[:, :3])  # trace(R_n^T R_q)
    angle = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
    ok = (dist <= pos_tol) & (angle <= rot_tol_deg)
    if not ok.any():
        return None
    return int(np.flatnonzero(ok)[np.argmin(dist[ok])])


# ----------------------------------------------------------------------------------------------- overlays
def poison_centres(means: torch.Tensor | np.ndarray, tags: torch.Tensor | np.ndarray) -> np.ndarray:
    """Centres of the poison Gaussians.

    Args:
        means: ``[N, 3]`` Gaussian centres, scene units.
        tags: ``[N]`` poison tag (``> 0.5`` = poison) or bool mask.

    Returns:
        ``[P, 3]`` float32 centres of the poison Gaussians, scene units.
    """
    m = means.detach().cpu().numpy() if isinstance(means, torch.Tensor) else np.asarray(means)
    t = tags.detach().cpu().numpy() if isinstance(tags, torch.Tensor) else np.asarray(tags)
    return m[t.astype(np.float32) > 0.5].astype(np.float32).reshape(-1, 3)


def density_colors(values: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """Colour ``[M]`` densities with matplotlib's ``turbo`` map -> ``[M, 3]`` uint8 (vmin blue, vmax red)."""
    import matplotlib

    span = max(float(vmax) - float(vmin), 1e-12)
    t = np.clip((np.asarray(values, dtype=np.float64) - vmin) / span, 0.0, 1.0)
    rgba = matplotlib.colormaps["turbo"](0.1 + 0.9 * t)  # turbo's first tenth is too dark to read
    return (rgba[:, :3] * 255.0).round().astype(np.uint8)


@dataclass(frozen=True)
class VoxelCloud:
    """Thresholded KDE voxels as a point cloud.

    Attributes:
        points: ``[M, 3]`` float32 voxel centres, scene units.
        colors: ``[M, 3]`` uint8 (turbo colour map from the threshold to the maximum).
        n_above: number of voxels at or above the threshold (``M`` is smaller when subsampled).
        voxel_size: voxel edge, scene units.
    """

    points: np.ndarray
    colors: np.ndarray
    n_above: int
    voxel_size: float


def kde_voxel_cloud(
    grid: DensityGrid,
    kde: np.ndarray | None = None,
    threshold: float = 0.5,
    max_points: int = 50_000,
    seed: int = 0,
) -> VoxelCloud:
    """Voxels whose KDE is at least ``threshold`` times its maximum, coloured by KDE.

    Args:
        grid: the density grid's geometry (origin, voxel size) and, when ``kde`` is None, its values.
        kde: ``[X, Y, Z]`` KDE values on the grid (the ``kde`` extra of ``density_grid.npz``).
        threshold: fraction of the maximum, in ``[0, 1]``.
        max_points: at most this many voxels are returned (a deterministic uniform subsample).
        seed: seed of the subsample.

    Returns:
        The :class:`VoxelCloud` (empty when the KDE is zero everywhere).
    """
    values = grid.values if kde is None else np.asarray(kde, dtype=np.float32)
    if values.shape != grid.shape:
        raise ValueError(f"KDE of shape {values.shape} does not match the grid {grid.shape}")
    vmax = float(values.max()) if values.size else 0.0
    if not vmax > 0.0:
        return VoxelCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), 0, grid.voxel_size)
    cut = float(np.clip(threshold, 0.0, 1.0)) * vmax
    idx = np.argwhere(values >= cut)
    n_above = int(idx.shape[0])
    if n_above > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(n_above, size=max_points, replace=False))
        idx = idx[keep]
    points = grid.origin + (idx + 0.5) * grid.voxel_size
    colors = density_colors(values[tuple(idx.T)], cut, vmax)
    return VoxelCloud(points.astype(np.float32), colors, n_above, grid.voxel_size)


@dataclass(frozen=True)
class FrustumSpec:
    """Arguments of ``viser``'s ``add_camera_frustum`` for a dataset camera (viser units)."""

    fov: float
    aspect: float
    wxyz: np.ndarray
    position: np.ndarray


def frustum_spec(
    c2w: np.ndarray, fy: float, width: float, height: float, scale: float = VISER_SCALE
) -> FrustumSpec:
    """Frustum of a pinhole camera: vertical fov (radians), aspect ``W / H`` and the viser pose."""
    wxyz, position = viser_pose_from_c2w(c2w, scale)
    return FrustumSpec(vertical_fov(fy, height), float(width) / float(height), wxyz, position)


# ----------------------------------------------------------------------------------------------- attack data
class PanelError(Exception):
    """Something the panel cannot show; its message is displayed in the panel."""


@dataclass(frozen=True)
class PoisonedViewData:
    """A poisoned view's illusion target.

    Attributes:
        index: training-view index.
        name: image name.
        target: ``[H, W, 3]`` float32 in ``[0, 1]``, the illusion composite I_ILL.
        mask: ``[H, W]`` bool, the illusion's pixels.
    """

    index: int
    name: str
    target: np.ndarray
    mask: np.ndarray


def _read_png(path: Path) -> np.ndarray:
    import imageio.v3 as iio

    arr = np.asarray(iio.imread(path))
    return arr.astype(np.float32) / (65535.0 if arr.dtype == np.uint16 else 255.0)


def load_attack_views(attack_dir: Path) -> list[PoisonedViewData]:
    """Poisoned views and their targets/masks from a run's ``attack/`` folder.

    Raises:
        PanelError: no ``attack.json``, an unreadable one, or missing target/mask images.
    """
    record_path = attack_dir / "attack.json"
    if not record_path.exists():
        raise PanelError(f"no attack record at {record_path} (a run trained without the attack?)")
    try:
        record = json.loads(record_path.read_text())
        listed = [(int(v["index"]), str(v["name"])) for v in record["poisoned_views"]]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise PanelError(f"cannot read {record_path}: {type(err).__name__}: {err}") from err
    views = []
    for index, name in listed:
        stem = attack_dir / f"view{index:04d}"
        try:
            target = _read_png(Path(f"{stem}_target.png"))[..., :3]
            mask = _read_png(Path(f"{stem}_mask.png"))
        except OSError as err:
            raise PanelError(f"missing target/mask image of poisoned view {name}: {err}") from err
        mask = (mask if mask.ndim == 2 else mask[..., 0]) > 0.5
        views.append(PoisonedViewData(index, name, target, mask))
    return views


def views_from_pipeline(pipeline: StealthPipeline) -> list[PoisonedViewData]:
    """Poisoned views the pipeline resolved itself (training and ``ns-viewer``'s test mode)."""
    return [
        PoisonedViewData(
            v.index,
            v.name,
            v.target.detach().cpu().float().numpy(),
            v.mask.detach().cpu().numpy().astype(bool),
        )
        for v in getattr(pipeline, "poison_views", [])
    ]


# ----------------------------------------------------------------------------------------------- the panel
class StealthAttackPanel(ViewerElement[bool], ViewerControl):
    """The "StealthAttack" viewer panel (see the module docstring). Create one per pipeline; it does
    nothing until a viewer installs it."""

    def __init__(self, pipeline: StealthPipeline) -> None:
        super().__init__(name="StealthAttack")
        self._pipeline = pipeline
        self.render_filter: str = "all"
        """The viewer's ``render_filter`` (``FILTER_OPTIONS`` values), applied to viewer renders only."""
        self.entries: list[ViewEntry] = []
        self.poisoned: list[PoisonedViewData] = []
        self.problems: list[str] = []
        self._poses: dict[tuple[str, int], tuple[np.ndarray, float, float, float]] = {}
        self._entry_c2w = np.zeros((0, 3, 4))
        self._viewer: Viewer | None = None
        self._server: viser.ViserServer | None = None
        self._gui: dict[str, Any] = {}
        self._nodes: dict[str, Any] = {}
        self._overlay_notes: list[str] = []
        self._psnr_cache: dict[tuple[int, str, int], float] = {}
        self._psnr_busy = False
        self._psnr_lock = threading.Lock()
        self._executor: ThreadPoolExecutor | None = None
        self._voxel_cache: dict[tuple[str, float, float], VoxelCloud] = {}
        self._last_camera: viser.CameraHandle | None = None
        self._current_view: ViewEntry | None = None
        self._frusta_state: tuple | None = None
        self._scene_lock = threading.RLock()  # overlays are touched from viser's GUI and message threads

    # ------------------------------------------------------------------ nerfstudio hooks
    def _create_gui_handle(self, viser_server: viser.ViserServer) -> None:
        gui = viser_server.gui
        self.gui_handle = gui.add_folder("StealthAttack")
        with self.gui_handle:
            g = self._gui
            g["status"] = gui.add_markdown("Loading the attack's views...")
            g["view"] = gui.add_dropdown(
                "Jump to view", [NO_VIEW], NO_VIEW, hint="Poisoned, innocent training and held-out views"
            )
            g["jump"] = gui.add_button("Jump again", hint="Put the camera back onto the selected view")
            g["role"] = gui.add_markdown(" ")
            g["filter"] = gui.add_dropdown(
                "Poison Gaussians",
                list(FILTER_OPTIONS),
                "shown",
                hint="Render with them shown, hidden or alone",
            )
            g["readout"] = gui.add_markdown("Camera: free")
            g["centres"] = gui.add_checkbox(
                "Poison centres", False, hint="Centres of the poison Gaussians (magenta)"
            )
            g["kde"] = gui.add_checkbox(
                "KDE density", False, hint="Voxels above the threshold, coloured by KDE"
            )
            g["kde_threshold"] = gui.add_slider(
                "KDE threshold", 0.05, 1.0, 0.05, 0.8, hint="Fraction of the KDE's maximum"
            )
            g["frusta"] = gui.add_checkbox(
                "Poisoned cameras", True, hint="The poisoned views' frusta, in red"
            )
            g["refresh"] = gui.add_button("Refresh overlays", hint="Re-read the poison centres and the KDE")

    def install(self, viser_server: viser.ViserServer) -> None:
        """Build the GUI (the viewer calls this inside its "Custom Elements" folder)."""
        self._server = viser_server
        self._create_gui_handle(viser_server)
        g = self._gui
        g["view"].on_update(lambda _: self.jump_to_selected())
        g["jump"].on_click(lambda _: self.jump_to_selected())
        g["filter"].on_update(lambda _: self.set_render_filter(FILTER_OPTIONS.get(g["filter"].value, "all")))
        for key in ("centres", "kde", "kde_threshold", "frusta"):
            g[key].on_update(lambda _: self.refresh_overlays())
        g["refresh"].on_click(lambda _: self.refresh_overlays(reload=True))

    def _setup(self, viewer: Viewer) -> None:
        """The viewer exists (end of its constructor): read the views, wrap its renderer, draw overlays."""
        super()._setup(viewer)
        self._viewer = viewer
        self._server = viewer.viser_server
        self.load_views()
        self._wrap_renderer()
        if self._gui:
            self._gui["view"].options = [NO_VIEW] + [e.label for e in self.entries]
            self.refresh_overlays()
        self._server.on_client_connect(lambda client: client.camera.on_update(self.update_readout))
        for client in self._server.get_clients().values():
            client.camera.on_update(self.update_readout)

    # ------------------------------------------------------------------ data
    @property
    def run_dir(self) -> Path | None:
        """The run's folder (that of ``config.yml``), known once a viewer is set up."""
        return None if self._viewer is None else Path(self._viewer.log_filename).parent

    @property
    def attack_dir(self) -> Path | None:
        """``<run>/attack``: the pipeline's while training, else next to ``config.yml``."""
        pipeline_dir = getattr(self._pipeline, "attack_dir", None)
        if pipeline_dir is not None:
            return Path(pipeline_dir)
        return None if self.run_dir is None else self.run_dir / "attack"

    def load_views(self) -> None:
        """View list, camera poses and poisoned targets/masks: read once, then cached.

        Poisoned views come from the pipeline when it resolved them (``ns-train``, ``ns-viewer``), else
        from ``<run>/attack/``; problems are collected in ``problems`` and shown in the panel.
        """
        self.problems = []
        dm = self._pipeline.datamanager
        base = getattr(getattr(dm.config, "dataparser", None), "data", None)
        datasets = {"train": getattr(dm, "train_dataset", None), "eval": getattr(dm, "eval_dataset", None)}
        names = {
            split: ([] if ds is None else display_names(ds.image_filenames, base))
            for split, ds in datasets.items()
        }
        self.poisoned = views_from_pipeline(self._pipeline)
        if not self.poisoned and self.attack_dir is not None:
            try:
                self.poisoned = load_attack_views(self.attack_dir)
            except PanelError as err:
                self.problems.append(str(err))
        valid = [v for v in self.poisoned if 0 <= v.index < len(names["train"])]
        if len(valid) < len(self.poisoned):
            self.problems.append("some poisoned views are not among this dataset's training views")
        self.poisoned = valid
        self.entries = build_view_entries(names["train"], names["eval"], [v.index for v in self.poisoned])
        for split, ds in datasets.items():
            if ds is None:
                continue
            cams = ds.cameras
            c2ws = cams.camera_to_worlds.detach().cpu().double().numpy()
            for i in range(len(cams)):
                self._poses[(split, i)] = (
                    c2ws[i, :3, :4],
                    float(cams.fy[i]),
                    float(cams.width[i]),
                    float(cams.height[i]),
                )
        poses = [self._poses[(e.split, e.index)][0] for e in self.entries]
        self._entry_c2w = np.stack(poses) if poses else np.zeros((0, 3, 4))

    def entry(self, label: str) -> ViewEntry | None:
        """The view with this dropdown label, if any."""
        return next((e for e in self.entries if e.label == label), None)

    def poisoned_data(self, index: int) -> PoisonedViewData | None:
        """Target and mask of poisoned training view ``index``."""
        return next((v for v in self.poisoned if v.index == index), None)

    def jump_for(self, entry: ViewEntry) -> CameraJump:
        """The camera jump onto a view."""
        c2w, fy, _, height = self._poses[(entry.split, entry.index)]
        return camera_jump(c2w, fy, height)

    def status_text(self) -> str:
        """Markdown of the panel's status line(s)."""
        model = self._pipeline.model
        lines = []
        if self.poisoned:
            names = ", ".join(f"`{v.name}`" for v in self.poisoned)
            n_poison = int(model.poison_mask.sum()) if hasattr(model, "poison_mask") else 0
            lines.append(f"Poisoned: {names}  \n{n_poison} poison Gaussians of {model.num_points}")
        elif not self.problems:
            lines.append("This run has no poisoned views (trained without the attack).")
        lines += [f"**{p}**" for p in self.problems]
        if self._overlay_notes:
            lines.append(", ".join(self._overlay_notes))
        return "  \n".join(lines)

    # ------------------------------------------------------------------ actions
    def _set_text(self, key: str, content: str) -> None:
        handle = self._gui.get(key)
        if handle is not None and handle.content != content:
            handle.content = content

    def _rerender(self) -> None:
        self.cb_hook(self)  # the viewer rewires cb_hook to "take the train lock, then re-render"

    def jump_to_selected(self) -> None:
        """Show the selected view's role and move every client's camera onto it."""
        entry = self.entry(self._gui["view"].value)
        if entry is None:
            self._set_text("role", " ")
            return
        self._set_text("role", f"`{entry.name}`: {ROLE_TEXT[entry.role]}")
        self._set_text("status", self.status_text())  # the poison count changes while training
        if self._server is None:
            return
        jump = self.jump_for(entry)
        if self._viewer is not None and entry.split == "train":
            self._viewer.current_camera_idx = entry.index
        for client in self._server.get_clients().values():
            apply_camera_jump(client.camera, jump)

    def set_render_filter(self, render_filter: str) -> None:
        """Filter the viewer's renders (``"all"``, ``"hide_poison"``, ``"only_poison"``) and re-render."""
        if render_filter not in FILTER_OPTIONS.values():
            raise ValueError(f"unknown render filter {render_filter!r}")
        self.render_filter = render_filter
        self._rerender()
        if self._last_camera is not None:
            self.update_readout(self._last_camera)

    # ------------------------------------------------------------------ PSNR read-out
    def update_readout(self, camera: viser.CameraHandle) -> None:
        """A camera moved (viser's message thread, so only cheap work here): which view is it on and,
        for a poisoned one, its masked PSNR (cached; computed in a worker thread)."""
        self._last_camera = camera
        if not self._gui or not self.entries:
            return
        hit = match_view(c2w_from_viser_pose(camera.wxyz, camera.position), self._entry_c2w)
        entry = None if hit is None else self.entries[hit]
        self._current_view = entry
        self._sync_frusta()
        if entry is None:
            self._set_text("readout", "Camera: free")
            return
        if entry.role != "poisoned":
            self._set_text("readout", f"Camera on {entry.role} view `{entry.name}`")
            return
        key = (entry.index, self.render_filter, int(getattr(self._viewer, "step", 0)))
        if key in self._psnr_cache:
            self._set_text("readout", self._psnr_text(entry, key))
            return
        self._set_text("readout", f"Camera on **poisoned** view `{entry.name}`  \nmasked PSNR: computing...")
        with self._psnr_lock:
            if self._psnr_busy:
                return
            self._psnr_busy = True
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="stealth-panel")
        self._executor.submit(self._compute_psnr, entry, key)

    def _psnr_text(self, entry: ViewEntry, key: tuple[int, str, int]) -> str:
        shown = {"all": "poison shown", "hide_poison": "poison hidden", "only_poison": "only poison"}[key[1]]
        return (
            f"Camera on **poisoned** view `{entry.name}`  \n"
            f"masked PSNR vs illusion: **{self._psnr_cache[key]:.2f} dB** ({shown}, step {key[2]})"
        )

    def _compute_psnr(self, entry: ViewEntry, key: tuple[int, str, int]) -> None:
        try:
            psnr = self.masked_psnr(entry.index, key[1])
            if len(self._psnr_cache) > 256:  # a long training session: old steps are of no use
                self._psnr_cache.clear()
            self._psnr_cache[key] = psnr
            self._set_text("status", self.status_text())
        except Exception as err:  # noqa: BLE001 - shown in the panel; never kills the viewer
            self._set_text("readout", f"masked PSNR failed: {type(err).__name__}: {err}")
            return
        finally:
            with self._psnr_lock:
                self._psnr_busy = False
        if self._last_camera is not None:
            self.update_readout(self._last_camera)  # shows it, or starts the next one if things moved on

    @torch.no_grad()
    def masked_psnr(self, index: int, render_filter: str = "all") -> float:
        """Masked PSNR (dB) of poisoned view ``index`` rendered at its own resolution against its target."""
        data = self.poisoned_data(index)
        if data is None:
            raise PanelError(f"view {index} is not poisoned")
        model = self._pipeline.model
        with self._train_lock():
            camera = self._pipeline.datamanager.train_dataset.cameras[index : index + 1].to(model.device)
            was_training = model.training
            model.eval()
            try:
                with model.filtered(render_filter):
                    rgb = model.get_outputs(camera)["rgb"].float().cpu()
            finally:
                model.train(was_training)
        return masked_psnr(rgb, data.target, data.mask)

    def _train_lock(self) -> Any:
        lock = getattr(self._viewer, "train_lock", None)
        return lock if lock is not None else contextlib.nullcontext()

    # ------------------------------------------------------------------ rendering
    def _wrap_renderer(self) -> None:
        """Apply the panel's filter to the viewer's own renders (its render threads) only: training,
        evaluation and the PSNR read-out keep the model's ``render_filter``."""
        from nerfstudio.viewer.render_state_machine import RenderStateMachine

        model = self._pipeline.model
        if not hasattr(model, "render_filter") or getattr(model, "_stealth_panel_wrapped", False):
            return
        original = model.get_outputs_for_camera
        panel = self

        def get_outputs_for_camera(camera: Any, obb_box: Any = None) -> dict[str, Any]:
            if panel.render_filter == "all" or not isinstance(threading.current_thread(), RenderStateMachine):
                return original(camera, obb_box=obb_box)
            with model.filtered(panel.render_filter):
                return original(camera, obb_box=obb_box)

        object.__setattr__(model, "get_outputs_for_camera", get_outputs_for_camera)
        object.__setattr__(model, "_stealth_panel_wrapped", True)

    # ------------------------------------------------------------------ overlays
    def _set_node(self, name: str, make: Callable[[], Any] | None) -> None:
        """Add/replace (``make``) or remove (None) a scene node of ours."""
        old = self._nodes.pop(name, None)
        if make is None:
            if old is not None:
                old.remove()
            return
        self._nodes[name] = make()  # viser replaces a node of the same name

    def refresh_overlays(self, reload: bool = False) -> None:
        """(Re)draw the 3D overlays the checkboxes ask for and remove the others."""
        if self._server is None or not self._gui:
            return
        centres = None
        if self._gui["centres"].value:
            model = self._pipeline.model
            with self._train_lock():  # before the scene lock: training may hold it for a whole step
                mask = model.poison_mask if hasattr(model, "poison_mask") else torch.zeros(model.num_points)
                centres = poison_centres(model.means, mask)
        with self._scene_lock:
            self._refresh_overlays_locked(reload, centres)

    def _refresh_overlays_locked(self, reload: bool, centres: np.ndarray | None) -> None:
        assert self._server is not None
        if reload:
            self._voxel_cache.clear()
        scene = self._server.scene
        g = self._gui
        notes: list[str] = []
        if centres is not None:
            self._set_node(
                CENTRES_NODE,
                lambda: scene.add_point_cloud(
                    CENTRES_NODE,
                    points=centres * VISER_SCALE,
                    colors=POISON_COLOR,
                    point_size=POISON_POINT_SIZE,
                    point_shape="circle",
                ),
            )
            notes.append(f"{len(centres)} poison centres")
        else:
            self._set_node(CENTRES_NODE, None)
        cloud = None
        if g["kde"].value:
            try:
                cloud = self.voxel_cloud(float(g["kde_threshold"].value))
                drawn = f" ({len(cloud.points)} drawn)" if len(cloud.points) < cloud.n_above else ""
                notes.append(f"{cloud.n_above} KDE voxels{drawn}")
            except PanelError as err:
                notes.append(f"**{err}**")
        if cloud is not None:
            self._set_node(
                KDE_NODE,
                lambda: scene.add_point_cloud(
                    KDE_NODE,
                    points=cloud.points * VISER_SCALE,
                    colors=cloud.colors,
                    point_size=cloud.voxel_size * VISER_SCALE,
                    point_shape="square",
                ),
            )
        else:
            self._set_node(KDE_NODE, None)
        self._draw_frusta(bool(g["frusta"].value))
        self._overlay_notes = notes
        self._set_text("status", self.status_text())

    def voxel_cloud(self, threshold: float) -> VoxelCloud:
        """Thresholded KDE voxels from ``<attack>/density_grid.npz`` (cached per file and threshold)."""
        attack_dir = self.attack_dir
        path = None if attack_dir is None else attack_dir / "density_grid.npz"
        if path is None or not path.exists():
            raise PanelError(f"no KDE: {path} does not exist (it is written at the injection step)")
        key = (str(path), path.stat().st_mtime, round(threshold, 4))
        if key not in self._voxel_cache:
            try:
                grid, extras = load_density_npz(path)
            except (OSError, ValueError) as err:
                raise PanelError(f"cannot read {path}: {err}") from err
            self._voxel_cache.clear()
            self._voxel_cache[key] = kde_voxel_cloud(grid, extras.get("kde"), threshold)
        return self._voxel_cache[key]

    def _draw_frusta(self, visible: bool) -> None:
        assert self._server is not None
        scene = self._server.scene
        frustum_scale = float(getattr(getattr(self._viewer, "config", None), "camera_frustum_scale", 0.1))
        for v in self.poisoned:
            name = f"{FRUSTA_NODE}/view{v.index:04d}"
            if not visible:
                self._set_node(name, None)
                continue
            if name in self._nodes:
                continue
            c2w, fy, width, height = self._poses[("train", v.index)]
            spec = frustum_spec(c2w, fy, width, height)
            step = max(1, math.ceil(v.target.shape[0] / 100))
            thumb = (v.target[::step, ::step] * 255).round().astype(np.uint8)
            handle = scene.add_camera_frustum(
                name,
                fov=spec.fov,
                aspect=spec.aspect,
                scale=1.5 * frustum_scale,
                color=POISONED_FRUSTUM_COLOR,
                image=thumb,
                wxyz=spec.wxyz,
                position=spec.position,
            )
            handle.on_click(self._select_on_click(f"poisoned: {v.name}"))
            self._nodes[name] = handle
        self._sync_frusta(force=True)

    def _sync_frusta(self, force: bool = False) -> None:
        """Which camera frusta to show (cheap unless something changed; called on every camera message).

        * The frusta at the view the camera sits on are hidden: their image planes are right in front of
          the camera and would cover the render. They come back when the camera leaves.
        * While the red poisoned-view frusta are on, nerfstudio's own frusta at those views are hidden:
          they show the clean dataset image, not the illusion composite the view was trained on.
        """
        entry = self._current_view
        covered = entry.index if entry is not None and entry.split == "train" else None
        theirs = getattr(self._viewer, "camera_handles", None) or {}  # nerfstudio's, made after _setup
        hide_button = getattr(self._viewer, "hide_images", None)  # shown while the training cams are shown
        cams_shown = bool(getattr(hide_button, "visible", True))
        ours_on = bool(self._gui["frusta"].value) if self._gui else False
        state = (covered, len(theirs), cams_shown, ours_on)
        if state == self._frusta_state and not force:
            return
        with self._scene_lock:
            previous = self._frusta_state[0] if self._frusta_state else None
            self._frusta_state = state
            poisoned = {v.index for v in self.poisoned}
            for index in (poisoned | {covered, previous}) - {None}:
                handle = theirs.get(index)
                if handle is not None:
                    want = cams_shown and index != covered and not (ours_on and index in poisoned)
                    if handle.visible != want:
                        handle.visible = want
                ours = self._nodes.get(f"{FRUSTA_NODE}/view{index:04d}")
                if ours is not None and ours.visible != (index != covered):
                    ours.visible = index != covered

    def _select_on_click(self, label: str) -> Callable[[Any], None]:
        def on_click(_: Any) -> None:
            if self._gui["view"].value == label:
                self.jump_to_selected()
            else:
                self._gui["view"].value = label  # fires the dropdown's update, which jumps

        return on_click


CENTRES_NODE = "/stealth_attack/poison_centres"
KDE_NODE = "/stealth_attack/kde_voxels"
FRUSTA_NODE = "/stealth_attack/poisoned_cameras"
