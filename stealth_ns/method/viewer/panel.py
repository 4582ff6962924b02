"""The panel itself: the glue between viser's GUI, nerfstudio's viewer and the pipeline.

nerfstudio's viewer discovers :class:`StealthAttackPanel` (``pipeline.stealth_attack``) twice:

* as a ``ViewerElement``: ``install(server)`` builds the panel's GUI inside the "Custom Elements" folder;
* as a ``ViewerControl``: ``_setup(viewer)`` hands it the viewer (viser server, train lock, run folder).

It reads the pipeline only through :class:`~stealth_ns.method.viewer.source.PanelSource` and keeps everything
heavy out of the viewer's render path: views, targets, masks and voxel clouds are read once and cached,
and the masked-PSNR render runs in a worker thread, cached per (view, filter, step). The render filter is
the model's ``viewer_render_filter``, which the model applies to the viewer's render threads only.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import viser
from nerfstudio.viewer.viewer_elements import ViewerControl, ViewerElement

from stealth_ns.attack.record import PoisonView
from stealth_ns.images.metrics import masked_psnr
from stealth_ns.method.render_view import RenderFilter
from stealth_ns.method.viewer.overlays import KdeVoxels, poison_centres
from stealth_ns.method.viewer.poses import CameraJump, apply_camera_jump, c2w_from_viser_pose, camera_jump
from stealth_ns.method.viewer.readout import PsnrWorker, ReadoutKey
from stealth_ns.method.viewer.scene import OverlayScene
from stealth_ns.method.viewer.source import PanelError, PanelSource
from stealth_ns.method.viewer.views import ROLE_TEXT, ViewEntry, ViewSet, load_view_set

if TYPE_CHECKING:
    from nerfstudio.viewer.viewer import Viewer

#: Dropdown label -> ``StealthSplatModel.viewer_render_filter``.
FILTER_OPTIONS: dict[str, RenderFilter] = {
    "shown": "all",
    "hidden": "hide_poison",
    "only poison": "only_poison",
}
#: Render filter -> how the read-out names it.
FILTER_TEXT: dict[str, str] = {
    "all": "poison shown",
    "hide_poison": "poison hidden",
    "only_poison": "only poison",
}

NO_VIEW = "(free camera)"
#: nerfstudio's ``ViewerConfig.camera_frustum_scale`` default, used before a viewer is set up.
DEFAULT_FRUSTUM_SCALE = 0.1


class StealthAttackPanel(ViewerElement[bool], ViewerControl):
    """The "StealthAttack" viewer panel (see the package docstring). Create one per pipeline; it does
    nothing until a viewer installs it."""

    def __init__(self, source: PanelSource) -> None:
        super().__init__(name="StealthAttack")
        self._source = source
        self.views = ViewSet.empty()
        """The views, read when a viewer sets the panel up."""
        self._viewer: Viewer | None = None
        self._server: viser.ViserServer | None = None
        self._scene: OverlayScene | None = None
        self._gui: dict[str, Any] = {}
        self._overlay_notes: list[str] = []
        self._kde = KdeVoxels()
        self._psnr = PsnrWorker(self.masked_psnr)
        self._last_camera: viser.CameraHandle | None = None
        self._current_view: ViewEntry | None = None

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
        self._attach(viser_server)
        self._create_gui_handle(viser_server)
        g = self._gui
        g["view"].on_update(lambda _: self.jump_to_selected())
        g["jump"].on_click(lambda _: self.jump_to_selected())
        g["filter"].on_update(lambda _: self.set_render_filter(FILTER_OPTIONS.get(g["filter"].value, "all")))
        for key in ("centres", "kde", "kde_threshold", "frusta"):
            g[key].on_update(lambda _: self.refresh_overlays())
        g["refresh"].on_click(lambda _: self.refresh_overlays(reload=True))

    def _setup(self, viewer: Viewer) -> None:
        """The viewer exists (end of its constructor): read the views, draw the overlays, follow cameras."""
        super()._setup(viewer)
        self._viewer = viewer
        server = self._attach(viewer.viser_server)
        self.load_views()
        if self._gui:
            self._gui["view"].options = [NO_VIEW] + [e.label for e in self.entries]
            self.refresh_overlays()
        server.on_client_connect(lambda client: client.camera.on_update(self.update_readout))
        for client in server.get_clients().values():
            client.camera.on_update(self.update_readout)

    def _attach(self, server: viser.ViserServer) -> viser.ViserServer:
        if self._server is not server or self._scene is None:
            self._server = server
            self._scene = OverlayScene(server.scene)
        return server

    # ------------------------------------------------------------------ data
    @property
    def entries(self) -> list[ViewEntry]:
        """The dropdown's views."""
        return self.views.entries

    @property
    def poisoned(self) -> list[PoisonView]:
        """The poisoned views, in attack order."""
        return self.views.poisoned

    @property
    def render_filter(self) -> RenderFilter:
        """The viewer's render filter (``FILTER_OPTIONS`` values): the model's ``viewer_render_filter``."""
        return self._source.model.viewer_render_filter

    @property
    def run_dir(self) -> Path | None:
        """The run's folder (that of ``config.yml``), known once a viewer is set up."""
        return None if self._viewer is None else Path(self._viewer.log_filename).parent

    @property
    def attack_dir(self) -> Path | None:
        """``<run>/attack``: the pipeline's while training, else next to ``config.yml``."""
        if self._source.attack_dir is not None:
            return Path(self._source.attack_dir)
        return None if self.run_dir is None else self.run_dir / "attack"

    def load_views(self) -> None:
        """View list, camera poses and poisoned targets/masks: read once, then kept.

        Poisoned views come from the pipeline when it resolved them (``ns-train``, ``ns-viewer``), else
        from the attack record in :attr:`attack_dir`; problems are shown in the panel.
        """
        self.views = load_view_set(self._source, self.attack_dir)

    def jump_for(self, entry: ViewEntry) -> CameraJump:
        """The camera jump onto a view."""
        pose = self.views.pose(entry)
        return camera_jump(pose.c2w, pose.fy, pose.height)

    def status_text(self) -> str:
        """Markdown of the panel's status line(s)."""
        model = self._source.model
        lines = []
        if self.poisoned:
            names = ", ".join(f"`{v.name}`" for v in self.poisoned)
            n_poison = int(model.poison_mask.sum())
            lines.append(f"Poisoned: {names}  \n{n_poison} poison Gaussians of {model.num_points}")
        elif not self.views.problems:
            lines.append("This run has no poisoned views (trained without the attack).")
        lines += [f"**{p}**" for p in self.views.problems]
        if self._overlay_notes:
            lines.append(", ".join(self._overlay_notes))
        return "  \n".join(lines)

    # ------------------------------------------------------------------ the viewer
    def _train_lock(self) -> contextlib.AbstractContextManager[Any]:
        """The viewer's train lock (held by training for a whole step); none in ``ns-viewer``."""
        lock = None if self._viewer is None else self._viewer.train_lock
        return lock if lock is not None else contextlib.nullcontext()

    def _step(self) -> int:
        return 0 if self._viewer is None else int(self._viewer.step)

    def _frustum_scale(self) -> float:
        return (
            DEFAULT_FRUSTUM_SCALE if self._viewer is None else float(self._viewer.config.camera_frustum_scale)
        )

    def _set_text(self, key: str, content: str) -> None:
        handle = self._gui.get(key)
        if handle is not None and handle.content != content:
            handle.content = content

    def _rerender(self) -> None:
        self.cb_hook(self)  # the viewer rewires cb_hook to "take the train lock, then re-render"

    # ------------------------------------------------------------------ actions
    def jump_to_selected(self) -> None:
        """Show the selected view's role and move every client's camera onto it."""
        entry = self.views.entry(self._gui["view"].value)
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

    def set_render_filter(self, render_filter: RenderFilter) -> None:
        """Filter the viewer's renders (``"all"``, ``"hide_poison"``, ``"only_poison"``) and re-render."""
        if render_filter not in FILTER_OPTIONS.values():
            raise ValueError(f"unknown render filter {render_filter!r}")
        self._source.model.viewer_render_filter = render_filter
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
        entry = self.views.at(c2w_from_viser_pose(camera.wxyz, camera.position))
        self._current_view = entry
        self._sync_frusta()
        if entry is None:
            self._set_text("readout", "Camera: free")
            return
        if entry.role != "poisoned":
            self._set_text("readout", f"Camera on {entry.role} view `{entry.name}`")
            return
        key = (entry.index, self.render_filter, self._step())
        psnr = self._psnr.cached(key)
        if psnr is not None:
            self._set_text("readout", self._psnr_text(entry, key, psnr))
            return
        self._set_text("readout", f"Camera on **poisoned** view `{entry.name}`  \nmasked PSNR: computing...")
        self._psnr.start(key, on_done=self._psnr_done, on_error=self._psnr_failed)

    @staticmethod
    def _psnr_text(entry: ViewEntry, key: ReadoutKey, psnr: float) -> str:
        return (
            f"Camera on **poisoned** view `{entry.name}`  \n"
            f"masked PSNR vs illusion: **{psnr:.2f} dB** ({FILTER_TEXT[key[1]]}, step {key[2]})"
        )

    def _psnr_done(self) -> None:
        self._set_text("status", self.status_text())
        if self._last_camera is not None:
            self.update_readout(self._last_camera)  # shows it, or starts the next one if things moved on

    def _psnr_failed(self, err: Exception) -> None:
        self._set_text("readout", f"masked PSNR failed: {type(err).__name__}: {err}")

    def masked_psnr(self, index: int, render_filter: RenderFilter = "all") -> float:
        """Masked PSNR (dB) of poisoned view ``index`` rendered at its own resolution against its target."""
        view = self.views.poisoned_view(index)
        cameras = self.views.train_cameras
        if view is None or cameras is None:
            raise PanelError(f"view {index} is not poisoned")
        with self._train_lock():
            rgb = self._source.model.render_view(cameras[index : index + 1], render_filter)["rgb"]
        return masked_psnr(rgb, view.target, view.mask)

    # ------------------------------------------------------------------ overlays
    def refresh_overlays(self, reload: bool = False) -> None:
        """(Re)draw the 3D overlays the checkboxes ask for and remove the others."""
        if self._scene is None or not self._gui:
            return
        centres = None
        if self._gui["centres"].value:
            model = self._source.model
            with self._train_lock():  # before the scene lock: training may hold it for a whole step
                centres = poison_centres(model.means, model.poison_mask)
        with self._scene.lock:
            self._draw_overlays(self._scene, reload, centres)

    def _draw_overlays(self, scene: OverlayScene, reload: bool, centres: np.ndarray | None) -> None:
        if reload:
            self._kde.clear()
        g = self._gui
        notes: list[str] = []
        scene.show_centres(centres)
        if centres is not None:
            notes.append(f"{len(centres)} poison centres")
        cloud = None
        if g["kde"].value:
            try:
                cloud = self._kde.cloud(self.attack_dir, float(g["kde_threshold"].value))
                drawn = f" ({len(cloud.points)} drawn)" if len(cloud.points) < cloud.n_above else ""
                notes.append(f"{cloud.n_above} KDE voxels{drawn}")
            except PanelError as err:
                notes.append(f"**{err}**")
        scene.show_voxels(cloud)
        frusta = [(v, self.views.poses[("train", v.index)]) for v in self.poisoned]
        scene.show_frusta(frusta, bool(g["frusta"].value), self._frustum_scale(), self._select_on_click)
        self._sync_frusta(force=True)
        self._overlay_notes = notes
        self._set_text("status", self.status_text())

    def _sync_frusta(self, force: bool = False) -> None:
        """Hide the frusta that would cover the camera's view (see :meth:`OverlayScene.sync_frusta`)."""
        if self._scene is None:
            return
        entry = self._current_view
        covered = entry.index if entry is not None and entry.split == "train" else None
        theirs = getattr(self._viewer, "camera_handles", None) or {}  # nerfstudio's, made after _setup
        cams_shown = True if self._viewer is None else bool(self._viewer.hide_images.visible)
        poisoned = {v.index for v in self.poisoned}
        self._scene.sync_frusta(covered, poisoned, theirs, cams_shown, force=force)

    def _select_on_click(self, view: PoisonView) -> Callable[[Any], None]:
        """Click handler of a poisoned view's frustum: select (and so jump onto) the view."""
        label = f"poisoned: {view.name}"

        def on_click(_: Any) -> None:
            if self._gui["view"].value == label:
                self.jump_to_selected()
            else:
                self._gui["view"].value = label  # fires the dropdown's update, which jumps

        return on_click
