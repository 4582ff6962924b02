"""Checks on an output folder before any slow work: it can be created and written."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from stealth_ns.errors import StealthNSError


def check_writable(output: Path, what: str = "report") -> None:
    """StealthNSError unless the folder ``output`` (existing or to be created) can be written and its
    ``images/``, where the commands put their pictures, is not a file. ``what`` names the command's
    output in the messages ("report", "defence results", "scan")."""
    if output.exists() and not output.is_dir():
        raise StealthNSError(f"--output {output} is a file, not a folder")
    if (output / "images").exists() and not (output / "images").is_dir():
        raise StealthNSError(f"--output {output}: {output / 'images'} is a file, not a folder")
    existing = output
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise StealthNSError(f"cannot write the {what} to {output}: {existing} is a file, not a folder")
    try:  # a real write: permissions, read-only file systems, root
        with tempfile.TemporaryDirectory(dir=existing, prefix=".stealth-ns-write-test-"):
            pass
    except OSError as err:
        raise StealthNSError(
            f"cannot write the {what} to {output}: {err.strerror or err} ({existing})"
        ) from None


def check_outside(output: Path, folder: Path, what: str) -> None:
    """StealthNSError when ``output`` is ``folder`` or lies inside it (links resolved): a command writes
    beside a run or a dataset, never into it. ``what`` names the folder ("the run folder", ...)."""
    out, inside = Path(output).resolve(), Path(folder).resolve()
    if out == inside or inside in out.parents:
        raise StealthNSError(f"--output {output} is inside {what} {inside}; choose another folder")


def check_file_writable(path: Path, flag: str) -> None:
    """StealthNSError unless the file ``path`` (given as ``flag``) can be written: not a folder, in an
    existing folder that can be written (checked before a benchmark runs, not after)."""
    path = Path(path)
    if path.is_dir():
        raise StealthNSError(f"{flag} {path} is a folder: give a file name (e.g. {path / 'bench.json'})")
    if not path.parent.is_dir():
        raise StealthNSError(f"cannot write {flag} {path}: folder {path.parent} does not exist")
    try:
        with tempfile.TemporaryFile(dir=path.parent, prefix=".stealth-ns-write-test-"):
            pass
    except OSError as err:
        raise StealthNSError(f"cannot write {flag} {path}: {err.strerror or err}") from None


def remove_tree(path: Path, output: Path) -> None:
    """``shutil.rmtree(path)`` of something a command wrote under its ``--output`` earlier, refused
    (StealthNSError) when a symbolic link on the way from ``output`` would take the removal elsewhere:
    nothing outside ``--output`` is deleted. A link at ``path`` itself is removed, not followed."""
    path, output = Path(path), Path(output)
    rel = Path(os.path.relpath(os.path.abspath(path), os.path.abspath(output)))
    if rel.parts[:1] == ("..",) or os.path.isabs(rel):
        raise StealthNSError(f"{path} is not inside --output {output}: not removed")
    step = Path(os.path.abspath(output))
    for part in rel.parts[:-1]:
        step = step / part
        if step.is_symlink():
            raise StealthNSError(
                f"--output {output}: {step} is a symbolic link to {step.resolve()}; stealth-ns replaces "
                "what it wrote there only inside --output: remove the link or choose another folder"
            )
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)
