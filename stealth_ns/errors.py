"""The one exception type that the CLI turns into a one-line message instead of a traceback."""

from __future__ import annotations


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
