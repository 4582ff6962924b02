"""The compiled background composite (raster/csrc/composite_cpu.cpp) against torch's expression, bitwise."""

from __future__ import annotations

import pytest
import torch

from stealth_ns.raster import composite
from stealth_ns.raster.cpp_backend import load_extension

pytestmark = pytest.mark.skipif(load_extension() is None, reason="compiled CPU kernels unavailable")


def _inputs(shape: tuple[int, ...], D: int, seed: int) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    render = torch.rand(*shape, D, generator=g) * 1.4 - 0.2  # some values clamp at 0, some at 1
    alpha = torch.rand(*shape, 1, generator=g)
    background = torch.rand(D, generator=g)
    v_rgb = torch.randn(*shape, D, generator=g)
    flat = render.view(-1)
    flat[:5] = torch.tensor([float("nan"), 0.0, -0.0, 1.0, float("inf")])  # edges of the clamp
    alpha.view(-1)[5:8] = torch.tensor([0.0, 1.0, float("nan")])
    v_rgb.view(-1)[8:10] = torch.tensor([0.0, -0.0])
    return render, alpha, background, v_rgb


def _run(fn, render, alpha, background, v_rgb):
    r = render.clone().requires_grad_(True)
    a = alpha.clone().requires_grad_(True)
    rgb = fn(r, a, background)
    rgb.backward(v_rgb)
    return rgb.detach(), r.grad, a.grad


def _reference(render, alpha, background):
    return torch.clamp(render + (1 - alpha) * background, 0.0, 1.0)


@pytest.mark.parametrize(
    ("shape", "D", "threads"), [((1, 37, 53), 3, 1), ((1, 120, 97), 3, 2), ((2, 9, 11), 4, 2)]
)
def test_same_values_and_gradients_as_torch(shape, D, threads):
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        inputs = _inputs(shape, D, seed=D + threads)
        assert composite._compiled_path(*inputs[:3])
        got = _run(composite.composite_on_background, *inputs)
        want = _run(_reference, *inputs)
    finally:
        torch.set_num_threads(before)
    for g, w in zip(got, want, strict=True):
        assert torch.equal(g.isnan(), w.isnan())
        assert torch.equal(torch.nan_to_num(g), torch.nan_to_num(w))


def test_torch_path_where_the_kernel_does_not_apply():
    render, alpha, background, _ = _inputs((1, 8, 8), 3, seed=0)
    sliced = torch.cat([render, alpha], dim=-1)[..., :3]  # not contiguous
    assert not composite._compiled_path(sliced, alpha, background)
    assert not composite._compiled_path(render, alpha, background.requires_grad_(True))
    assert not composite._compiled_path(render.double(), alpha.double(), background.double())
    bg = torch.rand(3, requires_grad=True)
    rgb = composite.composite_on_background(render, alpha, bg)
    rgb.sum().backward()
    assert bg.grad is not None  # the torch expression: the background gets its gradient


def test_bad_shapes_are_refused():
    ext = load_extension()
    render, alpha, background, _ = _inputs((1, 4, 4), 3, seed=1)
    with pytest.raises(RuntimeError, match="background must be"):
        ext.composite_fwd(render, alpha, torch.rand(4))
    with pytest.raises(RuntimeError, match="alpha must be"):
        ext.composite_fwd(render, torch.rand(1, 4, 5, 1), background)
    wide = torch.rand(1, 4, 6, 3)
    with pytest.raises(RuntimeError, match="alpha must be"):  # as many pixels, in another shape
        ext.composite_fwd(wide, torch.rand(1, 6, 4, 1), background)
