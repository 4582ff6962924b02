"""antimatter15's ``.splat``: a headerless run of 32-byte rows, one per Gaussian (little-endian).

The format of antimatter15's WebGL viewer, written by gsplat's exporter (``format="splat"``), SuperSplat
and many web tools:

=========  ==========  ==========================================================================
bytes      type        what
=========  ==========  ==========================================================================
0-11       float32 x3  centre x y z (scene units, the frame of the PLY it came from)
12-23      float32 x3  per-axis standard deviation, **linear** (the PLY's ``exp(scale_i)``)
24-27      uint8 x4    colour r g b (``255 * (0.5 + SH_C0 * f_dc)``) and opacity (``255 * sigmoid``)
28-31      uint8 x4    rotation w x y z of the unit quaternion, ``128 + 128 * q`` (clipped to 255)
=========  ==========  ==========================================================================

What it loses (:mod:`~stealth_ns.gaussians.quantisation` states the shared conventions): every SH
coefficient above degree 0 (a cloud reads back with ``sh_rest`` of shape ``[N, 0, 3]``); colour and
opacity to 8 bits, the colour clipped to ``[0, 1]``; the rotation to 8 bits a component (error up to
1/256 of the unit quaternion); the other PLY properties (:attr:`GaussianCloud.extra`, e.g. ``poison``).
Centres are exact; scales go through float32 ``exp`` / ``log`` (relative error ~1e-7). Rows keep their
order (gsplat's exporter sorts them along a Morton curve; this writer does not).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.ply import GaussianCloud, checked_rows
from stealth_ns.gaussians.quantisation import (
    code_of,
    colour_of_dc,
    dc_of_colour,
    opacity_codes,
    opacity_logits,
    read_model_bytes,
    round_half_away,
    unit_quats,
)

#: Bytes of one row.
ROW_BYTES = 32
#: One row, as numpy reads it.
ROW = np.dtype([("mean", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])


def read_splat(path: Path) -> GaussianCloud:
    """Read a ``.splat`` file. StealthNSError with one line when it is missing, empty, not a whole
    number of 32-byte rows (a truncated download), or has too many broken rows (rows with a NaN or
    infinite value or a non-positive scale are left out: :mod:`~stealth_ns.gaussians.broken_rows`)."""
    path = Path(path)
    raw = read_model_bytes(path, ".splat")
    if not raw:
        raise StealthNSError(f"{path} holds no Gaussians (an empty .splat file)")
    if len(raw) % ROW_BYTES:
        raise StealthNSError(
            f"{path}: {len(raw)} bytes is not a whole number of 32-byte .splat rows "
            f"({len(raw) // ROW_BYTES} rows and {len(raw) % ROW_BYTES} bytes over: a truncated file?)"
        )
    rows = np.frombuffer(raw, dtype=ROW)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.log(rows["scale"].astype(np.float64))
    rgba = rows["rgba"]
    cloud = GaussianCloud(
        means=rows["mean"].astype(np.float32),
        log_scales=log_scales.astype(np.float32),
        quats=((rows["rot"].astype(np.float64) - 128) / 128).astype(np.float32),
        opacity_logits=opacity_logits(rgba[:, 3]).astype(np.float32),
        sh_dc=dc_of_colour(rgba[:, :3] / 255).astype(np.float32),
        sh_rest=np.zeros((len(rows), 0, 3), np.float32),
    )
    return checked_rows(path, cloud)


def splat_rows(cloud: GaussianCloud) -> np.ndarray:
    """``[N]`` rows of :data:`ROW` holding ``cloud`` (its SH above degree 0 and extras left out)."""
    rows = np.zeros(len(cloud), dtype=ROW)
    rows["mean"] = cloud.means
    rows["scale"] = np.exp(cloud.log_scales.astype(np.float64))
    rows["rgba"][:, :3] = code_of(colour_of_dc(cloud.sh_dc), 8)
    rows["rgba"][:, 3] = opacity_codes(cloud.opacity_logits.reshape(-1))
    rows["rot"] = np.clip(round_half_away(unit_quats(cloud.quats) * 128 + 128), 0, 255)
    return rows


def write_splat(path: Path, cloud: GaussianCloud) -> None:
    """Write ``cloud`` as a ``.splat`` file, rows in the cloud's order."""
    Path(path).write_bytes(splat_rows(cloud).tobytes())
