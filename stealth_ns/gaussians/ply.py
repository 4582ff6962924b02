"""The standard 3D Gaussian Splatting PLY: one ``vertex`` element, one row per Gaussian.

The layout the official 3DGS code writes, and gsplat, OpenSplat and ``ns-export gaussian-splat`` with
it (float32 unless said otherwise; other properties, such as the normals ``nx ny nz``, are ignored on
read and kept in :attr:`GaussianCloud.extra` when numeric):

==================  ========================================================================
``x y z``           centre, in the frame the trainer worked in (scene units)
``f_dc_0..2``       SH degree-0 coefficient per colour channel (colour = 0.5 + C0 * f_dc)
``f_rest_0..M-1``   the higher SH coefficients, **channel-major**: the K = (d + 1)^2 - 1
                    coefficients of red, then of green, then of blue (M = 3K; d = 0..3)
``opacity``         opacity logit (opacity = sigmoid)
``scale_0..2``      natural log of the per-axis standard deviation
``rot_0..3``        rotation quaternion w x y z (not necessarily normalised)
==================  ========================================================================

``ns-export`` of a stealth-splat run adds ``poison`` (uchar, 1 = injected; :mod:`stealth_ns.method.export`).
Rows with a NaN or infinite value are left out (:mod:`~stealth_ns.gaussians.broken_rows`); every reading
problem is one :class:`~stealth_ns.foundation.errors.StealthNSError` line naming the file.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.broken_rows import FIELD_NAMES, RowsLeftOut, check_left_out, find_broken_rows

REQUIRED: tuple[str, ...] = (
    "x",
    "y",
    "z",
    *(f"f_dc_{i}" for i in range(3)),
    "opacity",
    *(f"scale_{i}" for i in range(3)),
    *(f"rot_{i}" for i in range(4)),
)
#: Number of ``f_rest_*`` properties for SH degree 0..3.
REST_COUNTS: dict[int, int] = {d: 3 * ((d + 1) ** 2 - 1) for d in range(4)}
_LAYOUT = set(REQUIRED) | {"nx", "ny", "nz"}


@dataclass
class GaussianCloud:
    """The Gaussians of a model, as a PLY stores them (float32 numpy arrays, N rows)."""

    means: np.ndarray
    """``[N, 3]`` centres (scene units)."""
    log_scales: np.ndarray
    """``[N, 3]`` natural log of the per-axis standard deviations."""
    quats: np.ndarray
    """``[N, 4]`` rotations, w x y z."""
    opacity_logits: np.ndarray
    """``[N]`` opacity before the sigmoid."""
    sh_dc: np.ndarray
    """``[N, 3]`` SH degree-0 coefficients."""
    sh_rest: np.ndarray
    """``[N, K, 3]`` higher SH coefficients, coefficient-major (nerfstudio's ``features_rest``)."""
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    """Other numeric per-row properties of the file (e.g. ``poison``), ``[N]`` each."""
    left_out: RowsLeftOut | None = None
    """The broken rows the reader left out of the file (:mod:`~stealth_ns.gaussians.broken_rows`); None
    when it left out none, and on a cloud not read from a file (a subset, a moved cloud)."""

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh_rest.shape[1] + 1))) - 1

    def poison_mask(self) -> np.ndarray | None:
        """``[N]`` bool: the rows stealth-ns's ``poison`` tag marks; None when the cloud carries no tag, or
        one of another length than its rows."""
        tag = self.extra.get("poison")
        if tag is None or len(tag) != len(self):
            return None
        return np.asarray(tag) > 0

    def subset(self, rows: np.ndarray) -> GaussianCloud:
        """The rows selected by ``rows`` (a bool mask or indices); without :attr:`left_out`."""
        return GaussianCloud(
            self.means[rows],
            self.log_scales[rows],
            self.quats[rows],
            self.opacity_logits[rows],
            self.sh_dc[rows],
            self.sh_rest[rows],
            {k: v[rows] for k, v in self.extra.items()},
        )

    def without_broken_rows(self) -> tuple[GaussianCloud, RowsLeftOut]:
        """The cloud without its broken rows (:func:`~stealth_ns.gaussians.broken_rows.find_broken_rows`;
        the others in their order; the cloud itself when none is) and the record of what was left out."""
        broken, record = find_broken_rows({name: getattr(self, name) for name in FIELD_NAMES})
        return (self.subset(~broken) if record.count else self), record


def open_ply(path: Path, what: str) -> Any:
    """``path`` parsed by plyfile (a ``PlyData``); StealthNSError with one line when it is missing
    (``no WHAT file at PATH``) or not a readable PLY."""
    from plyfile import PlyData

    if not path.is_file():
        raise StealthNSError(f"no {what} file at {path}")
    try:
        return PlyData.read(str(path))
    except Exception as err:  # plyfile raises PlyParseError, ValueError, struct errors, EOFError...
        raise StealthNSError(f"{path} is not a readable PLY file ({type(err).__name__}: {err})") from None


