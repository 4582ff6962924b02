"""``stealth-ns scan``: its options, as tyro parses them, and the command."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import tyro

from stealth_ns.scan.config import ScanConfig


@dataclass
class Scan:
    """Look for poison in a trained 3DGS model from any trainer, no ground truth: a verdict and the views."""

    model: Path
    """The model: a 3DGS PLY (official 3DGS, gsplat, OpenSplat, ns-export gaussian-splat), a
    nerfstudio run's config.yml (stealth-splat, splatfacto) or an official 3DGS output folder
    (cameras.json, point_cloud/iteration_*/)."""
    data: Path | None = None
    """The dataset the model was trained on (nerfstudio-data, COLMAP or Blender): its training cameras
    and images. Needed for a PLY; a run's own dataset by default; for an official 3DGS output folder,
    its cfg_args' source_path, else none (scanned on its cameras.json alone)."""
    output: Path = Path("stealth-scan")
    """Folder for scan.json, scan.html, the images and the cleaned model (cleaned.ply, cleaned/)."""
    options: Annotated[ScanConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=ScanConfig)

    def main(self) -> None:
        from stealth_ns.scan.arguments import check_arguments

        check_arguments(self.model, self.data, self.output, self.options)  # before torch and nerfstudio load
        from stealth_ns.scan.command import run_scan, summary_lines

        doc = run_scan(self.model, self.data, self.output, self.options)
        print("\n".join(summary_lines(doc, self.output)))
