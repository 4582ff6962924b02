"""Densification statistics without boolean indexing.

gsplat's :class:`~gsplat.strategy.DefaultStrategy` accumulates, after every backward pass, the
screen-space gradient norm, a visibility count and the largest screen radius of each visible
Gaussian. It selects the visible ones with boolean masks (``torch.where``, ``grads[sel]``,
``radii[sel]``, an indexed assignment): each is a ``nonzero`` plus a gather over all N rows,
about 3.5 ms per step with one thread at 70k Gaussians on a CPU. :class:`DenseStatisticsStrategy`
computes the same sums with masked dense operations over the ``[C, N]`` grid instead, camera by
camera in the order ``index_add_`` adds them, so the state is bitwise the same
(``tests/test_densification.py`` checks it against gsplat's).
"""

from __future__ import annotations

from typing import Any

import torch
from gsplat.strategy import DefaultStrategy

__all__ = ["DenseStatisticsStrategy"]


class DenseStatisticsStrategy(DefaultStrategy):
    """gsplat's default densification strategy; only the per-step statistics update differs."""

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
        grads = (means2d.absgrad if self.absgrad else means2d.grad).clone()  # [C, N, 2]
        grads[..., 0] *= info["width"] / 2.0 * info["n_cameras"]  # to [-1, 1] screen units, as gsplat
        grads[..., 1] *= info["height"] / 2.0 * info["n_cameras"]
        n_gaussians = len(list(params.values())[0])
        for key in ("grad2d", "count") + (("radii",) if self.refine_scale2d_stop_iter > 0 else ()):
            if state[key] is None:
                state[key] = torch.zeros(n_gaussians, device=grads.device)
        visible = info["radii"] > 0  # [C, N]
        norms = grads.norm(dim=-1)  # [C, N]
        zero = norms.new_zeros(())
        # gsplat's indexed assignment: each camera compares with the radii from before this step and,
        # where several cameras see a Gaussian, the last camera's value is the one written
        before = state["radii"].clone() if self.refine_scale2d_stop_iter > 0 else None
        for c in range(visible.shape[0]):
            state["grad2d"] += torch.where(visible[c], norms[c], zero)
            state["count"] += visible[c]
            if before is not None:
                radii = info["radii"][c] / float(max(info["width"], info["height"]))
                kept = state["radii"]  # updated in place, as gsplat's
                kept.copy_(torch.where(visible[c], torch.maximum(before, radii), kept))
