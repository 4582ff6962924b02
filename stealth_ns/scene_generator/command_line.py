"""``stealth-ns make-scene``: its options, as tyro parses them, and the command."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal


@dataclass
class MakeScene:
    """Generate a procedural scene (images, poses, depth; seed points except for Blender format)."""

    output: Path
    """Folder to write (created; must be empty unless --overwrite)."""
    preset: Literal["orbit", "forward", "facing", "object"] = "orbit"
    """orbit: inward-facing 360 capture (Mip-NeRF 360 like), nerfstudio-data format;
    forward: free forward trajectory (Free like), nerfstudio-data format;
    facing: forward-facing hand-held capture of a cluttered scene (LLFF like), nerfstudio-data format;
    object: 1-3 objects on a transparent background seen from the upper hemisphere (NeRF-synthetic
    like), Blender format (train with blender-data)."""
    resolution: str | None = None
    """Image size as WIDTHxHEIGHT in pixels (default: 128x96; 128x128 for object)."""
    views: int | None = None
    """Number of views, at least 8 (default: 60 orbit, 48 forward, 24 facing, 150 object = 100 train
    + 25 val + 25 test)."""
    seed: int = 0
    """Random seed: the same seed gives byte-identical files."""
    overwrite: bool = False
    """Replace the contents of a non-empty output folder."""

    def main(self) -> None:
        from stealth_ns.scene_generator import make_scene

        summary = make_scene(
            preset=self.preset,
            output=self.output,
            resolution=self.resolution,
            views=self.views,
            seed=self.seed,
            overwrite=self.overwrite,
        )
        print(summary)
