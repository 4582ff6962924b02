"""Adam for the Gaussians with torch's fused kernel (one pass over each parameter tensor).

nerfstudio's ``AdamOptimizerConfig`` builds ``torch.optim.Adam`` with its defaults, which on a CPU
is the per-tensor loop implementation: about ten elementwise passes over the parameters, their
gradients and both moments. The fused kernel computes the same update in one pass (timings:
docs/design/training_step.md). The optimizer state is
Adam's (``exp_avg``, ``exp_avg_sq``, a ``step`` tensor), so gsplat's densification and checkpoints
handle it as before; checkpoints of the loop implementation load into it.

nerfstudio steps one optimizer per Gaussian group every iteration, and around each kernel call
``torch.optim.Adam.step`` runs a layer of Python (profiler label, hooks, state checks, grouping by
device), and ``zero_grad`` another (timings: docs/design/training_step.md).
:class:`FusedAdam` makes the same kernel call with the same arguments itself whenever none of that
machinery has anything to do (see :meth:`FusedAdam.step`), so parameters, moments and checkpoints
stay bitwise torch's; everything else goes through torch's implementation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from torch import Tensor
from torch.optim import optimizer as torch_optimizer

__all__ = ["FusedAdam", "FusedAdamOptimizerConfig"]

# torch's own step, wrapped as torch wraps it (profiler label, global and per-optimizer hooks)
_TORCH_STEP = torch.optim.Optimizer.profile_hook_step(torch.optim.Adam.step)

#: One param group's fused-kernel arguments: (group, params, grads, exp_avgs, exp_avg_sqs, steps).
_GroupWork = tuple[dict[str, Any], list[Tensor], list[Tensor], list[Tensor], list[Tensor], list[Tensor]]


class FusedAdam(torch.optim.Adam):
    """``torch.optim.Adam(fused=True)`` without torch's per-call Python work where it has none to do."""

    def __init__(self, params: Any, **kwargs: Any) -> None:
        kwargs.setdefault("fused", True)
        super().__init__(params, **kwargs)

    def step(self, closure: Callable[[], float] | None = None) -> float | None:  # type: ignore[override]
        """torch's fused update, called directly when there is no closure, no step hook, no grad
        scaler's ``grad_scale`` / ``found_inf``, no CUDA graph capture, every group fused with float
        hyperparameters and without amsgrad / capturable / differentiable, and every parameter with a
        gradient already has its state (torch creates it at the first step) and shares its group's
        device and dtype. Otherwise torch's ``Adam.step``."""
        work = self._direct_work(closure)
        if work is None:
            return _TORCH_STEP(self, closure)
        with torch.no_grad():
            for group, params, grads, exp_avgs, exp_avg_sqs, steps in work:
                beta1, beta2 = group["betas"]
                torch._foreach_add_(steps, 1)
                update = torch._fused_adamw_ if group.get("decoupled_weight_decay") else torch._fused_adam_
                update(
                    params,
                    grads,
                    exp_avgs,
                    exp_avg_sqs,
                    [],
                    steps,
                    amsgrad=False,
                    lr=group["lr"],
                    beta1=beta1,
                    beta2=beta2,
                    weight_decay=group["weight_decay"],
                    eps=group["eps"],
                    maximize=group["maximize"],
                    grad_scale=None,
                    found_inf=None,
                )
        return None

    step.hooked = True  # type: ignore[attr-defined]  # torch must not wrap it: the hooks are checked above

    def zero_grad(self, set_to_none: bool = True) -> None:
        """As torch's (which only adds a profiler label when setting the gradients to None)."""
        if not set_to_none:
            super().zero_grad(set_to_none)
            return
        for group in self.param_groups:
            for p in group["params"]:
                p.grad = None

    def _direct_work(self, closure: Callable[[], float] | None) -> list[_GroupWork] | None:
        """The kernel calls of a direct step, or None when torch's step must run."""
        hooks = (
            self._optimizer_step_pre_hooks,
            self._optimizer_step_post_hooks,
            getattr(torch_optimizer, "_global_optimizer_pre_hooks", None),
            getattr(torch_optimizer, "_global_optimizer_post_hooks", None),
        )
        if closure is not None or any(hooks):
            return None
        if getattr(self, "grad_scale", None) is not None or getattr(self, "found_inf", None) is not None:
            return None
        if torch.cuda.is_available() and torch.cuda.is_current_stream_capturing():
            return None
        work = []
        for group in self.param_groups:
            if not group["fused"] or group["amsgrad"] or group["capturable"] or group["differentiable"]:
                return None
            if isinstance(group["lr"], Tensor) or not all(isinstance(b, float) for b in group["betas"]):
                return None
            params, grads, exp_avgs, exp_avg_sqs, steps = [], [], [], [], []
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state.get(p)
                if not state or p.grad.is_sparse or p.is_complex():
                    return None
                if params and (p.device != params[0].device or p.dtype != params[0].dtype):
                    return None
                params.append(p)
                grads.append(p.grad)
                exp_avgs.append(state["exp_avg"])
                exp_avg_sqs.append(state["exp_avg_sq"])
                steps.append(state["step"])
            if params:
                work.append((group, params, grads, exp_avgs, exp_avg_sqs, steps))
        return work


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config building :class:`FusedAdam` (torch's fused kernel, CPU and CUDA)."""

    _target: type = field(default_factory=lambda: FusedAdam)
    fused: bool = True
    """torch's fused Adam kernel (the same update, one pass over each tensor; 6x faster on a CPU here)."""
