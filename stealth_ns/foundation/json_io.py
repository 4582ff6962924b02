"""JSON that every tool writes the same way: plain values only, never a half-written file; and the
atomic write under it (:func:`atomic_path`) that every other file written whole goes through."""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from stealth_ns.foundation.errors import write_error


def json_safe(obj: Any) -> Any:
    """Numpy scalars -> Python numbers, non-finite floats -> None, tuples -> lists, paths -> str,
    dict keys -> str (what ``json.dumps`` takes and every JSON reader understands)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "item") and callable(obj.item) and getattr(obj, "ndim", 1) == 0:
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary file beside ``path`` for the block to write (same suffix, so a writer that goes by
    the extension picks the same format), renamed onto ``path`` when the block ends and removed when it
    fails: ``path`` holds the old file or the whole new one, never a part (a full disk).

    Raises:
        StealthNSError: ``cannot write PATH: REASON`` for an OSError in the block or the rename; other
            errors propagate as they are (the temporary file removed all the same).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as err:
        raise write_error(path, err) from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (:func:`atomic_path`)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_npz_atomic(path: Path, arrays: dict[str, Any]) -> None:
    """``numpy.savez_compressed`` of ``arrays`` to ``path`` (the name as given: no ".npz" appended),
    encoded in memory and written whole or not at all (:func:`atomic_path`)."""
    import numpy as np

    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    write_bytes_atomic(path, buffer.getvalue())


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to ``path`` whole or not at all (:func:`atomic_path`); a failed write is a one-line
    StealthNSError naming ``path``."""
    write_text_atomic(path, json.dumps(data, indent=2) + "\n")
