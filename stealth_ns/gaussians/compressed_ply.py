"""The compressed PLY of PlayCanvas (SuperSplat, splat-transform; gsplat's exporter writes it as
``format="ply_compressed"``), usually named ``*.compressed.ply``: three PLY elements, binary
little-endian, the Gaussians cut into chunks of :data:`CHUNK_SIZE` consecutive rows.

=============  ========================================================================================
element        properties
=============  ========================================================================================
``chunk``      one per 256 rows (the last may be short), float32: the chunk's bounds ``min_x min_y
               min_z max_x max_y max_z`` of the centres, ``min_scale_x .. max_scale_z`` of the log
               scales and, in the 18-property layout, ``min_r min_g min_b max_r max_g max_b`` of the
               colours (the older 12-property layout has none: colours span ``[0, 1]``)
``vertex``     one per Gaussian, uint32: ``packed_position`` and ``packed_scale`` (x, y, z of the
               value within its chunk's bounds, 11, 10 and 11 bits, x in the top bits),
               ``packed_color`` (r, g, b within the chunk's colour bounds and the opacity
               ``sigmoid(logit)``, 8 bits each, r in the top byte), ``packed_rotation`` ("smallest
               three": the top 2 bits name the largest component of the unit quaternion w x y z,
               made positive and left out; the other three, in order, 10 bits each over
               ``[-1/sqrt 2, 1/sqrt 2]``)
``sh``         (optional) one per Gaussian: ``f_rest_0 .. f_rest_{3K-1}`` uchar, channel-major as
               in the standard PLY (:mod:`~stealth_ns.gaussians.ply`), the value ``v`` coded as
               ``floor((v / 8 + 0.5) * 256)`` and read as the bucket centre ``((q + 0.5) / 256 - 0.5)
               * 8`` (codes 0 and 255 read as -4 and +4)
=============  ========================================================================================

What it loses (conventions in :mod:`~stealth_ns.gaussians.quantisation`): a centre to half a step of
its chunk's extent (2047 steps in x and z, 1023 in y), a log scale likewise within its chunk's range;
the colour to 8 bits of its chunk's range, the opacity to 8 bits; the rotation to 10 bits a component
(error up to ~7e-4); the higher SH to 8 bits over ``[-4, 4]`` (error up to 1/64, values outside
clipped); the other PLY properties (:attr:`GaussianCloud.extra`, e.g. ``poison``). Rows keep their order
(gsplat's exporter sorts them along a Morton curve and drops those with opacity under 1/255; this
writer does neither).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.ply import GaussianCloud, checked_rows, open_ply
from stealth_ns.gaussians.quantisation import (
    code_of,
    colour_of_dc,
    dc_of_colour,
    opacity_codes,
    opacity_logits,
    unit_quats,
    value_of,
)

#: Rows per chunk.
CHUNK_SIZE = 256
#: The chunk properties every compressed PLY has.
CHUNK_BOUNDS: tuple[str, ...] = (
    *(f"{end}_{a}" for end in ("min", "max") for a in "xyz"),
    *(f"{end}_scale_{a}" for end in ("min", "max") for a in "xyz"),
)
#: The chunk properties of the 18-property layout (colour bounds).
CHUNK_COLOURS: tuple[str, ...] = tuple(f"{end}_{c}" for end in ("min", "max") for c in "rgb")
#: The vertex properties.
PACKED: tuple[str, ...] = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
#: The smallest-three code's three stored components, by the index of the largest one.
_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def ply_element_names(path: Path) -> list[str]:
    """The element names in the header of the PLY file at ``path`` (empty when it is none)."""
    try:
        with open(path, "rb") as file:
            head = file.read(1 << 16)
    except OSError:
        return []
    if not head.startswith(b"ply"):
        return []
    end = head.find(b"end_header")
    lines = head[: end if end >= 0 else len(head)].splitlines()
    return [line.split()[1].decode("ascii", "replace") for line in lines if line.startswith(b"element ")]


def is_compressed_ply(path: Path) -> bool:
    """Whether the PLY at ``path`` is a compressed one (its header has a ``chunk`` element)."""
    return "chunk" in ply_element_names(path)


def read_compressed_ply(path: Path) -> GaussianCloud:
    """Read a compressed PLY. StealthNSError with one line when the file is missing or not a PLY, lacks
    the ``chunk`` or ``vertex`` element or one of their properties, has a chunk count that does not fit
    its Gaussians, an ``sh`` element of no SH degree 1-3 or of another length, or too many broken rows
    (rows with a NaN or infinite value are left out: :mod:`~stealth_ns.gaussians.broken_rows`)."""
    path = Path(path)
    ply = open_ply(path, "compressed PLY")
    elements = {e.name: e for e in ply.elements}
    for name in ("chunk", "vertex"):
        if name not in elements:
            raise StealthNSError(
                f"{path} is a compressed PLY without its '{name}' element (it needs chunk and vertex)"
            )
    chunk_names = set(elements["chunk"].data.dtype.names or ())
    with_colours = any(p in chunk_names for p in CHUNK_COLOURS)
    chunk = _columns(path, elements["chunk"], CHUNK_BOUNDS + (CHUNK_COLOURS if with_colours else ()))
    packed = _columns(path, elements["vertex"], PACKED, np.uint32)
    n = int(elements["vertex"].count)
    if n == 0:
        raise StealthNSError(f"{path} holds no Gaussians (element vertex 0)")
    if int(elements["chunk"].count) != -(-n // CHUNK_SIZE):
        raise StealthNSError(
            f"{path}: {elements['chunk'].count} chunks for {n} Gaussians "
            f"(a compressed PLY has one per {CHUNK_SIZE}: {-(-n // CHUNK_SIZE)})"
        )
    sh_rest = _sh_rest(path, elements["sh"].data if "sh" in elements else None, n)
    cloud = _decoded(chunk, packed, with_colours, sh_rest)
    return checked_rows(path, cloud)


def _columns(
    path: Path, element: Any, names: tuple[str, ...], dtype: type = np.float64
) -> dict[str, np.ndarray]:
    """The properties ``names`` of a plyfile ``element``, as ``dtype`` arrays."""
    data = element.data
    present = set(data.dtype.names or ())
    missing = [p for p in names if p not in present]
    if missing:
        raise StealthNSError(
            f"{path}: the compressed PLY's '{element.name}' element lacks {', '.join(missing)}"
        )
    return {p: np.asarray(data[p]).astype(dtype) for p in names}


def _sh_rest(path: Path, data: np.ndarray | None, n: int) -> np.ndarray:
    """``[N, K, 3]`` the higher SH of the ``sh`` element's rows (K = 0 without one, or with one of no
    properties, as gsplat's exporter writes for SH degree 0)."""
    if data is None or not data.dtype.names:
        return np.zeros((n, 0, 3), np.float32)
    names = set(data.dtype.names or ())
    m = len(names)
    if m not in (9, 24, 45) or any(f"f_rest_{i}" not in names for i in range(m)):
        raise StealthNSError(
            f"{path}: the compressed PLY's 'sh' element has {m} properties, which fit no SH degree 1-3 "
            "(need f_rest_0.. numbered from 0, 9, 24 or 45 of them)"
        )
    if len(data) != n:
        raise StealthNSError(
            f"{path}: the compressed PLY's 'sh' element has {len(data)} rows for {n} Gaussians"
        )
    codes = np.stack([np.asarray(data[f"f_rest_{i}"], np.float64) for i in range(m)], axis=-1)
    unit = np.where(codes == 0, 0.0, np.where(codes == 255, 1.0, (codes + 0.5) / 256))
    return ((unit - 0.5) * 8).reshape(n, 3, m // 3).transpose(0, 2, 1).astype(np.float32)


def _bounds(chunk: dict[str, np.ndarray], prefix: str, axes: str) -> tuple[np.ndarray, np.ndarray]:
    """``[C, 3]`` lower and upper bounds of the chunk properties ``min_{prefix}{a}`` / ``max_...``."""
    low = np.stack([chunk[f"min_{prefix}{a}"] for a in axes], axis=-1)
    return low, np.stack([chunk[f"max_{prefix}{a}"] for a in axes], axis=-1)


def _unpack_111011(packed: np.ndarray) -> np.ndarray:
    """``[N, 3]`` unit values of 11-10-11-bit codes (float64)."""
    parts = (value_of(packed >> 21, 11), value_of((packed >> 11) & 0x3FF, 10), value_of(packed & 0x7FF, 11))
    return np.stack(parts, axis=-1)


def _unpack_rotation(packed: np.ndarray) -> np.ndarray:
    """``[N, 4]`` unit quaternions w x y z of smallest-three codes (float64)."""
    n = len(packed)
    fields = [(packed >> shift) & 0x3FF for shift in (20, 10, 0)]
    others = (value_of(np.stack(fields, axis=-1), 10) - 0.5) * np.sqrt(2)
    largest = (packed >> 30).astype(np.int64)
    quats = np.zeros((n, 4))
    quats[np.arange(n)[:, None], _OTHERS[largest]] = others
    quats[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - (others**2).sum(axis=1)))
    return quats


