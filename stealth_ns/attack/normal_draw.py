"""Counter-based standard normal deviates for the attack's view noise: SplitMix64 + Box-Muller.

Deviate pair ``j`` of stream ``key`` is a pure function of ``(key, j)``, so the compiled kernel
(``csrc/noise_cpu.cpp``) draws a 1-MP image's 2.3 M deviates on every core, where ``torch.randn``'s one
Mersenne Twister took ~8 ms of each noised training step. The numpy functions here are the readable
reference with the same contract; every float operation is rounded as the kernel rounds it, and the
tests compare bitwise::

    h          = splitmix64(key + (j + 1) * 0x9E3779B97F4A7C15)
    u1         = ((h >> 40) + 1) / 2^24               in (0, 1]
    n2         = (h >> 8) mod 2^24                    the angle in 2^-24 turns
    r          = sqrt(max(-2 ln u1, 0))
    z[2 j]     = r cos(2 pi n2 / 2^24)
    z[2 j + 1] = r sin(2 pi n2 / 2^24)

24-bit uniforms as in torch's own CPU ``normal_``, so ``|z| <= sqrt(48 ln 2) = 5.77``. ``ln``, ``sin`` and
``cos`` are Cephes' single-precision polynomials (max error ~1e-7 relative). A stream of ``count``
deviates is the first ``count`` of this sequence, whatever the shape it is given.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch

__all__ = [
    "NOISE_GENERATOR",
    "normal_deviates",
    "normal_deviates_reference",
    "noisy_uint8",
    "noisy_uint8_reference",
]

NOISE_GENERATOR = "splitmix64-box-muller"
"""The generator's name, in the identity of a training that draws view noise (``runs.training``): a
finished run drawn with another generator (torch's Mersenne Twister before it) is retrained, not reused."""

_U64 = np.uint64
_F = np.float32
# Cephes logf (x = mantissa - 1) and sinf / cosf (|a| <= pi / 4) coefficients, highest degree first
_LOG = (
    7.0376836292e-2, -1.1514610310e-1, 1.1676998740e-1, -1.2420140846e-1, 1.4249322787e-1,
    -1.6668057665e-1, 2.0000714765e-1, -2.4999993993e-1, 3.3333331174e-1,
)  # fmt: skip
_SIN = (-1.9515295891e-4, 8.3321608736e-3, -1.6666654611e-1)
_COS = (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2)


def _splitmix(key: int, j: np.ndarray) -> np.ndarray:
    """SplitMix64 outputs ``[len(j)]`` uint64 for pair indices ``j`` (uint64) of stream ``key``."""
    z = _U64(key) + (j + _U64(1)) * _U64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> _U64(27))) * _U64(0x94D049BB133111EB)
    return z ^ (z >> _U64(31))


def _ln_u1(h: np.ndarray) -> np.ndarray:
    """``ln(((h >> 40) + 1) / 2^24)`` in float32 (exponent split off, mantissa in (sqrt(1/2), sqrt(2)])."""
    f = ((h >> _U64(40)) + _U64(1)).astype(_F)  # 1 .. 2^24, exact
    bits = f.view(np.uint32)
    m = ((bits & np.uint32(0x7FFFFF)) | np.uint32(0x3F800000)).view(_F)  # [1, 2)
    big = m > _F(np.sqrt(2.0))
    m = np.where(big, m * _F(0.5), m)
    e = ((bits >> np.uint32(23)).astype(np.int32) - 127 + big.astype(np.int32) - 24).astype(_F)
    x = m - _F(1.0)
    z = x * x
    p = np.full_like(x, _F(_LOG[0]))
    for coefficient in _LOG[1:]:
        p = p * x + _F(coefficient)
    y = p * x * z
    y = y + e * _F(-2.12194440e-4)
    y = y + _F(-0.5) * z
    return (x + y) + e * _F(0.693359375)


def _pairs(key: int, n_pairs: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``n_pairs`` pairs ``(z[2 j], z[2 j + 1])`` of stream ``key``, float32 each."""
    h = _splitmix(key, np.arange(n_pairs, dtype=_U64))
    r = np.sqrt(np.maximum(_F(-2.0) * _ln_u1(h), _F(0.0)))
    n2 = ((h >> _U64(8)) & _U64(0xFFFFFF)).astype(np.int32)
    q = (n2 + (1 << 21)) >> 22  # nearest quarter turn, 0 .. 4
    a = (n2 - (q << 22)).astype(_F) * _F(2.0**-24) * _F(2 * np.pi)  # [-pi/4, pi/4]
    z = a * a
    s = np.full_like(a, _F(_SIN[0]))
    for coefficient in _SIN[1:]:
        s = s * z + _F(coefficient)
    s = s * z * a + a
    c = np.full_like(a, _F(_COS[0]))
    for coefficient in _COS[1:]:
        c = c * z + _F(coefficient)
    c = c * z * z - _F(0.5) * z + _F(1.0)
    k = q & 3
    cos_t = np.select([k == 0, k == 1, k == 2], [c, -s, -c], s)
    sin_t = np.select([k == 0, k == 1, k == 2], [s, c, -s], -c)
    return r * cos_t, r * sin_t


def normal_deviates_reference(count: int, key: int) -> np.ndarray:
    """The first ``count`` deviates of stream ``key`` (0 <= key < 2^63) as float32 ``[count]`` (numpy)."""
    z0, z1 = _pairs(key, (count + 1) // 2)
    out = np.empty(2 * len(z0), dtype=_F)
    out[0::2], out[1::2] = z0, z1
    return out[:count]


def noisy_uint8_reference(image: np.ndarray, sigma: float, key: int) -> np.ndarray:
    """``clip(round_half_even(image + float32(sigma) z), 0, 255)`` as uint8, ``z`` stream ``key`` over the
    flattened image (numpy)."""
    z = normal_deviates_reference(image.size, key).reshape(image.shape)
    return np.clip(np.rint(image.astype(_F) + _F(sigma) * z), 0, 255).astype(np.uint8)


def _extension() -> Any:
    """The compiled module, or None where it is unavailable."""
    from stealth_ns.raster.cpp_backend import load_extension

    return load_extension()


def normal_deviates(shape: tuple[int, ...], key: int) -> torch.Tensor:
    """Stream ``key``'s first ``prod(shape)`` deviates as a float32 CPU tensor of ``shape``: compiled and
    parallel when the extension is built, the numpy reference otherwise (the same values)."""
    import torch

    count = int(np.prod(shape, dtype=np.int64))
    ext = _extension()
    flat = (
        ext.normal_draw(count, key)
        if ext is not None
        else torch.from_numpy(normal_deviates_reference(count, key))
    )
    return flat.reshape(shape)


def noisy_uint8(image: torch.Tensor, sigma: float, key: int) -> torch.Tensor:
    """:func:`noisy_uint8_reference` of a uint8 tensor on any device, computed on the CPU (one compiled
    pass when the extension is built) and returned on the image's device."""
    import torch

    ext = _extension()
    cpu = image.cpu().contiguous()
    out = (
        ext.noisy_u8(cpu, float(sigma), key)
        if ext is not None
        else torch.from_numpy(noisy_uint8_reference(cpu.numpy(), sigma, key))
    )
    return out.to(image.device)
