"""The one place that changes the rows of the Gaussians together with their training state.

A model's per-Gaussian tensors (``gauss_params``: every entry ``[N, ...]``), the Adam state of each
(``exp_avg``, ``exp_avg_sq``: ``[N, ...]``) and gsplat's densification statistics (``[N]`` tensors in
the strategy state) must always have the same rows, or the next step indexes past one of them.
gsplat keeps this in ``gsplat/strategy/ops.py`` for its own duplicate / split / prune; appending
rows from outside the strategy (the poison injection) is done here, with the same contract, and so
is re-pointing the optimizers at rows that were replaced whole (a loaded checkpoint).
"""

from __future__ import annotations

import torch
from torch import Tensor


@torch.no_grad()
def append_rows(
    params: torch.nn.ParameterDict,
    optimizers: dict[str, torch.optim.Optimizer],
    strategy_state: dict,
    rows: dict[str, Tensor],
) -> None:
    """Append rows to every per-Gaussian tensor, keeping optimizer and strategy state consistent.

    Args:
        params: the per-Gaussian parameters (every entry ``[N, ...]``), replaced by ``[N + M, ...]``.
        optimizers: optimizer per ``params`` entry (gsplat's strategy contract: one Parameter each);
            their per-row state gets zero rows (a new row starts as if never stepped).
        strategy_state: gsplat ``DefaultStrategy`` state; its ``[N, ...]`` tensors get zero rows.
        rows: new values for every ``params`` entry, each ``[M, ...]``.

    Raises:
        ValueError: ``rows`` does not name exactly the entries of ``params``, or the row counts differ.
    """
    if set(rows) != set(params.keys()):
        raise ValueError(f"new rows for {sorted(rows)} but the model has {sorted(params.keys())}")
    counts = {rows[name].shape[0] for name in rows}
    if len(counts) != 1:
        raise ValueError(f"new rows disagree on their count: { {k: v.shape[0] for k, v in rows.items()} }")
    n_old, n_new = params["means"].shape[0], counts.pop()
    for name in list(params.keys()):
        old = params[name]
        new = torch.nn.Parameter(torch.cat([old.data, rows[name].to(old)]), requires_grad=old.requires_grad)
        optimizer = optimizers.get(name)
        if optimizer is not None:
            _swap_in_optimizer(optimizer, old, new, n_old)
        params[name] = new
    for key, value in strategy_state.items():
        if isinstance(value, Tensor) and value.dim() > 0 and value.shape[0] == n_old:
            strategy_state[key] = _pad(value, n_new)


def _pad(value: Tensor, n_new: int) -> Tensor:
    """``value`` [N, ...] with ``n_new`` zero rows appended."""
    return torch.cat([value, value.new_zeros((n_new, *value.shape[1:]))])


def _swap_in_optimizer(
    optimizer: torch.optim.Optimizer, old: Tensor, new: torch.nn.Parameter, n_old: int
) -> None:
    """Replace ``old`` by ``new`` in ``optimizer``; its per-row state tensors get zero rows."""
    n_new = new.shape[0] - n_old
    for group in optimizer.param_groups:
        for i, param in enumerate(group["params"]):
            if param is not old:
                continue
            state = optimizer.state.pop(param, {})
            for key, value in state.items():
                if (
                    key != "step"
                    and isinstance(value, Tensor)
                    and value.dim() > 0
                    and value.shape[0] == n_old
                ):
                    state[key] = _pad(value, n_new)
            group["params"][i] = new
            if state:
                optimizer.state[new] = state


def select_rows(tensors: dict, keep: Tensor) -> dict:
    """``tensors`` with only the rows where ``keep`` ([N] bool) is True: every tensor whose first
    dimension is N is indexed, everything else (scalars, other shapes, non-tensors) is kept as is.

    For saved state (a checkpoint's ``gauss_params.*`` and gsplat's per-Gaussian statistics), where
    no optimizer needs to follow; the model's live rows change through gsplat's ops or
    :func:`append_rows`."""
    n = keep.shape[0]
    return {
        k: v[keep] if isinstance(v, Tensor) and v.dim() > 0 and v.shape[0] == n else v
        for k, v in tensors.items()
    }


@torch.no_grad()
def rebind_optimizers(params: torch.nn.ParameterDict, optimizers: dict[str, torch.optim.Optimizer]) -> None:
    """Point the optimizer of every ``params`` entry at the entry's current Parameter, moving its state
    over (after the entries were replaced, e.g. by loading a checkpoint). Optimizers of other names
    are left alone.

    Raises:
        ValueError: a per-row state tensor does not have its new Parameter's shape (the state and the
            rows do not belong together).
    """
    for name, optimizer in optimizers.items():
        if name not in params:
            continue
        param = params[name]
        for group in optimizer.param_groups:
            (old,) = group["params"]
            if old is param:
                continue
            state = optimizer.state.pop(old, None)
            group["params"] = [param]
            if state is not None:
                for key, value in state.items():
                    if isinstance(value, Tensor) and value.dim() > 0 and value.shape != param.shape:
                        raise ValueError(
                            f"optimizer state {name}.{key} has shape {tuple(value.shape)} but the "
                            f"model's {name} has {tuple(param.shape)}: checkpoint and optimizer "
                            "state do not belong together"
                        )
                optimizer.state[param] = state
