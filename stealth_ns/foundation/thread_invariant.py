"""Element-wise activations whose values do not depend on the number of CPU threads.

PyTorch runs an element-wise CPU op over a tensor of more than ``GRAIN_SIZE`` (32768) elements in
one chunk per thread. Each chunk goes through the vectorised loop and finishes its last few
elements with the scalar kernel, and for ``sigmoid`` (among others) the two kernels may round
differently by one ulp. Where the chunk boundaries fall therefore depends on the thread count, and
so do a few values: a training on 1 thread and on 2 drifts apart once the model has more than 32768
Gaussians (docs/design/determinism.md). The functions here apply the op to fixed slices of ``GRAIN_SIZE``
elements, each of which PyTorch runs on one thread, so every element is computed by the same kernel
whatever the thread count: the values are those of a one-thread run, bit for bit, forward and
backward (autograd differentiates each slice on its own).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import torch
from torch import Tensor

#: PyTorch's ``at::internal::GRAIN_SIZE``: an element-wise op over at most this many elements runs on
#: one thread. A multiple of every vector width, so the slices' vectorised loops line up with a
#: one-thread run's.
GRAIN_SIZE = 32768


def in_fixed_slices(op: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
    """``op(x)`` for an element-wise ``op``, computed over fixed slices of :data:`GRAIN_SIZE` elements
    of ``x`` flattened: bitwise the one-thread result at any thread count. ``x``: any shape; the result
    has its shape. CUDA tensors and small tensors go to ``op`` directly."""
    n = x.numel()
    if x.device.type != "cpu" or n <= GRAIN_SIZE:
        return op(x)
    flat = x.reshape(-1)
    parts = [op(flat[i : i + GRAIN_SIZE]) for i in range(0, n, GRAIN_SIZE)]
    return torch.cat(parts).reshape(x.shape)


def sigmoid(x: Tensor) -> Tensor:
    """``torch.sigmoid(x)``, the same at every thread count (:func:`in_fixed_slices`)."""
    return in_fixed_slices(torch.sigmoid, x)


def exp(x: Tensor) -> Tensor:
    """``torch.exp(x)``, the same at every thread count (:func:`in_fixed_slices`)."""
    return in_fixed_slices(torch.exp, x)


@contextmanager
def one_thread() -> Iterator[None]:
    """Run the block's PyTorch CPU ops on one thread (the calling thread's setting, restored after):
    for code that is not ours (gsplat's densification) whose element-wise ops cannot be given fixed
    slices."""
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
