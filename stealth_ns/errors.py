"""The one exception type that the CLI turns into a one-line message instead of a traceback."""

from __future__ import annotations


class StealthNSError(Exception):
    """A problem with the user's input or environment, explained in one line."""


def fail(err: StealthNSError | str) -> None:
    """Stop ns-train / ns-eval with a one-line message (no traceback)."""
    raise SystemExit(f"stealth-ns: error: {err}")
