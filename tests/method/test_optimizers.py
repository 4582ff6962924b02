"""FusedAdam: torch's fused Adam update, bitwise, with torch's implementation wherever it is needed."""

import pytest
import torch

from stealth_ns.method.optimizers import FusedAdam, FusedAdamOptimizerConfig


def _params(seed: int) -> list[torch.nn.Parameter]:
    g = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(shape, generator=g)) for shape in ((1000, 3), (1000, 15, 3), (7,))]


def _grads(params: list[torch.nn.Parameter], step: int) -> None:
    g = torch.Generator().manual_seed(100 + step)
    for i, p in enumerate(params):
        p.grad = None if (i == 2 and step % 2) else torch.randn(p.shape, generator=g) * 1e-3


def _run(cls: type, kwargs: dict, steps: int = 6) -> tuple[list[torch.Tensor], dict]:
    params = _params(0)
    opt = cls([{"params": params[:2]}, {"params": params[2:], "lr": 3e-3}], **kwargs)
    for step in range(steps):
        _grads(params, step)
        opt.step()
        opt.zero_grad()
        if step == 2:  # densification-style: the group's first tensor grows, its state rows with it
            old = params[0]
            params[0] = torch.nn.Parameter(torch.cat([old.detach(), old.detach()[:10]]))
            state = opt.state.pop(old)
            for key in ("exp_avg", "exp_avg_sq"):
                state[key] = torch.cat([state[key], torch.zeros(10, 3)])
            opt.state[params[0]] = state
            opt.param_groups[0]["params"][0] = params[0]
        if step == 3:
            opt.param_groups[0]["lr"] *= 0.5  # a scheduler step
    return [p.detach() for p in params], opt.state_dict()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"lr": 1e-2, "eps": 1e-15},
        {"lr": 1e-2, "eps": 1e-8, "weight_decay": 0.1, "maximize": True},
        {"lr": 1e-2, "weight_decay": 0.1, "decoupled_weight_decay": True},
    ],
)
def test_same_parameters_and_state_as_torch_fused_adam(kwargs: dict) -> None:
    ours, ours_state = _run(FusedAdam, kwargs)
    torchs, torch_state = _run(torch.optim.Adam, {**kwargs, "fused": True})
    for a, b in zip(ours, torchs, strict=True):
        assert torch.equal(a, b)
    for pid, state in torch_state["state"].items():
        for key, value in state.items():
            assert torch.equal(ours_state["state"][pid][key], value), key
    assert ours_state["param_groups"] == torch_state["param_groups"]


def test_direct_path_is_taken_after_the_first_step_only(monkeypatch: pytest.MonkeyPatch) -> None:
    import stealth_ns.method.optimizers as module

    calls = []
    torch_step = module._TORCH_STEP
    monkeypatch.setattr(module, "_TORCH_STEP", lambda *a: calls.append(1) or torch_step(*a))
    params = _params(1)
    opt = FusedAdam(params, lr=1e-3)
    for step in range(3):
        _grads(params, 2 * step)  # every parameter has a gradient
        opt.step()
    assert calls == [1]  # the first step creates the state through torch


def test_hooks_closure_and_set_to_none_false_go_through_torch() -> None:
    params = _params(2)
    opt = FusedAdam(params, lr=1e-3)
    _grads(params, 0)
    opt.step()
    seen = []
    handle = opt.register_step_pre_hook(lambda *_: seen.append("pre"))
    opt.register_step_post_hook(lambda *_: seen.append("post"))
    opt.step()
    assert seen == ["pre", "post"]
    handle.remove()

    def closure() -> float:
        seen.append("closure")
        return 1.5

    assert opt.step(closure) == 1.5 and "closure" in seen
    opt.zero_grad(set_to_none=False)
    assert all(p.grad is not None and not p.grad.any() for p in params)
    opt.zero_grad()
    assert all(p.grad is None for p in params)
    with pytest.raises(RuntimeError):  # torch's own checks still apply on its path
        FusedAdam(params, lr=1e-3, differentiable=True).step()


def test_config_builds_fused_adam() -> None:
    opt = FusedAdamOptimizerConfig(lr=1e-3, eps=1e-15).setup(_params(3))
    assert isinstance(opt, FusedAdam) and opt.defaults["fused"] is True