def _decoded(
    chunk: dict[str, np.ndarray], packed: dict[str, np.ndarray], with_colours: bool, sh_rest: np.ndarray
) -> GaussianCloud:
    n = len(packed["packed_position"])
    rows = np.arange(n) // CHUNK_SIZE

    def lerp(bounds: tuple[np.ndarray, np.ndarray], unit: np.ndarray) -> np.ndarray:
        return bounds[0][rows] * (1 - unit) + bounds[1][rows] * unit

    colour = packed["packed_color"]
    rgb = np.stack([value_of((colour >> shift) & 0xFF, 8) for shift in (24, 16, 8)], axis=-1)
    means = lerp(_bounds(chunk, "", "xyz"), _unpack_111011(packed["packed_position"]))
    log_scales = lerp(_bounds(chunk, "scale_", "xyz"), _unpack_111011(packed["packed_scale"]))
    return GaussianCloud(
        means=means.astype(np.float32),
        log_scales=log_scales.astype(np.float32),
        quats=_unpack_rotation(packed["packed_rotation"]).astype(np.float32),
        opacity_logits=opacity_logits(colour & 0xFF).astype(np.float32),
        sh_dc=dc_of_colour(lerp(_bounds(chunk, "", "rgb"), rgb) if with_colours else rgb).astype(np.float32),
        sh_rest=sh_rest,
    )


