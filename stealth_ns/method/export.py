"""The poison tag in ``ns-export gaussian-splat`` PLY files.

nerfstudio's exporter writes a fixed list of per-Gaussian properties. While ns-export loads a
stealth-splat run, ``install_export_hook`` wraps ``ExportGaussianSplat.write_ply`` so that the
file also gets a ``poison`` property (uchar, 1 = poison Gaussian). The exporter copies each
row's position from ``model.means`` (after its crop box and NaN / low-opacity filters), so
rows are matched to the model's Gaussians by their exact (x, y, z).
"""

from __future__ import annotations

import sys
from collections.abc import Callable

import numpy as np

from stealth_ns.method.model import StealthSplatModel


def poison_column(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, means: np.ndarray, tags: np.ndarray
) -> np.ndarray:
    """[M] uint8 tag of each exported row, found by its exact position among ``means`` [N, 3]."""
    lookup: dict[bytes, int] = {}
    for key, tag in zip(np.ascontiguousarray(means, dtype=np.float32), tags, strict=True):
        k = key.tobytes()
        lookup[k] = max(lookup.get(k, 0), int(tag))
    rows = np.stack([x.reshape(-1), y.reshape(-1), z.reshape(-1)], axis=-1).astype(np.float32)
    return np.array([lookup.get(row.tobytes(), 0) for row in rows], dtype=np.uint8)


def install_export_hook(model: StealthSplatModel) -> bool:
    """Add the ``poison`` property to gaussian-splat PLYs written by this process's ns-export.

    Returns False (and does nothing) when ns-export's module is not loaded.
    """
    exporter = sys.modules.get("nerfstudio.scripts.exporter")
    if exporter is None or not hasattr(exporter, "ExportGaussianSplat"):
        return False
    cls = exporter.ExportGaussianSplat
    original: Callable = getattr(cls.write_ply, "__wrapped_write_ply__", cls.write_ply)

    def write_ply(filename, count, map_to_tensors):
        # read the model now: ns-export loads the checkpoint after building the pipeline
        if "poison" not in map_to_tensors and {"x", "y", "z"} <= set(map_to_tensors):
            means = model.means.detach().cpu().numpy()
            tags = model.poison_mask.cpu().numpy().astype(np.uint8)
            m = map_to_tensors
            map_to_tensors["poison"] = poison_column(m["x"], m["y"], m["z"], means, tags)
        return original(filename, count, map_to_tensors)

    write_ply.__wrapped_write_ply__ = original  # type: ignore[attr-defined]
    cls.write_ply = staticmethod(write_ply)
    return True
