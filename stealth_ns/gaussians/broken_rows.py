"""Rows of a model file that cannot be Gaussians, left out on reading: the one place that decides which,
and how many a file may hold.

A row is broken when one of its values is NaN or infinite (centre, log scale, rotation, opacity logit,
SH coefficients; other per-row properties are not looked at) or its rotation quaternion has length 0.
No renderer can draw such a row; trainers write a few when a Gaussian diverged. Every reader
(:mod:`~stealth_ns.gaussians.model_files`) passes what it decoded through
:func:`~stealth_ns.gaussians.ply.checked_rows`: the rows :func:`find_broken_rows` finds are left out
(:meth:`~stealth_ns.gaussians.ply.GaussianCloud.without_broken_rows`, the others in their order), a
:class:`RowsLeftOut` says which and why, and a file with more than :data:`MAX_LEFT_OUT_SHARE` of its
rows broken is refused in one line (:func:`check_left_out`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.foundation.errors import StealthNSError

#: The largest share of a file's rows left out before the file is refused (a share above it is).
#: A trainer's divergent Gaussians are rare: a handful in a model of 10^4-10^6 rows, far below 1 %.
#: Past 1 % the file itself is broken (a damaged chunk of a compressed PLY is 256 rows at once, a
#: writer of the wrong type or byte order breaks most rows), its other rows cannot be trusted either,
#: and what is left of it is no longer the model that was trained.
#: A file whose every row is broken is refused at any limit.
MAX_LEFT_OUT_SHARE = 0.01
#: The row indices a record keeps (the first ones, in the file's order).
ROWS_NAMED = 5
#: Each checked field of a :class:`~stealth_ns.gaussians.ply.GaussianCloud`, as a reason names it.
FIELD_NAMES: dict[str, str] = {
    "means": "centre",
    "log_scales": "scale",
    "quats": "rotation",
    "opacity_logits": "opacity",
    "sh_dc": "colour (SH degree 0)",
    "sh_rest": "colour (higher SH)",
}
#: The reason of a rotation quaternion of length 0.
ZERO_ROTATION = "zero rotation"


@dataclass(frozen=True)
class RowsLeftOut:
    """What a reader left out of a model file."""

    count: int
    """Rows left out."""
    total: int
    """Rows in the file."""
    reasons: dict[str, int]
    """Reason -> rows with it (``NaN or infinite centre``..., ``zero rotation``); a row may have several."""
    rows: tuple[int, ...]
    """The first :data:`ROWS_NAMED` rows left out, as indices into the file."""

    @property
    def share(self) -> float:
        return self.count / self.total if self.total else 0.0

    def line(self) -> str:
        """One line for the terminal: ``left out 3 of 120,000 Gaussians (0.0025%, at most 1%): NaN or
        infinite centre (2), zero rotation (1); rows 5, 17, 99``."""
        reasons = ", ".join(f"{r} ({n:,})" for r, n in self.reasons.items())
        return (
            f"left out {self.count:,} of {self.total:,} Gaussians ({_percent(self.share)}, at most "
            f"{_percent(MAX_LEFT_OUT_SHARE)}): {reasons}; rows {self.row_list()}"
        )

    def row_list(self) -> str:
        """The rows named, ``5, 17, 99`` (``, ...`` after them when more were left out)."""
        return ", ".join(str(i) for i in self.rows) + (", ..." if self.count > len(self.rows) else "")

    def record(self) -> dict[str, Any]:
        """As scan.json records it."""
        return {**dataclasses.asdict(self), "rows": list(self.rows), "limit_share": MAX_LEFT_OUT_SHARE}


def _percent(share: float) -> str:
    return f"{100 * share:.3g}%"


def find_broken_rows(fields: Mapping[str, np.ndarray]) -> tuple[np.ndarray, RowsLeftOut]:
    """``[N]`` bool, the broken rows, and their record (``count`` 0 when none is), of a cloud's
    :data:`FIELD_NAMES` arrays (``fields``: name -> ``[N, ...]``). Pure: refuses nothing."""
    n = len(fields["means"])
    broken = np.zeros(n, dtype=bool)
    reasons: dict[str, int] = {}
    for name, label in FIELD_NAMES.items():
        bad = ~np.isfinite(fields[name].reshape(n, -1)).all(axis=1)
        broken |= bad
        reasons[f"NaN or infinite {label}"] = int(bad.sum())
    with np.errstate(invalid="ignore", over="ignore"):  # a NaN quaternion is counted above
        zero = np.linalg.norm(fields["quats"].astype(np.float64), axis=1) == 0
    broken |= zero
    reasons[ZERO_ROTATION] = int(zero.sum())
    rows = np.flatnonzero(broken)
    record = RowsLeftOut(
        int(rows.size), n, {r: c for r, c in reasons.items() if c}, tuple(int(i) for i in rows[:ROWS_NAMED])
    )
    return broken, record


def check_left_out(path: Path, record: RowsLeftOut) -> None:
    """StealthNSError with one line, naming the file ``path``, when more than :data:`MAX_LEFT_OUT_SHARE`
    of its rows, or every row, are broken."""
    if record.count < record.total and record.share <= MAX_LEFT_OUT_SHARE:
        return
    why = (
        "every row is broken"
        if record.count == record.total
        else f"{_percent(record.share)} of its rows, more than the {_percent(MAX_LEFT_OUT_SHARE)} "
        "a reader leaves out"
    )
    raise StealthNSError(
        f"{path}: {record.count:,} of {record.total:,} Gaussians have a NaN, infinite or zero-rotation "
        f"value (rows {record.row_list()}): {why}; the file is broken (docs/design/scan.md)"
    )
