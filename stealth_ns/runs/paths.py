"""A run as the commands take it (its folder, its ``config.yml``, or a 3DGS PLY), before anything loads."""

from __future__ import annotations

from pathlib import Path


def run_file(given: Path) -> Path:
    """The file a run named on the command line stands for: ``given/config.yml`` for a folder, ``given``
    itself otherwise (a config.yml or a PLY). A loaded run keeps it as its ``config_path``."""
    given = Path(given)
    return given / "config.yml" if given.is_dir() else given


def same_run(a: Path, b: Path) -> bool:
    """Whether two runs as given (folder, config.yml or PLY) are one and the same (links resolved)."""
    return run_file(a).resolve() == run_file(b).resolve()
