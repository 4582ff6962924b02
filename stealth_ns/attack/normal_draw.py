"""Counter-based standard normal deviates for the attack's view noise: SplitMix64 + Box-Muller.

Deviate pair ``j`` of stream ``key`` is a pure function of ``(key, j)``, so the compiled kernel
(``csrc/noise_cpu.cpp``) draws a 1-MP image's 2.3 M deviates on every core, where ``torch.randn``'s one
Mersenne Twister draws them on one (docs/design/training_step.md has the figures). The numpy functions here
are the readable reference with the same contract; every float operation is rounded as the kernel
rounds it, and the tests compare bitwise::

    h          = splitmix64(key + (j + 1) * 0x9E3779B97F4A7C15)
    u1         = ((h >> 40) + 1) / 2^24               in (0, 1]
    n2         = (h >> 8) mod 2^24                    the angle in 2^-24 turns
    r          = sqrt(max(-2 ln u1, 0))
    z[2 j]     = r cos(2 pi n2 / 2^24)
    z[2 j + 1] = r sin(2 pi n2 / 2^24)

24-bit uniforms as in torch's own CPU ``normal_``, so ``|z| <= sqrt(48 ln 2) = 5.77``. ``ln``, ``sin`` and
``cos`` are Cephes' single-precision polynomials (max error ~1e-7 relative). A stream of ``count``
deviates is the first ``count`` of this sequence, whatever the shape it is given.

Three implementations of one contract: the numpy reference, the compiled CPU kernel, and the same
operations as torch tensor operations (:func:`_pairs_on`), which draw the noise of an image cached on
a CUDA device where it lives instead of sending it to the CPU and back every step. Each torch operation is
one IEEE-rounded float32 operation (no fused multiply-add spans two of them), so all three give the
same bits on any device. That is ~118 kernel launches per image, whose launch cost exceeds the GPU
work, so on CUDA they are captured once per image shape as a CUDA graph and replayed
(:class:`_NoiseGraph`), with the key and sigma read from device memory.
"""

from __future__ import annotations

import warnings
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


def _as_int64(value: int) -> int:
    """The int64 with the bits of the uint64 ``value``."""
    return value - (1 << 64) if value >= 1 << 63 else value


def _srl(z: torch.Tensor, shift: int) -> torch.Tensor:
    """Logical right shift of int64 bit patterns (torch's ``>>`` on int64 is arithmetic)."""
    return (z >> shift) & ((1 << (64 - shift)) - 1)


