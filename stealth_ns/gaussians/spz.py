"""Niantic's ``.spz``, versions 2 and 3: one gzip stream holding a 16-byte header and the Gaussians'
attributes one after another (little-endian; N Gaussians, SH degree d, D = (d + 1)^2 - 1).

==================  ==============  ========================================================================
part                bytes           what
==================  ==============  ========================================================================
header              16              magic ``NGSP`` (0x5053474e), uint32 version, uint32 N, uint8 d,
                                    uint8 fractional bits F, uint8 flags (1: antialiased), uint8 0
positions           9 N             x y z of each centre, 24-bit two's complement fixed point, ``/ 2^F``
alphas              N               opacity, ``255 * sigmoid(logit)``
colours             3 N             ``f_dc * 0.15 * 255 + 127.5`` (SH degree 0, a wider range than 8-bit
                                    colour)
scales              3 N             ``(log scale + 10) * 16`` (log scales -10 .. 5.94 in steps of 1/16)
rotations           3 N (v2)        v2: x y z of the unit quaternion made ``w >= 0``, ``127.5 * (q + 1)``;
                    4 N (v3)        v3: "smallest three", a uint32: top 2 bits the index (in x y z w) of
                                    the largest component, left out and made positive; then the other
                                    three in order, each a sign bit and 9 bits of ``|q| / sqrt(1/2)``
sh                  3 D N           the higher SH, coefficient-major with the channel fastest (the
                                    order of :attr:`GaussianCloud.sh_rest`), ``128 + 128 * v`` (clipped)
==================  ==============  ========================================================================

**Frame.** SPZ stores its Gaussians in the RUB frame (x right, y up, z back), a PLY in RDF (y down,
z front): reading turns them half a turn about x into the PLY's frame (``y, z -> -y, -z``: the centres,
the quaternions' ``y z`` and the SH coefficients odd in y or z change sign) and writing turns them back,
as Niantic's converters do between ``.ply`` and ``.spz``. A file written without the conversion (an
``UNSPECIFIED`` coordinate system) reads upside down.

What it loses (conventions in :mod:`~stealth_ns.gaussians.quantisation`): a centre to 1/4096 of a unit
(F = 12; a scene reaching beyond 2048 units from the origin gets fewer fractional bits); a log scale to
1/32, clipped to -10 .. 5.94; the colour to 8 bits over ``f_dc`` in ``[-3.33, 3.33]``; the opacity to 8
bits; the rotation to 9 bits a component (v3) or 8 bits (v2, whose reconstructed w is coarse when small);
the higher SH to 1/256 over ``[-1, 1]`` (values outside clipped: this writer keeps all 8 bits, where
Niantic's rounds degree 1 to 5 bits and higher degrees to 4 for a smaller file); the antialiased flag
and any extensions (ignored on read); the other PLY properties (:attr:`GaussianCloud.extra`).

Version 4 (an uncompressed ``NGSP`` header and zstd-compressed streams) and version 1 (float16 centres,
never released) are refused with one line.
"""

from __future__ import annotations

import gzip
import struct
import zlib
from pathlib import Path

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.ply import GaussianCloud, checked_rows
from stealth_ns.gaussians.quantisation import (
    opacity_codes,
    opacity_logits,
    read_model_bytes,
    round_half_away,
    unit_quats,
)

MAGIC = 0x5053474E
#: The versions read and written.
VERSIONS: tuple[int, ...] = (2, 3)
#: magic, version, N, SH degree, fractional bits, flags, reserved.
HEADER = struct.Struct("<IIIBBBB")
#: ``f_dc`` to 8-bit colour: ``f_dc * COLOUR_SCALE * 255 + 127.5``.
COLOUR_SCALE = 0.15
#: Fractional bits of the centres written (1/4096 of a unit), fewer for a scene that needs them.
FRACTIONAL_BITS = 12
#: Sign of each SH coefficient above degree 0 (3DGS order, degrees 1-3) under ``y, z -> -y, -z``.
SH_FLIP = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], dtype=np.float64)
#: The smallest-three code's three stored components, by the index of the largest one (x y z w).
_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
_SQRT1_2 = np.sqrt(0.5)


def read_spz(path: Path) -> GaussianCloud:
    """Read an ``.spz`` file (version 2 or 3). StealthNSError with one line when the file is missing,
    neither gzip nor SPZ, a broken gzip stream, of a bad magic, another version or an SH degree above 3,
    cut short, without Gaussians, or has too many broken rows (rows with a NaN or infinite value are
    left out: :mod:`~stealth_ns.gaussians.broken_rows`)."""
    path = Path(path)
    payload = _payload(path, read_model_bytes(path, ".spz"))
    if len(payload) < HEADER.size:
        raise StealthNSError(f"{path}: its SPZ header is cut short ({len(payload)} of 16 bytes after gunzip)")
    magic, version, n, degree, fractional_bits, _, _ = HEADER.unpack_from(payload)
    if magic != MAGIC:
        raise StealthNSError(
            f"{path}: bad SPZ magic {payload[:4]!r} (an .spz file starts with NGSP once gunzipped)"
        )
    if version not in VERSIONS:
        raise _version_error(path, version)
    if n == 0:
        raise StealthNSError(f"{path} holds no Gaussians (an SPZ of 0 points)")
    if degree > 3:
        raise StealthNSError(f"{path}: SH degree {degree} is not supported (stealth-ns reads degrees 0-3)")
    sections = _sections(path, payload, version, n, (degree + 1) ** 2 - 1)
    cloud = _decoded(sections, version, fractional_bits)
    return checked_rows(path, cloud)


