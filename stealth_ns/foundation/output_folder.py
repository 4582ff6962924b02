"""Checks on an output folder before any slow work: it can be created and written; and the rules of what a
command writes into it (:func:`claim_output`): never through a link, never over an input or a file it
did not write, with a record of what it wrote."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

from stealth_ns.foundation.errors import StealthNSError, write_error
from stealth_ns.foundation.file_manifest import (
    files_under,
    foreign_files,
    listing,
    read_manifest,
    remove_owned,
    write_manifest,
)


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


def unfinished(
    err: OSError | StealthNSError, output: Path, what: str, remove: Callable[[], object]
) -> StealthNSError:
    """The one line of a command whose files could not all be written into ``output`` (a full disk:
    ``err``), once ``remove()`` has taken away what it wrote so far, so that nothing cut short is left
    looking finished. ``remove`` returns whether it removed anything; ``what`` names the output
    ("report", "scan")."""
    line = write_error(err.filename or output, err) if isinstance(err, OSError) else err
    try:
        removed = remove()
    except (OSError, StealthNSError):
        return StealthNSError(f"{line}; the unfinished {what} in {output} could not be removed")
    return StealthNSError(f"{line}; the unfinished {what} was removed" if removed else str(line))


# ------------------------------------------------------------------ a command's files in its --output
def check_no_links(output: Path, rels: Iterable[str]) -> None:
    """StealthNSError when one of ``rels`` (paths relative to ``output`` that a command is about to
    write, replace or remove), or a folder on the way to it from ``output``, is a symbolic link: nothing
    is written outside ``--output``, never through a link (``output`` itself may be one: the folder the
    user named)."""
    for rel in rels:
        step = Path(output)
        for part in Path(rel).parts:
            step = step / part
            if step.is_symlink():
                raise StealthNSError(
                    f"--output {output}: {step} is a symbolic link (to {os.readlink(step)}); stealth-ns "
                    "never writes through a link: remove it or choose another folder"
                )


def check_inputs_kept(output: Path, rels: Iterable[str], inputs: Mapping[str, Path | None]) -> None:
    """StealthNSError when an input (flag -> file or folder) is one of ``rels`` (relative to ``output``:
    files to be written, folders to be replaced whole), lies inside one or holds one, links resolved (a
    hard link to a written file counts too): a command never writes over what it reads."""
    real_out = Path(os.path.realpath(output))
    for flag, given in inputs.items():
        if given is None or not (Path(given).exists() or Path(given).is_symlink()):
            continue
        real_in = Path(os.path.realpath(given))
        for rel in rels:
            target = real_out / rel
            same = real_in == target or (
                target.exists() and Path(given).is_file() and os.path.samefile(target, given)
            )
            holds, inside = target in real_in.parents, real_in in target.parents
            if same or holds or inside:
                what = "is" if same else ("holds" if holds else "lies in")
                raise StealthNSError(
                    f"--output {output}: the command writes {rel} there, which {what} its input {flag} "
                    f"{given}; it never writes over its input: choose another --output"
                )


def _present(output: Path, files: Iterable[str], folders: Iterable[str]) -> list[str]:
    """Of ``files`` and the files under ``folders`` (relative to ``output``), those there now."""
    files = [f for f in files if (output / f).exists() or (output / f).is_symlink()]
    return sorted({*files, *files_under(output, [d for d in folders if (output / d).exists()])})


def check_output_plan(
    output: Path,
    record: str,
    files: Iterable[str],
    folders: Iterable[str] = (),
    inputs: Mapping[str, Path | None] | None = None,
) -> None:
    """StealthNSError, before anything is written, when a command's ``files`` or ``folders`` (owned
    whole) in ``output`` would go through a link, over an input (``inputs``: flag -> path) or over a file
    its earlier run did not write there or that was changed since (the earlier run's ``record``:
    :mod:`stealth_ns.foundation.file_manifest`)."""
    files, folders = list(files), list(folders)
    check_no_links(output, [*files, *folders, record])
    check_inputs_kept(output, [*files, *folders], inputs or {})
    foreign = foreign_files(output, read_manifest(output / record), _present(output, files, folders))
    if foreign:
        raise StealthNSError(
            f"--output {output} holds {listing(foreign)}, which stealth-ns did not write there or which "
            f"changed since (not in its record {record}): move them away or choose another folder"
        )


def claim_output(
    output: Path,
    record: str,
    written_by: str,
    files: Iterable[str],
    folders: Iterable[str] = (),
    inputs: Mapping[str, Path | None] | None = None,
) -> None:
    """Make ``output`` ready for a command's ``files`` and ``folders``: :func:`check_output_plan`, then
    remove what the command's earlier run there recorded writing (unchanged, never through a link; a
    file the user changed since stays), and record the new plan first, so that a run cut short can
    still be replaced. :func:`record_output` records the files with their hashes at the end."""
    output = Path(output)
    files, folders = list(files), list(folders)
    check_output_plan(output, record, files, folders, inputs)
    earlier = read_manifest(output / record)
    stale = _present(output, [f for f in earlier.files if f not in files], earlier.folders)
    check_no_links(output, stale)
    stale = [f for f in stale if f not in foreign_files(output, earlier, stale)]
    try:
        output.mkdir(parents=True, exist_ok=True)
        remove_owned(output, earlier, stale)
        write_manifest(output / record, output, files, written_by, False, folders)
    except OSError as err:
        raise StealthNSError(f"cannot write to --output {output}: {err.strerror or err}") from None


def record_output(
    output: Path, record: str, written_by: str, files: Iterable[str], folders: Iterable[str] = ()
) -> None:
    """Record, with their hashes, the ``files`` and every file under ``folders`` that a command wrote
    into ``output`` (what its next run may replace)."""
    output = Path(output)
    write_manifest(output / record, output, _present(output, files, folders), written_by, True)