def _pairs_on(
    key: int | torch.Tensor, n_pairs: int, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`_pairs` as torch operations on ``device`` (uint64 arithmetic as int64 wrapping the same
    way), bitwise the same values. ``key`` may be an int64 scalar tensor on ``device`` (a CUDA graph's
    input)."""
    import torch

    j = torch.arange(1, n_pairs + 1, dtype=torch.int64, device=device)  # j + 1
    z = j * _as_int64(0x9E3779B97F4A7C15) + key
    z = (z ^ _srl(z, 30)) * _as_int64(0xBF58476D1CE4E5B9)
    z = (z ^ _srl(z, 27)) * _as_int64(0x94D049BB133111EB)
    h = z ^ _srl(z, 31)
    del j, z
    f = (_srl(h, 40) + 1).to(torch.float32)  # 1 .. 2^24, exact
    bits = f.view(torch.int32)  # positive: >> is logical
    m = ((bits & 0x7FFFFF) | 0x3F800000).view(torch.float32)
    big = m > float(_F(np.sqrt(2.0)))
    m = torch.where(big, m * 0.5, m)
    e = ((bits >> 23) - 127 + big.to(torch.int32) - 24).to(torch.float32)
    x = m - 1.0
    zz = x * x
    p = torch.full_like(x, float(_F(_LOG[0])))
    for coefficient in _LOG[1:]:
        p = p * x + float(_F(coefficient))
    y = p * x * zz
    y = y + e * float(_F(-2.12194440e-4))
    y = y + -0.5 * zz
    ln_u1 = (x + y) + e * float(_F(0.693359375))
    # torch's float32 sqrt is not correctly rounded on every device (docs/design/training_step.md); the
    # float64 root rounded to float32 is, as numpy's float32 sqrt
    r = torch.sqrt(torch.clamp_min(-2.0 * ln_u1, 0.0).double()).float()
    n2 = (_srl(h, 8) & 0xFFFFFF).to(torch.int32)
    q = (n2 + (1 << 21)) >> 22
    a = (n2 - (q << 22)).to(torch.float32) * 2.0**-24 * float(_F(2 * np.pi))
    zz = a * a
    s = torch.full_like(a, float(_F(_SIN[0])))
    for coefficient in _SIN[1:]:
        s = s * zz + float(_F(coefficient))
    s = s * zz * a + a
    c = torch.full_like(a, float(_F(_COS[0])))
    for coefficient in _COS[1:]:
        c = c * zz + float(_F(coefficient))
    c = c * zz * zz - 0.5 * zz + 1.0
    k = q & 3
    cos_t = torch.where(k == 0, c, torch.where(k == 1, -s, torch.where(k == 2, -c, s)))
    sin_t = torch.where(k == 0, s, torch.where(k == 1, c, torch.where(k == 2, -s, -c)))
    return r * cos_t, r * sin_t


def _deviates_on(count: int, key: int | torch.Tensor, device: torch.device) -> torch.Tensor:
    """The first ``count`` deviates of stream ``key`` as float32 ``[count]``, drawn on ``device``."""
    import torch

    z0, z1 = _pairs_on(key, (count + 1) // 2, device)
    return torch.stack([z0, z1], dim=-1).reshape(-1)[:count]


def _noisy_uint8_on(
    image: torch.Tensor, sigma: float | torch.Tensor, key: int | torch.Tensor
) -> torch.Tensor:
    """:func:`noisy_uint8_reference` as torch operations where ``image`` (uint8) is. ``sigma`` and ``key``
    may be scalar tensors there (float32, int64), as a CUDA graph's inputs."""
    import torch

    z = _deviates_on(image.numel(), key, image.device).reshape(image.shape)
    scale = sigma if isinstance(sigma, torch.Tensor) else float(_F(sigma))
    return torch.round(image.to(torch.float32) + scale * z).clamp_(0, 255).to(torch.uint8)


class _NoiseGraph:
    """:func:`_noisy_uint8_on` for uint8 images of one shape on one CUDA device, captured as a CUDA
    graph: a call is an input copy, two scalar writes, one replay and the output's copy, instead of
    ~118 launches. The same kernels run on the same values, so the bits are the eager path's."""

    def __init__(self, shape: tuple[int, ...], device: torch.device) -> None:
        import torch

        self.image = torch.zeros(shape, dtype=torch.uint8, device=device)
        self.sigma = torch.zeros((), dtype=torch.float32, device=device)
        self.key = torch.zeros((), dtype=torch.int64, device=device)
        with torch.cuda.device(device):
            side = torch.cuda.Stream()  # warm-up off the default stream, as torch's CUDA-graph recipe does
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                _noisy_uint8_on(self.image, self.sigma, self.key)
            torch.cuda.current_stream().wait_stream(side)
            self.graph = torch.cuda.CUDAGraph()
            # captured on the warm-up's stream; "thread_local": other threads' CUDA calls (a data
            # loader's pinned memory, say) do not break this thread's capture
            with torch.cuda.graph(self.graph, stream=side, capture_error_mode="thread_local"):
                self.out = _noisy_uint8_on(self.image, self.sigma, self.key)

    def __call__(self, image: torch.Tensor, sigma: float, key: int) -> torch.Tensor:
        self.image.copy_(image)
        self.sigma.fill_(float(_F(sigma)))
        self.key.fill_(key)
        self.graph.replay()
        return self.out.clone()  # the graph's output buffer is overwritten by the next replay


_MAX_NOISE_GRAPHS = 4
"""Image shapes given a graph each (splatfacto's resolution schedule has three); others run eagerly."""
_noise_graphs: dict[tuple[tuple[int, ...], Any], _NoiseGraph] = {}
_noise_graphs_off = ""  # why graphs are not used in this process, once that is known


def _noisy_uint8_cuda(image: torch.Tensor, sigma: float, key: int) -> torch.Tensor:
    """:func:`_noisy_uint8_on` of a uint8 image on a CUDA device, through its shape's :class:`_NoiseGraph`.
    A graph's first output is compared with the eager path's; where capture fails or they differ, graphs
    are turned off for the process with a warning (the eager path gives the same bits, only slower)."""
    global _noise_graphs_off
    slot = (tuple(image.shape), image.device)
    graph = _noise_graphs.get(slot)
    if graph is not None:
        return graph(image, sigma, key)
    if _noise_graphs_off or len(_noise_graphs) >= _MAX_NOISE_GRAPHS:
        return _noisy_uint8_on(image, sigma, key)
    eager = _noisy_uint8_on(image, sigma, key)
    try:
        graph = _NoiseGraph(slot[0], image.device)
        same = bool(graph(image, sigma, key).equal(eager))
    except (RuntimeError, TypeError) as error:  # TypeError: a torch whose graph API lacks an argument
        _noise_graphs_off = f"capture failed: {error}".splitlines()[0]
    else:
        if same:
            _noise_graphs[slot] = graph
        else:
            _noise_graphs_off = "the replayed noise differed from the eager one"
    if _noise_graphs_off:
        warnings.warn(
            f"stealth-ns: view noise without CUDA graphs ({_noise_graphs_off}); ~1 ms slower per step",
            RuntimeWarning,
            stacklevel=2,
        )
    return eager


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


def _check_key(key: int) -> None:
    """Raise ValueError unless ``key`` is a stream key, ``0 <= key < 2^63``: the compiled kernel and a CUDA
    graph take it as an int64 (``noise_schedule.noise_seed`` draws keys there)."""
    if not 0 <= key < 1 << 63:
        raise ValueError(f"a noise stream key must be in [0, 2^63), got {key}")


def _extension() -> Any:
    """The compiled module, or None where it is unavailable."""
    from stealth_ns.raster.cpp_backend import load_extension

    return load_extension()


def normal_deviates(shape: tuple[int, ...], key: int, device: Any = "cpu") -> torch.Tensor:
    """Stream ``key``'s first ``prod(shape)`` deviates as a float32 tensor of ``shape`` on ``device``. On a
    CUDA device drawn there (:func:`_pairs_on`); elsewhere on the CPU, compiled and parallel when the
    extension is built, the numpy reference otherwise. The same values everywhere."""
    import torch

    _check_key(key)
    device = torch.device(device)
    count = int(np.prod(shape, dtype=np.int64))
    if device.type == "cuda":
        return _deviates_on(count, key, device).reshape(shape)
    ext = _extension()
    flat = (
        ext.normal_draw(count, key)
        if ext is not None
        else torch.from_numpy(normal_deviates_reference(count, key))
    )
    return flat.reshape(shape).to(device)


def noisy_uint8(image: torch.Tensor, sigma: float, key: int) -> torch.Tensor:
    """:func:`noisy_uint8_reference` of a uint8 tensor, returned on the image's device: on a CUDA device
    torch operations there, replayed as a CUDA graph; elsewhere on the CPU, one compiled pass when the
    extension is built (other accelerators may lack the float64 the torch path takes its square root
    in)."""
    import torch

    _check_key(key)
    if image.device.type == "cuda":
        return _noisy_uint8_cuda(image, sigma, key)
    ext = _extension()
    cpu = image.cpu().contiguous()
    out = (
        ext.noisy_u8(cpu, float(sigma), key)
        if ext is not None
        else torch.from_numpy(noisy_uint8_reference(cpu.numpy(), sigma, key))
    )
    return out.to(image.device)
