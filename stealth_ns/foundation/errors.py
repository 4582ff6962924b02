"""The one exception type that the CLI turns into a one-line message instead of a traceback."""

from __future__ import annotations

import errno
from pathlib import Path

#: What the environment answers a write it refuses: a full disk or quota, a file too large, a read-only
#: file system.
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})
#: A file or folder the user may not touch (a read or a write: the error does not say which).
ACCESS_ERRNOS = frozenset({errno.EACCES, errno.EPERM})


class StealthNSError(Exception):
    """A problem with the user's input or environment, explained in one line."""


class StealthNSExit(SystemExit):
    """How :func:`fail` stops ns-train / ns-eval: a ``SystemExit`` (nerfstudio's entry points print its
    one-line message, no traceback) that keeps the :class:`StealthNSError` it came from in ``error``, so
    code that loads a pipeline in-process (``stealth-ns report``) re-raises that error as it was."""

    def __init__(self, error: StealthNSError) -> None:
        self.error = error
        super().__init__(f"stealth-ns: error: {error}")


def fail(err: StealthNSError | str) -> None:
    """Stop ns-train / ns-eval with a one-line message (no traceback)."""
    raise StealthNSExit(err if isinstance(err, StealthNSError) else StealthNSError(err))


def write_error(path: str | Path, err: OSError) -> StealthNSError:
    """One line for a write that failed: ``cannot write PATH: No space left on device``."""
    return StealthNSError(f"cannot write {path}: {err.strerror or err}")


def environment_error(err: OSError, where: str | Path | None = None) -> StealthNSError | None:
    """One line for an OSError the environment caused: :func:`write_error` for :data:`WRITE_ERRNOS`,
    ``PATH: Permission denied`` for :data:`ACCESS_ERRNOS`, naming the error's own file, else ``where``
    (the folder being written); None for any other OSError, which is left to show as it is."""
    if err.errno not in WRITE_ERRNOS | ACCESS_ERRNOS:
        return None
    path = err.filename if err.filename is not None else where
    if err.errno in ACCESS_ERRNOS:
        return StealthNSError(f"{path if path is not None else 'a file'}: {err.strerror or err}")
    return write_error(path if path is not None else "a file", err)