def _chunk_bounds(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[C, 3]`` per-chunk minimum and maximum of ``[N, 3]`` values (N > 0), as the file's float32
    holds them."""
    starts = np.arange(0, len(values), CHUNK_SIZE)
    low, high = np.minimum.reduceat(values, starts, axis=0), np.maximum.reduceat(values, starts, axis=0)
    return low.astype(np.float32).astype(np.float64), high.astype(np.float32).astype(np.float64)


def _unit_in_chunks(values: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``[N, 3]`` values as fractions of their chunk's bounds (0 where the bounds meet)."""
    rows = np.arange(len(values)) // CHUNK_SIZE
    low, span = bounds[0][rows], (bounds[1] - bounds[0])[rows]
    return np.where(span > 0, (values - low) / np.where(span > 0, span, 1.0), 0.0)


def _pack_111011(values: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``[N]`` 11-10-11-bit codes of ``[N, 3]`` values within their chunk's bounds."""
    unit = _unit_in_chunks(values, bounds)
    return (code_of(unit[:, 0], 11) << 21) | (code_of(unit[:, 1], 10) << 11) | code_of(unit[:, 2], 11)


def _pack_rotation(quats: np.ndarray) -> np.ndarray:
    """``[N]`` smallest-three codes of ``[N, 4]`` quaternions w x y z."""
    quats = unit_quats(quats)
    n = len(quats)
    largest = np.argmax(np.abs(quats), axis=1)
    quats = quats * np.where(quats[np.arange(n), largest] < 0, -1.0, 1.0)[:, None]
    codes = code_of(quats[np.arange(n)[:, None], _OTHERS[largest]] / np.sqrt(2) + 0.5, 10)
    return (largest.astype(np.uint32) << 30) | (codes[:, 0] << 20) | (codes[:, 1] << 10) | codes[:, 2]


def compressed_ply_tables(cloud: GaussianCloud) -> dict[str, np.ndarray]:
    """The ``chunk``, ``vertex`` and (with SH above degree 0) ``sh`` rows of ``cloud``, as structured
    arrays in the 18-property layout."""
    n, k = len(cloud), cloud.sh_rest.shape[1]
    means, scales = cloud.means.astype(np.float64), cloud.log_scales.astype(np.float64)
    colours = colour_of_dc(cloud.sh_dc)
    bounds = [_chunk_bounds(v) if n else (np.zeros((0, 3)),) * 2 for v in (means, scales, colours)]
    chunk = np.zeros(len(bounds[0][0]), dtype=[(p, "<f4") for p in CHUNK_BOUNDS + CHUNK_COLOURS])
    for (low, high), prefix, axes in zip(bounds, ("", "scale_", ""), ("xyz", "xyz", "rgb"), strict=True):
        for i, a in enumerate(axes):
            chunk[f"min_{prefix}{a}"], chunk[f"max_{prefix}{a}"] = low[:, i], high[:, i]
    vertex = np.zeros(n, dtype=[(p, "<u4") for p in PACKED])
    vertex["packed_position"] = _pack_111011(means, bounds[0])
    vertex["packed_scale"] = _pack_111011(scales, bounds[1])
    vertex["packed_rotation"] = _pack_rotation(cloud.quats)
    unit = _unit_in_chunks(colours, bounds[2])
    rgb = [code_of(unit[:, i], 8) for i in range(3)]
    vertex["packed_color"] = (
        (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | opacity_codes(cloud.opacity_logits.reshape(n))
    )
    tables = {"chunk": chunk, "vertex": vertex}
    if k:
        rest = cloud.sh_rest.astype(np.float64).transpose(0, 2, 1).reshape(n, 3 * k)
        sh = np.zeros(n, dtype=[(f"f_rest_{i}", "u1") for i in range(3 * k)])
        for i in range(3 * k):
            sh[f"f_rest_{i}"] = np.clip(np.floor((rest[:, i] / 8 + 0.5) * 256), 0, 255)
        tables["sh"] = sh
    return tables


def write_compressed_ply(path: Path, cloud: GaussianCloud, comment: str = "stealth-ns") -> None:
    """Write ``cloud`` as a compressed PLY (18-property chunks; an ``sh`` element when it has SH above
    degree 0), rows in the cloud's order."""
    from plyfile import PlyData, PlyElement

    elements = [PlyElement.describe(rows, name) for name, rows in compressed_ply_tables(cloud).items()]
    PlyData(elements, text=False, byte_order="<", comments=[comment]).write(str(path))
