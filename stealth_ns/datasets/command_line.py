"""``stealth-ns seed-points`` and ``stealth-ns check-data``: their options, as tyro parses them, and the
commands."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from stealth_ns.foundation.errors import StealthNSError


@dataclass
class SeedPoints:
    """Triangulate seed points (sparse_pc.ply) for a known-pose capture from its images and poses."""

    data: Path
    """nerfstudio-data folder (transforms.json), a transforms JSON file, or a Blender-format folder
    (transforms_train.json)."""
    output: Path | None = None
    """Folder for transforms.json + sparse_pc.ply, image paths pointing back to DATA (for a read-only
    dataset). Default: write sparse_pc.ply and a copy transforms_seeded.json into DATA."""
    overwrite: bool = False
    """Without --output: update DATA's transforms file in place (ply_file_path) and replace its
    sparse_pc.ply. With --output: replace OUTPUT's transforms.json and sparse_pc.ply."""
    max_points: int | None = None
    """Keep at most this many points (a random subset drawn with --seed)."""
    min_views: int = 3
    """Keep points seen in at least this many images (2 gives more, noisier points)."""
    max_error: float = 2.0
    """Keep points whose mean reprojection error is at most this many pixels."""
    seed: int = 0
    """Seed of COLMAP's RANSAC and of the --max-points subset: the same seed gives the same PLY."""

    def main(self) -> None:
        from stealth_ns.datasets.seed_points import make_seed_points

        summary = make_seed_points(
            data=self.data,
            output=self.output,
            overwrite=self.overwrite,
            max_points=self.max_points,
            seed=self.seed,
            min_views=self.min_views,
            max_error=self.max_error,
        )
        print(summary)


@dataclass
class CheckData:
    """Check a nerfstudio-data, COLMAP or Blender dataset (files, images, poses, intrinsics, seed points)."""

    data: Path
    """nerfstudio-data folder (transforms.json), a transforms JSON file, a COLMAP folder (sparse/0,
    images/) or a Blender folder (transforms_train/val/test.json)."""

    def main(self) -> None:
        from stealth_ns.datasets.check import check_dataset

        try:
            summary = check_dataset(self.data)
        except StealthNSError as err:  # a broken dataset is this command's "no" answer: exit 1
            print(f"stealth-ns: error: {err}", file=sys.stderr)
            sys.exit(1)
        print(summary)
