"""glibc malloc settings for CPU training: freed memory stays in the process for the next step.

A CPU training step allocates and frees the same large tensors every iteration (gradients of the SH
coefficients alone are 13 MB at 70k Gaussians). With glibc's defaults many of them are served by
fresh ``mmap`` pages or by heap memory trimmed back to the OS at the previous ``free``, so every step
pays page faults on first write. Raising the mmap threshold to the largest value glibc accepts and
never trimming the heap keeps those pages mapped and reused. Measured with ``stealth-ns bench
train`` (orbit, stealth-splat-lite, 2 threads): see ``docs/design/training_step.md``. Peak RSS is unchanged
(the process keeps its peak instead of returning memory between steps).
"""

from __future__ import annotations

import ctypes
import platform

__all__ = ["keep_freed_memory"]

# mallopt(3) parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
# only allocations above this get their own mmap; glibc before 2.35 refuses more than 32 MiB
_MMAP_THRESHOLDS = (2**30, 32 * 2**20)
_TRIM_THRESHOLD = 2**31 - 1  # never give the top of the heap back
_TOP_PAD = 64 * 2**20  # grow the heap in 64 MiB steps

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Apply the settings once per process; False where the C library is not glibc (nothing changed)."""
    global _applied
    if _applied is None:
        _applied = False
        if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
            mallopt = ctypes.CDLL(None).mallopt
            mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
            mmap_set = any(mallopt(_M_MMAP_THRESHOLD, value) == 1 for value in _MMAP_THRESHOLDS)
            _applied = mmap_set and mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD) == 1
            _applied = _applied and mallopt(_M_TOP_PAD, _TOP_PAD) == 1
    return _applied
