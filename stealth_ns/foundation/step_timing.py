"""Wall-clock time per phase of a training step, for ``stealth-ns bench train``.

The renderer and the model mark their phases with ``with phase("tile sort"):``. Outside a
benchmark no timer is active and :func:`phase` returns a shared no-op context (well under a
microsecond per call). While :data:`TIMER` is active, every phase's seconds are added to the
current step's entry; a phase may run several times per step (each is summed).

On CUDA the kernels a phase launches finish after it returns; a timer given ``sync``
(``torch.cuda.synchronize``) waits for them at both ends of every phase, so that each phase is
charged its own GPU work (at the cost of the overlap between CPU and GPU that training has without it).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from typing import Any

_NULL = contextlib.nullcontext()


class StepTimer:
    """Seconds per named phase, one dict per training step."""

    def __init__(self) -> None:
        self.active = False
        self.current: dict[str, float] = {}
        self.steps: list[dict[str, float]] = []
        self.sync: Callable[[], Any] | None = None
        """Called at both ends of every timed phase (``torch.cuda.synchronize`` on CUDA), or None."""

    def now(self) -> float:
        """``time.perf_counter()``, after waiting for ``sync`` (the device's queued work) if set."""
        if self.sync is not None:
            self.sync()
        return time.perf_counter()

    def add(self, name: str, seconds: float) -> None:
        if self.active:
            self.current[name] = self.current.get(name, 0.0) + seconds

    @contextlib.contextmanager
    def _timed(self, name: str) -> Iterator[None]:
        start = self.now()
        try:
            yield
        finally:
            self.add(name, self.now() - start)

    def phase(self, name: str) -> contextlib.AbstractContextManager[None]:
        """Time the ``with`` block as ``name`` (a no-op while inactive)."""
        return self._timed(name) if self.active else _NULL

    def wrap(self, name: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function``, with every call timed as ``name``."""

        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.phase(name):
                return function(*args, **kwargs)

        return timed

    def excluded(self, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function``, with no phase timed while it runs (its time stays in the enclosing step)."""

        def untimed(*args: Any, **kwargs: Any) -> Any:
            was, self.active = self.active, False
            try:
                return function(*args, **kwargs)
            finally:
                self.active = was

        return untimed

    def end_step(self, **counts: float) -> None:
        """Close the current step (``counts``: e.g. Gaussians, pairs, kept beside the phases)."""
        if self.active:
            self.steps.append({**self.current, **counts})
        self.current = {}


#: The process's timer; ``stealth-ns bench train`` activates it.
TIMER = StepTimer()


def phase(name: str) -> contextlib.AbstractContextManager[None]:
    """``with phase("rasterize forward"):`` -- timed into :data:`TIMER` when it is active."""
    return TIMER.phase(name)
