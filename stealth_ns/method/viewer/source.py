"""What the viewer panel reads from the pipeline and its model, as Protocols, and the error it shows.

:class:`stealth_ns.method.pipeline.StealthPipeline` satisfies :class:`PanelSource` (its model,
:class:`stealth_ns.method.model.StealthSplatModel`, satisfies :class:`PanelModel`); the panel uses nothing
else of them, so tests can hand it any object with these members.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from nerfstudio.cameras.cameras import Cameras
from torch import Tensor

from stealth_ns.attack.record import PoisonView
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method.model import RenderFilter


class PanelError(StealthNSError):
    """Something the panel cannot show; its message is displayed in the panel."""


@runtime_checkable
class PanelModel(Protocol):
    """The model's side: its poison Gaussians, a one-view render and the viewer's render filter."""

    viewer_render_filter: RenderFilter
    """Applied by the model to the viewer's own renders (its render threads) only."""

    @property
    def poison_mask(self) -> Tensor:
        """``[N]`` bool: which Gaussians are poison."""
        ...

    @property
    def num_points(self) -> int:
        """``N``, the number of Gaussians."""
        ...

    @property
    def means(self) -> Tensor:
        """``[N, 3]`` Gaussian centres, scene units."""
        ...

    def render_view(self, camera: Cameras, render_filter: RenderFilter = "all") -> dict[str, Any]:
        """One camera rendered as evaluation does (eval mode, restored after); ``rgb`` is ``[H, W, 3]``."""
        ...


@runtime_checkable
class PanelSource(Protocol):
    """The pipeline's side: the model, the poisoned views, where the attack's files are, every view."""

    @property
    def model(self) -> PanelModel:
        """The model the viewer renders."""
        ...

    @property
    def attack_dir(self) -> Path | None:
        """``<run>/attack`` while training; None otherwise (the panel then looks next to ``config.yml``)."""
        ...

    @property
    def poison_views(self) -> list[PoisonView]:
        """The poisoned views the pipeline resolved; empty when the attack is off or in inference mode."""
        ...

    def split_views(self) -> dict[str, tuple[list[str], Cameras]]:
        """``{"train": (names, cameras), "eval": (names, cameras)}`` (a split may be missing); names as users
        name views, relative to the dataset folder (e.g. ``"images/frame_00009.png"``)."""
        ...
