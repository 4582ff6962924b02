"""The record a command keeps of the files it wrote into a folder, so that ``--overwrite`` removes only
those: never a file the user added beside them, nor one of them the user changed since.

A manifest is a JSON file ``{"written_by": ..., "files": {relative path: SHA-256 or null}, "folders":
[...]}``. Paths are POSIX, relative to the folder. A null hash marks a file the command is about to
write (recorded first, so that a run cut short can still be replaced); ``folders`` lists folders the
command owns whole while it writes (their files are not known in advance). When the command finishes
it records every file with its hash and no folders. Used by ``make-scene`` (:mod:`stealth_ns.scene_generator`)
and the poisoned copies of ``poison-dataset`` / ``ipa-poison``
(:mod:`stealth_ns.poisoned_datasets.dataset_copy`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from stealth_ns.foundation.fingerprint import file_sha256
from stealth_ns.foundation.json_io import write_json_atomic


@dataclass(frozen=True)
class Manifest:
    """What a manifest records: files (path -> hash, None while being written) and owned folders."""

    files: dict[str, str | None] = field(default_factory=dict)
    folders: tuple[str, ...] = ()

    def owns(self, rel: str) -> bool:
        """Whether ``rel`` is recorded, or lies in an owned folder."""
        return rel in self.files or any(rel.startswith(f"{folder}/") for folder in self.folders)


def read_manifest(path: Path) -> Manifest:
    """The manifest at ``path``; empty when it is missing or unreadable (nothing is owned)."""
    try:
        meta = json.loads(Path(path).read_text(encoding="utf-8"))
        files = {str(k): (v if isinstance(v, str) else None) for k, v in meta["files"].items()}
        folders = tuple(str(f) for f in meta.get("folders", ()) if isinstance(f, str))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return Manifest()
    return Manifest(files, folders)


def write_manifest(
    path: Path, root: Path, files: Iterable[str], written_by: str, hashes: bool, folders: Iterable[str] = ()
) -> None:
    """Record ``files`` (paths relative to ``root``) as written by ``written_by``: with ``hashes`` their
    SHA-256 as they are now, else None (about to be written); ``folders``: owned whole meanwhile."""
    record = {
        f: (file_sha256(root / f) if hashes and (root / f).is_file() else None) for f in sorted(set(files))
    }
    write_json_atomic(path, {"written_by": written_by, "files": record, "folders": sorted(set(folders))})


def files_under(root: Path, names: Iterable[str] | None = None) -> list[str]:
    """Relative POSIX paths of the files and links under ``root`` (only under its entries ``names``
    when given), links not followed."""
    tops = [root / n for n in names] if names is not None else sorted(root.iterdir())
    found = []
    for top in tops:
        if top.is_dir() and not top.is_symlink():
            found += [
                q.relative_to(root).as_posix()
                for q in sorted(top.rglob("*"))
                if q.is_symlink() or not q.is_dir()
            ]
        elif top.exists() or top.is_symlink():
            found.append(top.relative_to(root).as_posix())
    return found


def foreign_files(root: Path, manifest: Manifest, present: Iterable[str]) -> list[str]:
    """Of the ``present`` files (relative to ``root``), those ``--overwrite`` must not touch: not owned
    by the manifest, a link or a folder where a file was written, or changed since it was recorded."""
    foreign = []
    for rel in present:
        p = root / rel
        if not manifest.owns(rel) or p.is_symlink() or p.is_dir():
            foreign.append(rel)
        elif manifest.files.get(rel) is not None and file_sha256(p) != manifest.files[rel]:
            foreign.append(rel)
    return foreign


def remove_owned(root: Path, manifest: Manifest, present: Iterable[str]) -> None:
    """Remove the ``present`` files the manifest owns (check :func:`foreign_files` first), then the
    folders that leaves empty, up to (not including) ``root``; nothing else is touched."""
    emptied: set[Path] = set()
    for rel in present:
        p = root / rel
        if manifest.owns(rel) and p.is_file() and not p.is_symlink():
            p.unlink()
            emptied.update(q for q in p.parents if q != root and q.is_relative_to(root))
    for folder in sorted(emptied, key=lambda q: -len(q.parts)):
        if folder.is_dir() and not folder.is_symlink() and not any(folder.iterdir()):
            folder.rmdir()


def listing(paths: list[str], shown: int = 3) -> str:
    """``a, b, c and 4 more``: the first ``shown`` of ``paths`` for a one-line message."""
    more = f" and {len(paths) - shown} more" if len(paths) > shown else ""
    return ", ".join(paths[:shown]) + more
