"""Densification statistics without boolean indexing.

gsplat's :class:`~gsplat.strategy.DefaultStrategy` accumulates, after every backward pass, the
screen-space gradient norm, a visibility count and the largest screen radius of each visible
Gaussian. It selects the visible ones with boolean masks (``torch.where``, ``grads[sel]``,
``radii[sel]``, an indexed assignment): each is a ``nonzero`` plus a gather over all N rows
(timings: docs/design/training_step.md). :class:`DenseStatisticsStrategy`
computes the same sums with masked dense operations over the ``[C, N]`` grid instead
(:func:`accumulate_statistics`), camera by camera in the order ``index_add_`` adds them, so the state
is bitwise the same (``tests/method/test_densification.py`` checks it against gsplat's). On a CPU the compiled
``densify_stats`` (``raster/csrc/densify_cpu.cpp``) does the same in one pass over the Gaussians,
bitwise equal to that reference.

Growing and pruning (gsplat's ``_grow_gs`` and ``_prune_gs``, every ``refine_every`` steps) run their
PyTorch ops on one thread (:func:`stealth_ns.foundation.thread_invariant.one_thread`): their ``exp`` and
``sigmoid`` over all Gaussians would otherwise give values, and so new Gaussians, that depend on the
thread count.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from gsplat.strategy import DefaultStrategy

from stealth_ns.foundation.thread_invariant import one_thread

__all__ = ["DenseStatisticsStrategy", "accumulate_statistics", "capped_pause"]

MAX_PAUSE_SHARE = 0.5
"""The largest share of an opacity-reset interval that refinement pauses for after each reset.

After a reset, splatfacto pauses growing and pruning for as many steps as there are training views, plus
one refine interval (gsplat's ``pause_refine_after_reset``), so that every view is drawn once and lifts
its Gaussians' opacities again before the opacity cull. Under the lite schedule an interval is 300 steps:
from 270 training views on that pause covered the whole interval and no Gaussian was ever grown or pruned
(a clean run ended with exactly its seed points), and at 161 views 15 of the 45 refinement steps ran.
Capped at half the interval, a capture of any size keeps 24 of them; below the cap (the lite schedule to
120 views, the 30k one to 1,400) the pause is splatfacto's."""


def capped_pause(pause: int, reset_every: int) -> int:
    """The steps refinement waits after each opacity reset: ``pause`` (splatfacto's: the number of training
    views plus one refine interval), at most :data:`MAX_PAUSE_SHARE` of ``reset_every``."""
    return min(pause, int(MAX_PAUSE_SHARE * reset_every))


@dataclass
class DenseStatisticsStrategy(DefaultStrategy):
    """gsplat's default densification strategy; the per-step statistics update differs, growing and
    pruning run on one thread (see the module docstring), and the pause after an opacity reset is
    :func:`capped_pause`'s."""

    def __post_init__(self) -> None:
        self.pause_refine_after_reset = capped_pause(self.pause_refine_after_reset, self.reset_every)

    def _grow_gs(self, *args: Any, **kwargs: Any) -> tuple[int, int]:
        with one_thread():
            return super()._grow_gs(*args, **kwargs)

    def _prune_gs(self, *args: Any, **kwargs: Any) -> int:
        with one_thread():
            return super()._prune_gs(*args, **kwargs)

    @torch.no_grad()
    def _update_state(
        self,
        params: dict[str, torch.nn.Parameter] | torch.nn.ParameterDict,
        state: dict[str, Any],
        info: dict[str, Any],
        packed: bool = False,
    ) -> None:
        if packed:  # [nnz] rows already: nothing to select
            super()._update_state(params, state, info, packed=packed)
            return
        for key in ("width", "height", "n_cameras", "radii", "gaussian_ids", self.key_for_gradient):
            assert key in info, f"{key} is required but missing."
        means2d = info[self.key_for_gradient]
        grads = means2d.absgrad if self.absgrad else means2d.grad  # [C, N, 2]
        n_gaussians = len(list(params.values())[0])
        for key in ("grad2d", "count") + (("radii",) if self.refine_scale2d_stop_iter > 0 else ()):
            if state[key] is None:
                state[key] = torch.zeros(n_gaussians, device=grads.device)
        max_radii = state["radii"] if self.refine_scale2d_stop_iter > 0 else None
        scale_x = info["width"] / 2.0 * info["n_cameras"]  # to [-1, 1] screen units, as gsplat
        scale_y = info["height"] / 2.0 * info["n_cameras"]
        size = float(max(info["width"], info["height"]))
        radii = info["radii"]
        kernel = _compiled_kernel(grads, radii) or accumulate_statistics
        kernel(state["grad2d"], state["count"], max_radii, grads, radii, scale_x, scale_y, size)


def accumulate_statistics(
    grad2d: torch.Tensor,
    count: torch.Tensor,
    max_radii: torch.Tensor | None,
    grads: torch.Tensor,
    radii: torch.Tensor,
    scale_x: float,
    scale_y: float,
    size: float,
) -> None:
    """One step's statistics, added in place (the reference of the compiled ``densify_stats``).

    For every camera ``c`` that sees Gaussian ``n`` (``radii[c, n] > 0``): ``grad2d[n]`` gains the norm
    of the screen-space gradient ``grads[c, n]`` ([C, N, 2], pixels) scaled by ``(scale_x, scale_y)``
    into gsplat's units, ``count[n]`` gains 1 and, when ``max_radii`` is given, ``max_radii[n]`` becomes
    the maximum of its value before this call and ``radii[c, n] / size`` (radius as a fraction of the
    image's longer side; with several cameras the last one's value is kept, as gsplat's indexed
    assignment keeps it). ``grad2d``, ``count``, ``max_radii``: [N] float.
    """
    grads = grads.clone()
    grads[..., 0] *= scale_x
    grads[..., 1] *= scale_y
    visible = radii > 0  # [C, N]
    norms = grads.norm(dim=-1)  # [C, N]
    zero = norms.new_zeros(())
    before = max_radii.clone() if max_radii is not None else None
    for c in range(visible.shape[0]):
        grad2d += torch.where(visible[c], norms[c], zero)
        count += visible[c]
        if max_radii is not None and before is not None:
            relative = radii[c] / size
            max_radii.copy_(torch.where(visible[c], torch.maximum(before, relative), max_radii))


def _compiled_kernel(grads: torch.Tensor, radii: torch.Tensor) -> Callable[..., None] | None:
    """The compiled ``densify_stats`` for contiguous CPU float32 gradients and int32 radii, else None."""
    if grads.device.type != "cpu" or grads.dtype != torch.float32 or radii.dtype != torch.int32:
        return None
    if not (grads.is_contiguous() and radii.is_contiguous()):
        return None
    from stealth_ns.raster.cpp_backend import load_extension

    ext = load_extension()
    return None if ext is None else ext.densify_stats