def read_gaussian_ply(path: Path) -> GaussianCloud:
    """Read a 3DGS PLY (binary either endianness, or ASCII). StealthNSError with one line when the file
    is missing or not a PLY, has no ``vertex`` element, lacks a property of :data:`REQUIRED`, has an
    ``f_rest_*`` count of no SH degree 0-3, has no Gaussians, or too many broken rows (rows with a NaN
    or infinite value or a zero rotation are left out: :mod:`~stealth_ns.gaussians.broken_rows`)."""
    path = Path(path)
    ply = open_ply(path, "PLY")
    if "vertex" not in [e.name for e in ply.elements]:
        raise StealthNSError(f"{path} has no 'vertex' element: not a point or Gaussian PLY")
    vertex = ply["vertex"]
    try:
        names = set(vertex.data.dtype.names or ())
    except Exception as err:
        raise StealthNSError(f"{path}: its vertex data cannot be read ({err})") from None
    missing = [p for p in REQUIRED if p not in names]
    if missing:
        raise StealthNSError(
            f"{path} is not a 3D Gaussian Splatting PLY: it lacks {', '.join(missing[:6])}"
            + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
            + " (a 3DGS PLY has x y z, f_dc_0..2, f_rest_*, opacity, scale_0..2, rot_0..3)"
        )
    n_rest = sum(1 for p in names if p.startswith("f_rest_"))
    degree = next((d for d, m in REST_COUNTS.items() if m == n_rest), None)
    if degree is None or any(f"f_rest_{i}" not in names for i in range(n_rest)):
        raise StealthNSError(
            f"{path}: {n_rest} f_rest_* properties fit no SH degree 0-3 "
            "(need 0, 9, 24 or 45, numbered from 0)"
        )
    n = int(vertex.count)
    if n == 0:
        raise StealthNSError(f"{path} holds no Gaussians (element vertex 0)")
    return checked_rows(path, _cloud_of(vertex.data, degree, names))


def _column(data: np.ndarray, names: list[str]) -> np.ndarray:
    return np.stack([np.asarray(data[n], dtype=np.float32) for n in names], axis=-1)


def _cloud_of(data: np.ndarray, degree: int, names: set[str]) -> GaussianCloud:
    k = (degree + 1) ** 2 - 1
    rest = _column(data, [f"f_rest_{i}" for i in range(3 * k)]) if k else np.zeros((len(data), 0), np.float32)
    extra = {
        p: np.asarray(data[p])
        for p in sorted(names - _LAYOUT)
        if not p.startswith("f_rest_") and np.issubdtype(data.dtype[p], np.number)
    }
    return GaussianCloud(
        means=_column(data, ["x", "y", "z"]),
        log_scales=_column(data, [f"scale_{i}" for i in range(3)]),
        quats=_column(data, [f"rot_{i}" for i in range(4)]),
        opacity_logits=np.asarray(data["opacity"], dtype=np.float32),
        sh_dc=_column(data, [f"f_dc_{i}" for i in range(3)]),
        sh_rest=rest.reshape(len(data), 3, k).transpose(0, 2, 1).copy(),
        extra=extra,
    )


def checked_rows(path: Path, cloud: GaussianCloud) -> GaussianCloud:
    """What every reader returns of the ``cloud`` it decoded from ``path``: its broken rows left out, their
    record in :attr:`GaussianCloud.left_out` (None when none was); StealthNSError with one line when the
    file holds too many (:func:`~stealth_ns.gaussians.broken_rows.check_left_out`)."""
    kept, record = cloud.without_broken_rows()
    if record.count == 0:
        return cloud
    check_left_out(path, record)
    return dataclasses.replace(kept, left_out=record)


def write_gaussian_ply(path: Path, cloud: GaussianCloud, comment: str = "stealth-ns") -> None:
    """Write ``cloud`` in the standard layout (binary little-endian; ``nx ny nz`` zero, as the official
    code writes them), its :attr:`~GaussianCloud.extra` properties after the layout's."""
    from plyfile import PlyData, PlyElement

    n, k = len(cloud), cloud.sh_rest.shape[1]
    columns: list[tuple[str, np.ndarray]] = [(a, cloud.means[:, i]) for i, a in enumerate("xyz")]
    columns += [(a, np.zeros(n, np.float32)) for a in ("nx", "ny", "nz")]
    columns += [(f"f_dc_{i}", cloud.sh_dc[:, i]) for i in range(3)]
    rest = cloud.sh_rest.transpose(0, 2, 1).reshape(n, 3 * k)
    columns += [(f"f_rest_{i}", rest[:, i]) for i in range(3 * k)]
    columns += [("opacity", cloud.opacity_logits.reshape(n))]
    columns += [(f"scale_{i}", cloud.log_scales[:, i]) for i in range(3)]
    columns += [(f"rot_{i}", cloud.quats[:, i]) for i in range(4)]
    typed = [(name, "<f4", np.asarray(v, dtype=np.float32)) for name, v in columns]
    typed += [
        (name, np.asarray(v).dtype.newbyteorder("<").str, np.asarray(v)) for name, v in cloud.extra.items()
    ]
    rows = np.empty(n, dtype=[(name, dt) for name, dt, _ in typed])
    for name, _, values in typed:
        rows[name] = values
    element = PlyElement.describe(rows, "vertex")
    PlyData([element], text=False, byte_order="<", comments=[comment]).write(str(path))
