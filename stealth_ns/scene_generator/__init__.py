"""Procedural test scenes rendered by analytic ray casting, in nerfstudio-data or Blender format.

Use :func:`make_scene` (or ``stealth-ns make-scene``). Four presets (layouts: :mod:`.presets`):

* ``orbit``: inward-facing 360-degree capture around a group of textured objects (Mip-NeRF 360
  like), 60 views by default, 128x96;
* ``forward``: a free forward walk down a street (Free dataset like), 48 views by default, 128x96;
* ``facing``: a forward-facing hand-held capture of a cluttered scene (LLFF like: cameras on a
  small planar grid, baseline ~10x smaller than the scene depth, all looking the same way), 24
  views by default, 128x96;
* ``object``: an object-centric capture of 1-3 objects on a transparent background
  (NeRF-synthetic / Blender like: cameras on the upper hemisphere at radius 4 looking at the
  origin), 150 views (100 train / 25 val / 25 test) by default, 128x128.

``orbit``, ``forward`` and ``facing`` are written in nerfstudio-data format (dataparser
``nerfstudio-data``) with SfM-like seed points in ``sparse_pc.ply`` (surface samples of the
training views with depth-proportional noise; ``facing`` adds 2% outliers, points pushed along
their viewing ray, as an SfM reconstruction has); every 8th view (index % 8 == 0) is held out for
testing. ``object`` is written in the Blender format (dataparser ``blender-data``: RGBA PNGs,
``transforms_{train,val,test}.json``) without seed points, as NeRF-synthetic has none.

Depth maps are **z-depth** (distance along the camera's -Z axis, world units; 0 where the pixel sees
sky or background), which is what nerfstudio's depth losses expect. They are float32 ``.npy`` in
world units, so a nerfstudio depth pipeline needs ``depth_unit_scale_factor=1.0`` (its default,
1e-3, assumes millimetres). ``scene.json`` records the preset, seed, resolution, split, field of
view, region of interest and the preset's own parameters.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stealth_ns.scene_generator.formats import split_indices
    from stealth_ns.scene_generator.generate import SceneSummary, make_scene, parse_resolution
    from stealth_ns.scene_generator.presets import PRESETS

__all__ = ["PRESETS", "SceneSummary", "make_scene", "parse_resolution", "split_indices"]

_HOMES = {
    "PRESETS": "presets",
    "SceneSummary": "generate",
    "make_scene": "generate",
    "parse_resolution": "generate",
    "split_indices": "formats",
}
"""The module of each public name. They load on first use: ``stealth-ns`` imports make-scene's options
(:mod:`.command_line`) from this package at start-up, and the renderer loads only when a scene is made."""


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
    globals()[name] = value
    return value
