"""The view noise's counter-based normal deviates (attack/normal_draw.py, raster/csrc/noise_cpu.cpp)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from scipy import stats

from stealth_ns.attack import normal_draw
from stealth_ns.attack.normal_draw import (
    noisy_uint8,
    noisy_uint8_reference,
    normal_deviates,
    normal_deviates_reference,
)
from stealth_ns.raster.cpp_backend import load_extension

needs_ext = pytest.mark.skipif(load_extension() is None, reason="compiled CPU kernels unavailable")


def test_splitmix_is_the_published_sequence():
    # splitmix64.c (Vigna) seeded with 1234567: the stream's outputs are mix(seed + k * golden), k >= 1
    expected = [6457827717110365317, 3203168211198807973, 9817491932198370423, 4593380528125082431]
    assert normal_draw._splitmix(1234567, np.arange(4, dtype=np.uint64)).tolist() == expected


def test_reference_is_box_muller_of_the_stream_to_float_precision():
    # the same uniforms through float64 numpy log / cos / sin: the polynomials agree to ~1e-6
    count, key = 20_001, 77
    h = normal_draw._splitmix(key, np.arange((count + 1) // 2, dtype=np.uint64))
    u1 = ((h >> np.uint64(40)) + np.uint64(1)).astype(np.float64) / 2.0**24
    theta = 2 * np.pi * ((h >> np.uint64(8)) & np.uint64(0xFFFFFF)).astype(np.float64) / 2.0**24
    r = np.sqrt(-2 * np.log(u1))
    exact = np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1).reshape(-1)[:count]
    np.testing.assert_allclose(normal_deviates_reference(count, key), exact, rtol=0, atol=3e-6)


def test_reference_statistics():
    z = normal_deviates_reference(400_000, 5)
    assert z.dtype == np.float32 and z.shape == (400_000,)
    assert abs(float(z.mean())) < 0.005 and float(z.std()) == pytest.approx(1.0, abs=0.005)
    assert float(np.abs(z).max()) <= np.sqrt(48 * np.log(2)) + 1e-6
    assert stats.kstest(z, "norm").pvalue > 1e-3
    assert abs(np.corrcoef(z[0::2], z[1::2])[0, 1]) < 0.01  # the two halves of a pair
    assert abs(np.corrcoef(z, normal_deviates_reference(400_000, 6))[0, 1]) < 0.01  # another stream
    # a stream's prefix does not depend on its length
    assert normal_deviates_reference(7, 5).tobytes() == z[:7].tobytes()


@needs_ext
@pytest.mark.parametrize("threads", [1, 2])
def test_compiled_deviates_equal_the_reference_bitwise(threads):
    ext = load_extension()
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for count in (0, 1, 2, 511, 512, 513, 70_001):
            for key in (0, 1, 2**63 - 1, 987654321):
                got = ext.normal_draw(count, key).numpy()
                assert got.tobytes() == normal_deviates_reference(count, key).tobytes(), (count, key)
    finally:
        torch.set_num_threads(before)


@needs_ext
def test_compiled_noisy_uint8_equals_the_reference():
    g = torch.Generator().manual_seed(0)
    image = torch.randint(0, 256, (97, 131, 3), dtype=torch.uint8, generator=g)
    image[:4] = 0
    image[-4:] = 255  # clipped both ways
    for sigma in (0.5, 12.3, 300.0):
        got = noisy_uint8(image, sigma, 42)
        assert got.dtype == torch.uint8 and got.shape == image.shape
        assert np.array_equal(got.numpy(), noisy_uint8_reference(image.numpy(), sigma, 42))
    strided = image.permute(1, 0, 2)  # any layout: the stream runs over the flattened (row-major) image
    assert np.array_equal(
        noisy_uint8(strided, 9.0, 3).numpy(), noisy_uint8_reference(strided.contiguous().numpy(), 9.0, 3)
    )


def test_torch_operations_equal_the_reference_bitwise():
    # the implementation a GPU-cached image is noised with, run here on the CPU: the same operations
    for count in (0, 1, 2, 513, 70_001):
        for key in (0, 1, 2**63 - 1, 987654321):
            got = normal_draw._deviates_on(count, key, torch.device("cpu")).numpy()
            assert got.tobytes() == normal_deviates_reference(count, key).tobytes(), (count, key)
    g = torch.Generator().manual_seed(1)
    image = torch.randint(0, 256, (61, 83, 3), dtype=torch.uint8, generator=g)
    image[:3], image[-3:] = 0, 255
    for sigma in (0.5, 12.3, 300.0):
        got = normal_draw._noisy_uint8_on(image, sigma, 42)
        assert got.dtype == torch.uint8
        assert np.array_equal(got.numpy(), noisy_uint8_reference(image.numpy(), sigma, 42))
    strided = image.permute(1, 0, 2)
    assert np.array_equal(
        normal_draw._noisy_uint8_on(strided, 9.0, 3).numpy(),
        noisy_uint8_reference(strided.contiguous().numpy(), 9.0, 3),
    )


def test_torch_operations_with_tensor_sigma_and_key_equal_the_reference():
    # a CUDA graph reads sigma and the key from device memory: the same operations with scalar tensors
    image = torch.randint(0, 256, (37, 29, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(2))
    for sigma, key in ((0.5, 0), (12.3, 2**63 - 1), (300.0, 987654321)):
        sigma_t = torch.tensor(float(np.float32(sigma)), dtype=torch.float32)
        got = normal_draw._noisy_uint8_on(image, sigma_t, torch.tensor(key, dtype=torch.int64))
        assert np.array_equal(got.numpy(), noisy_uint8_reference(image.numpy(), sigma, key)), (sigma, key)


class _FakeGraph:
    """Stands in for ``_NoiseGraph`` on the CPU: records its calls, returns what it is told to."""

    made: list[tuple[int, ...]] = []

    def __init__(self, shape, device, result=None):
        _FakeGraph.made.append(tuple(shape))
        self.result = result

    def __call__(self, image, sigma, key):
        if self.result == "raise":
            raise RuntimeError("operation not permitted when stream is capturing\nmore")
        return normal_draw._noisy_uint8_on(image, sigma, key) if self.result is None else self.result


@pytest.fixture
def graph_state(monkeypatch):
    monkeypatch.setattr(normal_draw, "_noise_graphs", {})
    monkeypatch.setattr(normal_draw, "_noise_graphs_off", "")
    _FakeGraph.made = []


def test_noise_graphs_one_per_shape_up_to_the_limit(graph_state, monkeypatch):
    monkeypatch.setattr(normal_draw, "_NoiseGraph", _FakeGraph)
    monkeypatch.setattr(normal_draw, "_MAX_NOISE_GRAPHS", 2)
    images = [torch.full((h, 4, 3), 100, dtype=torch.uint8) for h in (3, 5, 7)]
    for step in range(3):
        for image in images:
            got = normal_draw._noisy_uint8_cuda(image, 20.0, step)
            assert np.array_equal(got.numpy(), noisy_uint8_reference(image.numpy(), 20.0, step))
    assert _FakeGraph.made == [(3, 4, 3), (5, 4, 3)]  # the third shape runs eagerly
    assert normal_draw._noise_graphs_off == ""


@pytest.mark.parametrize("result", ["raise", "differs"])
def test_noise_graphs_turned_off_when_capture_fails_or_differs(graph_state, monkeypatch, result):
    image = torch.full((4, 6, 3), 100, dtype=torch.uint8)
    wrong = torch.zeros_like(image)
    monkeypatch.setattr(
        normal_draw,
        "_NoiseGraph",
        lambda shape, device: _FakeGraph(shape, device, "raise" if result == "raise" else wrong),
    )
    with pytest.warns(RuntimeWarning, match="without CUDA graphs"):
        got = normal_draw._noisy_uint8_cuda(image, 20.0, 5)
    assert np.array_equal(got.numpy(), noisy_uint8_reference(image.numpy(), 20.0, 5))  # the eager result
    assert normal_draw._noise_graphs == {}
    reason = normal_draw._noise_graphs_off
    assert reason == (
        "capture failed: operation not permitted when stream is capturing"
        if result == "raise"
        else "the replayed noise differed from the eager one"
    )
    other = torch.full((9, 6, 3), 7, dtype=torch.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no new warning
        got = normal_draw._noisy_uint8_cuda(other, 3.0, 6)  # nor a new graph
    assert np.array_equal(got.numpy(), noisy_uint8_reference(other.numpy(), 3.0, 6))
    assert _FakeGraph.made == [(4, 6, 3)]


def test_noisy_uint8_reference_rounds_half_to_even_and_clips():
    z = normal_deviates_reference(6, 11)
    image = np.array([0, 10, 100, 200, 250, 255], dtype=np.uint8)
    expected = np.clip(np.rint(image.astype(np.float32) + np.float32(40.0) * z), 0, 255).astype(np.uint8)
    assert np.array_equal(noisy_uint8_reference(image, 40.0, 11), expected)
    assert np.rint(np.float32(2.5)) == 2.0  # numpy's rint, the kernel's std::rint and torch.round agree


def test_without_the_extension_the_same_values(monkeypatch):
    image = torch.arange(3 * 5 * 7, dtype=torch.uint8).reshape(5, 7, 3)
    with_ext = (normal_deviates((5, 7, 3), 8), noisy_uint8(image, 20.0, 8))
    monkeypatch.setattr(normal_draw, "_extension", lambda: None)
    without = (normal_deviates((5, 7, 3), 8), noisy_uint8(image, 20.0, 8))
    assert with_ext[0].shape == (5, 7, 3) and with_ext[0].dtype == torch.float32
    assert torch.equal(with_ext[0], without[0]) and torch.equal(with_ext[1], without[1])


@pytest.mark.parametrize("key", [-1, 2**63, 2**64 - 1])
def test_a_key_outside_its_domain_is_refused_on_every_path(key):
    # the compiled kernel and a CUDA graph take the key as an int64: refused alike, in one line, before
    # either is reached (an out-of-range key once reached a CUDA graph's int64 fill and failed there)
    image = torch.zeros((5, 7, 3), dtype=torch.uint8)
    with pytest.raises(ValueError, match=r"noise stream key must be in \[0, 2\^63\), got"):
        noisy_uint8(image, 3.0, key)
    with pytest.raises(ValueError, match=r"noise stream key must be in \[0, 2\^63\), got"):
        normal_draw.normal_deviates((4,), key)
