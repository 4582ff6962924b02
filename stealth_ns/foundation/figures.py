"""Matplotlib figures written to PNG (Agg backend): a titled image grid and a labelled one-axes plot,
each written whole or not at all (:func:`~stealth_ns.foundation.json_io.atomic_path`: a full disk leaves no
cut picture, and is a one-line StealthNSError naming the file)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.foundation.json_io import atomic_path


def figure_grid(path: Path, rows: list[list[tuple[str, np.ndarray]]]) -> Path:
    """A PNG of images in a grid with a title above each (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows, n_cols = len(rows), max(len(r) for r in rows)
    h, w = rows[0][0][1].shape[:2]
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(2.6 * n_cols, 2.6 * n_rows * h / w + 0.4), squeeze=False
    )
    for ax in axes.flat:
        ax.axis("off")
    for r, row in enumerate(rows):
        for c, (title, image) in enumerate(row):
            axes[r][c].imshow(image, interpolation="nearest")
            axes[r][c].set_title(title, fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    return path


def save_plot(fig: Any, ax: Any, path: Path, xlabel: str, ylabel: str, title: str) -> None:
    """Label a one-axes matplotlib figure (grid, legend), write it to ``path`` (PNG) and close it."""

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)


def _save(fig: Any, path: Path) -> None:
    """Write ``fig`` to ``path`` (PNG, 120 dpi) whole or not at all, and close it."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(Path(path)) as tmp:
            fig.savefig(tmp, dpi=120)
    finally:
        plt.close(fig)
