"""The codes the web model formats share (:mod:`~stealth_ns.gaussians.splat_file`,
:mod:`~stealth_ns.gaussians.compressed_ply`, :mod:`~stealth_ns.gaussians.spz`), with the conventions
every one of them follows:

* **colour**: a display colour ``c`` and the SH degree-0 coefficient are one value,
  ``c = 0.5 + SH_C0 * sh_dc`` (the 3DGS renderers' convention);
* **opacity in 8 bits**: the code is ``round(255 * sigmoid(logit))``; it reads back as the logit of
  ``code / 255``, the two end codes moved a quarter step inwards (``0 -> 0.25 / 255``,
  ``255 -> 254.75 / 255``) so that they read as finite logits which write back to the same code;
* **rounding**: half away from zero, as C's ``round`` (what the reference writers use);
* **unit-range codes**: ``t`` in ``[0, 1]`` to ``bits`` bits is ``clip(round(t * (2^bits - 1)))``, read
  back as ``code / (2^bits - 1)``: the error of a value is at most half a step of its range;
* **quaternions** are w x y z throughout (a format that stores x y z w is reordered on read and write).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stealth_ns.foundation.errors import StealthNSError

#: The SH degree-0 basis constant, ``1 / (2 sqrt(pi))``.
SH_C0 = 0.28209479177387814
#: Where the end opacity codes read (a quarter step inside ``[0, 1]``).
_OPACITY_END = 0.25 / 255


def round_half_away(values: np.ndarray) -> np.ndarray:
    """``values`` rounded to the nearest integer, halves away from zero (float64, same shape)."""
    values = np.asarray(values, dtype=np.float64)
    return np.sign(values) * np.floor(np.abs(values) + 0.5)


def code_of(values: np.ndarray, bits: int) -> np.ndarray:
    """Unit-range ``values`` (any shape) to ``bits``-bit codes (uint32, clipped to the range)."""
    top = (1 << bits) - 1
    return np.clip(round_half_away(np.asarray(values, np.float64) * top), 0, top).astype(np.uint32)


def value_of(codes: np.ndarray, bits: int) -> np.ndarray:
    """``bits``-bit codes to values in ``[0, 1]`` (float64)."""
    return np.asarray(codes, dtype=np.float64) / ((1 << bits) - 1)


def colour_of_dc(sh_dc: np.ndarray) -> np.ndarray:
    """Display colour (float64, ~``[0, 1]``) of SH degree-0 coefficients (any shape)."""
    return 0.5 + SH_C0 * np.asarray(sh_dc, dtype=np.float64)


def dc_of_colour(colour: np.ndarray) -> np.ndarray:
    """SH degree-0 coefficients (float64) of display colours (any shape)."""
    return (np.asarray(colour, dtype=np.float64) - 0.5) / SH_C0


def opacity_codes(logits: np.ndarray) -> np.ndarray:
    """``[N]`` opacity logits to 8-bit codes (uint8)."""
    alpha = 1.0 / (1.0 + np.exp(-np.asarray(logits, dtype=np.float64)))
    return code_of(alpha, 8).astype(np.uint8)


def opacity_logits(codes: np.ndarray) -> np.ndarray:
    """``[N]`` 8-bit opacity codes to logits (float64; the end codes a quarter step inside)."""
    alpha = np.clip(np.asarray(codes, dtype=np.float64) / 255, _OPACITY_END, 1 - _OPACITY_END)
    return np.log(alpha / (1 - alpha))


def unit_quats(quats: np.ndarray) -> np.ndarray:
    """``[N, 4]`` quaternions scaled to unit length (float64; a zero one stays zero)."""
    quats = np.asarray(quats, dtype=np.float64)
    norms = np.linalg.norm(quats, axis=1, keepdims=True)
    return quats / np.where(norms > 0, norms, 1.0)


def read_model_bytes(path: Path, kind: str) -> bytes:
    """The bytes of the ``kind`` file at ``path`` (e.g. ``.splat``); one line when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise StealthNSError(f"no {kind} file at {path}")
    try:
        return path.read_bytes()
    except OSError as err:
        raise StealthNSError(f"cannot read {path}: {err.strerror or err}") from None
