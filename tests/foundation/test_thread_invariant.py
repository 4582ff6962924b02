"""Values that must not depend on the number of CPU threads: the activations of the Gaussians, the
model's render and gradients, gsplat's growing and pruning (docs/design/determinism.md)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import torch
from gsplat.strategy import DefaultStrategy
from model_helpers import build_model, camera

from stealth_ns.foundation import thread_invariant
from stealth_ns.foundation.thread_invariant import GRAIN_SIZE, in_fixed_slices, one_thread
from stealth_ns.method.densification import DenseStatisticsStrategy

#: Elements in a tensor that PyTorch splits in two chunks on two threads, the first ending off the
#: vector loop's stride (16401 elements): its last element goes through the tail kernel, whereas a
#: one-thread run computes it in the main loop.
N_SPLIT = GRAIN_SIZE + 33


@contextmanager
def threads(n: int) -> Iterator[None]:
    saved = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(saved)


def tail_sensitive_logit() -> float:
    """A value whose sigmoid PyTorch's tail kernel rounds unlike its vectorised loop on this CPU (the
    first and last element of a constant tensor differ); skips the test where none is found."""
    gen = torch.Generator().manual_seed(0)
    with threads(1):
        for v in (torch.randn(4000, generator=gen) * 3).tolist():
            out = torch.sigmoid(torch.full((129,), v))
            if out[0] != out[-1]:
                return v
    pytest.skip("this PyTorch build's sigmoid kernels round alike: no thread-count effect to remove")


@pytest.fixture(scope="module")
def logit() -> float:
    return tail_sensitive_logit()


def test_plain_sigmoid_depends_on_the_thread_count(logit: float) -> None:
    """The effect the module removes is there (so the tests below can fail)."""
    x = torch.full((N_SPLIT,), logit)
    with threads(1):
        one = torch.sigmoid(x)
    with threads(2):
        two = torch.sigmoid(x)
    assert not torch.equal(one, two)


@pytest.mark.parametrize("n_threads", [2, 3, 4])
def test_sigmoid_and_exp_match_one_thread_forward_and_backward(logit: float, n_threads: int) -> None:
    x = torch.full((N_SPLIT, 1), logit)
    results = {}
    for n in (1, n_threads):
        with threads(n):
            xs = x.clone().requires_grad_()
            y = thread_invariant.sigmoid(xs) * thread_invariant.exp(xs)
            (grad,) = torch.autograd.grad(y.square().sum(), xs)
            results[n] = (y.detach(), grad)
    assert torch.equal(results[1][0], results[n_threads][0])
    assert torch.equal(results[1][1], results[n_threads][1])
    with threads(1):  # and a one-thread run is PyTorch's own result, bit for bit
        assert torch.equal(thread_invariant.sigmoid(x), torch.sigmoid(x))


def test_fixed_slices_keep_shape_and_small_tensors() -> None:
    x = torch.randn(3, GRAIN_SIZE, 2)
    assert torch.equal(in_fixed_slices(torch.tanh, x), torch.tanh(x))
    small = torch.randn(7, 3)
    assert torch.equal(thread_invariant.exp(small), torch.exp(small))


def test_model_render_and_gradients_do_not_depend_on_the_thread_count(logit: float) -> None:
    """One training step's image, loss and gradients at 1 and 2 threads, with more Gaussians than a
    one-thread chunk and opacities whose sigmoid the tail kernel rounds differently."""
    model, optimizers = build_model(n_points=N_SPLIT, seed=3)
    with torch.no_grad():
        model.gauss_params["opacities"].fill_(logit)
    model.step_cb(optimizers, 0)
    cam = camera(64, 48, eye=(0.0, 0.0, 2.5))
    target = torch.rand(48, 64, 3, generator=torch.Generator().manual_seed(1))
    results = {}
    for n in (1, 2):
        with threads(n):
            model.train()
            for p in model.gauss_params.values():
                p.grad = None
            torch.manual_seed(0)  # splatfacto's random background
            out = model.get_outputs(cam)
            loss = sum(model.get_loss_dict(out, {"image": target}).values())
            loss.backward()
            grads = {k: p.grad.clone() for k, p in model.gauss_params.items() if p.grad is not None}
            results[n] = (out["rgb"].detach().clone(), grads)
    assert torch.equal(results[1][0], results[2][0])
    assert results[1][1].keys() == results[2][1].keys()
    for key, grad in results[1][1].items():
        assert torch.equal(grad, results[2][1][key]), key


def test_one_thread_sets_and_restores() -> None:
    with threads(2):
        with one_thread():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2


@pytest.mark.parametrize("method", ["_grow_gs", "_prune_gs"])
def test_growing_and_pruning_run_on_one_thread(method: str, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = []
    monkeypatch.setattr(DefaultStrategy, method, lambda self, *a, **k: seen.append(torch.get_num_threads()))
    with threads(2):
        getattr(DenseStatisticsStrategy(), method)({}, {}, {}, 0)
        assert torch.get_num_threads() == 2
    assert seen == [1]