def _version_error(path: Path, version: int | None) -> StealthNSError:
    if version == 4:
        return StealthNSError(
            f"{path}: SPZ version 4 (zstd-compressed streams) is not supported: stealth-ns reads versions "
            "2 and 3 (gzip); save the model as version 3"
        )
    return StealthNSError(
        f"{path}: SPZ version {version} is not supported (stealth-ns reads versions 2 and 3)"
    )


def _payload(path: Path, raw: bytes) -> bytes:
    """The gunzipped bytes of an ``.spz`` file."""
    if raw[:2] == b"\x1f\x8b":
        try:
            return gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as err:
            raise StealthNSError(
                f"{path}: its gzip stream is broken ({err}): a truncated .spz file?"
            ) from None
    if raw[:4] == b"NGSP":
        raise _version_error(path, int.from_bytes(raw[4:8], "little") if len(raw) >= 8 else None)
    raise StealthNSError(f"{path} is not an SPZ file (neither gzip-compressed nor starting with NGSP)")


def _sections(path: Path, payload: bytes, version: int, n: int, dim: int) -> dict[str, np.ndarray]:
    """The attribute bytes after the header, each ``[N, bytes per Gaussian]`` (uint8)."""
    widths = {"positions": 9, "alphas": 1, "colours": 3, "scales": 3, "rotations": 3 if version == 2 else 4}
    widths["sh"] = 3 * dim
    need = HEADER.size + n * sum(widths.values())
    if len(payload) < need:
        raise StealthNSError(
            f"{path}: its SPZ data is cut short ({n} Gaussians need {need} bytes after gunzip, it has "
            f"{len(payload)})"
        )
    sections, offset = {}, HEADER.size
    for name, width in widths.items():
        sections[name] = np.frombuffer(payload, np.uint8, n * width, offset).reshape(n, width)
        offset += n * width
    return sections


def _decoded(sections: dict[str, np.ndarray], version: int, fractional_bits: int) -> GaussianCloud:
    n = len(sections["alphas"])
    raw = sections["positions"].reshape(n, 3, 3).astype(np.int64)
    fixed = raw[..., 0] | (raw[..., 1] << 8) | (raw[..., 2] << 16)
    means = np.where(fixed & 0x800000, fixed - (1 << 24), fixed) / float(1 << fractional_bits)
    rotations = sections["rotations"]
    xyzw = _first_three(rotations) if version == 2 else _smallest_three(rotations.copy().view("<u4")[:, 0])
    sh = (sections["sh"].reshape(n, -1, 3).astype(np.float64) - 128) / 128
    return _turned(
        GaussianCloud(
            means=means.astype(np.float32),
            log_scales=(sections["scales"] / 16 - 10).astype(np.float32),
            quats=xyzw[:, [3, 0, 1, 2]].astype(np.float32),
            opacity_logits=opacity_logits(sections["alphas"][:, 0]).astype(np.float32),
            sh_dc=((sections["colours"] / 255 - 0.5) / COLOUR_SCALE).astype(np.float32),
            sh_rest=sh.astype(np.float32),
        )
    )


def _first_three(codes: np.ndarray) -> np.ndarray:
    """``[N, 4]`` unit quaternions x y z w of version 2's ``[N, 3]`` codes (w >= 0)."""
    xyz = codes.astype(np.float64) / 127.5 - 1
    return np.concatenate([xyz, np.sqrt(np.maximum(0.0, 1 - (xyz**2).sum(axis=1)))[:, None]], axis=1)


def _smallest_three(packed: np.ndarray) -> np.ndarray:
    """``[N, 4]`` unit quaternions x y z w of version 3's ``[N]`` smallest-three codes."""
    n = len(packed)
    fields = np.stack([(packed >> shift) & 0x3FF for shift in (20, 10, 0)], axis=-1)
    others = _SQRT1_2 * (fields & 0x1FF) / 511 * np.where(fields & 0x200, -1.0, 1.0)
    largest = (packed >> 30).astype(np.int64)
    quats = np.zeros((n, 4))
    quats[np.arange(n)[:, None], _OTHERS[largest]] = others
    quats[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1 - (others**2).sum(axis=1)))
    return quats


