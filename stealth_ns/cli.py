"""`stealth-ns` console script: tyro subcommands.

Every subcommand raises :class:`StealthNSError` for bad input; ``entrypoint`` prints it as
one line (``stealth-ns: error: ...``) and exits with status 2, never a traceback.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from stealth_ns.errors import StealthNSError


@dataclass
class MakeScene:
    """Generate a procedural scene in nerfstudio-data format (images, poses, seed points, depth)."""

    output: Path
    """Folder to write (created; must be empty unless --overwrite)."""
    preset: Literal["orbit", "forward"] = "orbit"
    """orbit: inward-facing 360 capture (Mip-NeRF 360 like); forward: free forward trajectory (Free like)."""
    resolution: str = "128x96"
    """Image size as WIDTHxHEIGHT in pixels."""
    views: int | None = None
    """Number of views (default: 60 for orbit, 48 for forward); at least 8."""
    seed: int = 0
    """Random seed: the same seed gives byte-identical files."""
    overwrite: bool = False
    """Replace the contents of a non-empty output folder."""

    def main(self) -> None:
        from stealth_ns.scenes import make_scene

        summary = make_scene(
            preset=self.preset,
            output=self.output,
            resolution=self.resolution,
            views=self.views,
            seed=self.seed,
            overwrite=self.overwrite,
        )
        print(summary)


Commands = (
    Annotated[MakeScene, tyro.conf.subcommand("make-scene")]
)


def main(argv: list[str] | None = None) -> None:
    cmd = tyro.cli(Commands, args=argv, prog="stealth-ns")
    cmd.main()


def entrypoint() -> None:
    try:
        main()
    except StealthNSError as err:
        print(f"stealth-ns: error: {err}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("stealth-ns: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    entrypoint()
