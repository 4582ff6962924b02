"""A view ranking of the protocol: its table, ``view_ranking.json`` and ``view_ranking.png``."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    pass
from stealth_ns.difficulty.protocol import rank


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