def _turned(cloud: GaussianCloud) -> GaussianCloud:
    """``cloud`` turned half a turn about x (``y, z -> -y, -z``): RUB <-> RDF, its own inverse."""
    k = cloud.sh_rest.shape[1]
    return GaussianCloud(
        means=cloud.means * np.array([1, -1, -1], np.float32),
        log_scales=cloud.log_scales,
        quats=cloud.quats * np.array([1, 1, -1, -1], np.float32),
        opacity_logits=cloud.opacity_logits,
        sh_dc=cloud.sh_dc,
        sh_rest=cloud.sh_rest * SH_FLIP[:k].astype(np.float32)[None, :, None],
        extra=cloud.extra,
    )


def _fractional_bits(path: Path, means: np.ndarray) -> int:
    """:data:`FRACTIONAL_BITS`, or fewer when a centre would not fit 24 bits with them."""
    reach = float(np.abs(means).max()) if means.size else 0.0
    bits = FRACTIONAL_BITS
    while bits > 0 and reach * (1 << bits) > (1 << 23) - 1:
        bits -= 1
    if reach > (1 << 23) - 1:
        raise StealthNSError(
            f"cannot write {path}: a centre lies {reach:.3g} units from the origin, beyond the 24-bit "
            "fixed point of .spz (8388607)"
        )
    return bits


def _pack_smallest_three(xyzw: np.ndarray) -> np.ndarray:
    """``[N, 4]`` uint8: version 3's codes of unit quaternions x y z w, little-endian."""
    n = len(xyzw)
    largest = np.argmax(np.abs(xyzw), axis=1)
    negate = xyzw[np.arange(n), largest] < 0
    others = xyzw[np.arange(n)[:, None], _OTHERS[largest]]
    magnitude = np.minimum(np.floor(511 * np.abs(others) / _SQRT1_2 + 0.5), 511).astype(np.uint32)
    fields = (((others < 0) ^ negate[:, None]).astype(np.uint32) << 9) | magnitude
    packed = (largest.astype(np.uint32) << 30) | (fields[:, 0] << 20) | (fields[:, 1] << 10) | fields[:, 2]
    return packed.astype("<u4").view(np.uint8).reshape(n, 4)


def _pack_first_three(xyzw: np.ndarray) -> np.ndarray:
    """``[N, 3]`` uint8: version 2's codes of unit quaternions x y z w (turned to w >= 0)."""
    signed = xyzw * np.where(xyzw[:, 3:] < 0, -1.0, 1.0)
    return np.clip(round_half_away(signed[:, :3] * 127.5 + 127.5), 0, 255).astype(np.uint8)


def _byte(values: np.ndarray) -> np.ndarray:
    return np.clip(round_half_away(values), 0, 255).astype(np.uint8)


def spz_bytes(path: Path, cloud: GaussianCloud, version: int = 3) -> bytes:
    """The uncompressed SPZ payload (header and attributes) of ``cloud``; ``path`` names the file in
    the one-line error for an SH degree above 3 or a centre beyond the fixed point's reach."""
    if version not in VERSIONS:
        raise ValueError(f"SPZ version {version}: stealth-ns writes versions {VERSIONS}")
    n, k = len(cloud), cloud.sh_rest.shape[1]
    degree = int(round(np.sqrt(k + 1))) - 1
    if (degree + 1) ** 2 - 1 != k or degree > 3:
        raise StealthNSError(f"cannot write {path}: {k} SH coefficients a channel fit no SH degree 0-3")
    turned = _turned(cloud)
    means = turned.means.astype(np.float64)
    bits = _fractional_bits(path, means)
    fixed = round_half_away(means * (1 << bits)).astype(np.int64) & 0xFFFFFF
    positions = np.stack([(fixed >> shift) & 0xFF for shift in (0, 8, 16)], axis=-1).astype(np.uint8)
    xyzw = unit_quats(turned.quats)[:, [1, 2, 3, 0]]
    parts = [
        HEADER.pack(MAGIC, version, n, degree, bits, 0, 0),
        positions.tobytes(),
        opacity_codes(cloud.opacity_logits.reshape(n)).tobytes(),
        _byte(cloud.sh_dc.astype(np.float64) * (COLOUR_SCALE * 255) + 127.5).tobytes(),
        _byte((cloud.log_scales.astype(np.float64) + 10) * 16).tobytes(),
        (_pack_first_three(xyzw) if version == 2 else _pack_smallest_three(xyzw)).tobytes(),
        _byte(round_half_away(turned.sh_rest.astype(np.float64) * 128) + 128).tobytes(),
    ]
    return b"".join(parts)


def write_spz(path: Path, cloud: GaussianCloud, version: int = 3) -> None:
    """Write ``cloud`` as an ``.spz`` file of ``version`` (2 or 3), rows in the cloud's order."""
    Path(path).write_bytes(gzip.compress(spz_bytes(path, cloud, version), mtime=0))
