"""The masked-PSNR read-out's worker: one render at a time, off viser's threads, cached.

Camera messages arrive on viser's message thread, which must never wait for a render: the panel asks
:class:`PsnrWorker` for a value and, when it is not cached yet, starts it in a worker thread; the worker
calls back when it is done, and the panel then shows it (or starts the next one, if the camera moved on).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from stealth_ns.method.model import RenderFilter

#: ``(poisoned training-view index, render filter, training step)``.
ReadoutKey = tuple[int, RenderFilter, int]


class PsnrWorker:
    """Masked PSNRs of poisoned views, computed one at a time in a worker thread, cached per key."""

    #: Above this many values the cache starts afresh (a long training session: old steps are of no use).
    MAX_CACHED = 256

    def __init__(self, compute: Callable[[int, RenderFilter], float]) -> None:
        """``compute(index, render_filter)`` is the masked PSNR (dB) of poisoned view ``index``."""
        self._compute = compute
        self._cache: dict[ReadoutKey, float] = {}
        self._busy = False
        self._lock = threading.Lock()
        self._executor: ThreadPoolExecutor | None = None

    def cached(self, key: ReadoutKey) -> float | None:
        """The value for ``key`` if it has been computed."""
        return self._cache.get(key)

    def start(
        self, key: ReadoutKey, on_done: Callable[[], None], on_error: Callable[[Exception], None]
    ) -> bool:
        """Compute ``key`` in the worker thread, then call ``on_done()`` (or ``on_error(err)`` if it failed).

        Returns:
            False, doing nothing, while another value is being computed (whose ``on_done`` asks again).
        """
        with self._lock:
            if self._busy:
                return False
            self._busy = True
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="stealth-panel")
        self._executor.submit(self._run, key, on_done, on_error)
        return True

    def _run(
        self, key: ReadoutKey, on_done: Callable[[], None], on_error: Callable[[Exception], None]
    ) -> None:
        try:
            value = self._compute(key[0], key[1])
            if len(self._cache) > self.MAX_CACHED:
                self._cache.clear()
            self._cache[key] = value
        except Exception as err:  # noqa: BLE001 - reported through on_error; never kills the viewer
            on_error(err)
            return
        finally:
            with self._lock:
                self._busy = False
        on_done()
