"""The panel's nodes in the viewer's viser scene: poison centres, KDE voxels, the poisoned cameras' frusta,
and which camera frusta (the panel's and nerfstudio's) are visible.

viser's GUI and message threads both touch these nodes: every change happens under :attr:`OverlayScene.lock`.
Inputs are in nerfstudio's scene units; nodes are drawn in viser units (``VISER_SCALE``).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import viser

from stealth_ns.attack.record import PoisonView
from stealth_ns.images.io import to_uint8
from stealth_ns.method.viewer.overlays import VoxelCloud
from stealth_ns.method.viewer.poses import VISER_SCALE, ViewPose, frustum_spec

CENTRES_NODE = "/stealth_attack/poison_centres"
KDE_NODE = "/stealth_attack/kde_voxels"
FRUSTA_NODE = "/stealth_attack/poisoned_cameras"

POISON_COLOR = (255, 0, 255)
#: Poison-centre point size in viser units (0.004 scene units; nerfstudio scales cameras to ~unit distance).
POISON_POINT_SIZE = 0.04
POISONED_FRUSTUM_COLOR = (255, 48, 48)
#: Poisoned frusta are this much larger than nerfstudio's training-camera frusta.
POISONED_FRUSTUM_SCALE = 1.5
#: Longest side of the frusta's thumbnails of the illusion target, pixels (about).
THUMBNAIL_SIZE = 100


def frustum_node(index: int) -> str:
    """Scene-node name of the frustum of poisoned training view ``index``."""
    return f"{FRUSTA_NODE}/view{index:04d}"


class OverlayScene:
    """The panel's scene nodes (see the module docstring)."""

    def __init__(self, scene: viser.SceneApi) -> None:
        self._scene = scene
        self.nodes: dict[str, Any] = {}
        """Our nodes by name (viser handles)."""
        self.lock = threading.RLock()
        self._frusta_state: tuple[int | None, int, bool, bool] | None = None

    def _set_node(self, name: str, make: Callable[[], Any] | None) -> None:
        """Add/replace (``make``) or remove (None) a node of ours."""
        old = self.nodes.pop(name, None)
        if make is None:
            if old is not None:
                old.remove()
            return
        self.nodes[name] = make()  # viser replaces a node of the same name

    def show_centres(self, centres: np.ndarray | None) -> None:
        """Draw ``[P, 3]`` poison centres (scene units) as magenta points, or remove them (None)."""
        if centres is None:
            self._set_node(CENTRES_NODE, None)
            return
        self._set_node(
            CENTRES_NODE,
            lambda: self._scene.add_point_cloud(
                CENTRES_NODE,
                points=centres * VISER_SCALE,
                colors=POISON_COLOR,
                point_size=POISON_POINT_SIZE,
                point_shape="circle",
            ),
        )

    def show_voxels(self, cloud: VoxelCloud | None) -> None:
        """Draw the KDE voxels as squares of a voxel's size, or remove them (None)."""
        if cloud is None:
            self._set_node(KDE_NODE, None)
            return
        self._set_node(
            KDE_NODE,
            lambda: self._scene.add_point_cloud(
                KDE_NODE,
                points=cloud.points * VISER_SCALE,
                colors=cloud.colors,
                point_size=cloud.voxel_size * VISER_SCALE,
                point_shape="square",
            ),
        )

    def show_frusta(
        self,
        views: Sequence[tuple[PoisonView, ViewPose]],
        visible: bool,
        frustum_scale: float,
        on_click: Callable[[PoisonView], Callable[[Any], None]],
    ) -> None:
        """Draw (once) or remove the poisoned views' frusta: red, larger than nerfstudio's (whose size is
        ``frustum_scale``), showing the illusion target the view was trained on; ``on_click(view)`` is the
        click handler of a view's frustum."""
        for view, pose in views:
            name = frustum_node(view.index)
            if not visible:
                self._set_node(name, None)
                continue
            if name in self.nodes:
                continue
            spec = frustum_spec(pose.c2w, pose.fy, pose.width, pose.height)
            step = max(1, math.ceil(view.target.shape[0] / THUMBNAIL_SIZE))
            handle = self._scene.add_camera_frustum(
                name,
                fov=spec.fov,
                aspect=spec.aspect,
                scale=POISONED_FRUSTUM_SCALE * frustum_scale,
                color=POISONED_FRUSTUM_COLOR,
                image=to_uint8(view.target[::step, ::step]),
                wxyz=spec.wxyz,
                position=spec.position,
            )
            handle.on_click(on_click(view))
            self.nodes[name] = handle

    def sync_frusta(
        self,
        covered: int | None,
        poisoned: set[int],
        theirs: Mapping[int, Any],
        cams_shown: bool,
        force: bool = False,
    ) -> None:
        """Which camera frusta to show (cheap unless something changed; called on every camera message).

        * The frusta at the view the camera sits on (training index ``covered``) are hidden: their image
          planes are right in front of the camera and would cover the render. They come back when the
          camera leaves.
        * While the red poisoned-view frusta are on, nerfstudio's own frusta at those views (``theirs``, by
          training index, shown when ``cams_shown``) are hidden: they show the clean dataset image, not the
          illusion composite the view was trained on.
        """
        ours_on = any(frustum_node(i) in self.nodes for i in poisoned)
        state = (covered, len(theirs), cams_shown, ours_on)
        if state == self._frusta_state and not force:
            return
        with self.lock:
            previous = self._frusta_state[0] if self._frusta_state else None
            self._frusta_state = state
            for index in (poisoned | {covered, previous}) - {None}:
                handle = theirs.get(index)
                if handle is not None:
                    want = cams_shown and index != covered and not (ours_on and index in poisoned)
                    if handle.visible != want:
                        handle.visible = want
                ours = self.nodes.get(frustum_node(index))
                if ours is not None and ours.visible != (index != covered):
                    ours.visible = index != covered
