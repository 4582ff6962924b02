"""DenseStatisticsStrategy's per-step statistics against gsplat's DefaultStrategy (bitwise), through
both the torch reference and the compiled kernel."""

import pytest
import torch
from gsplat.strategy import DefaultStrategy

from stealth_ns.method import densification
from stealth_ns.method.densification import DenseStatisticsStrategy
from stealth_ns.raster.cpp_backend import load_extension

needs_cpp = pytest.mark.skipif(load_extension() is None, reason="C++ extension unavailable")


def _info(n_cameras: int, n: int, seed: int) -> dict:
    g = torch.Generator().manual_seed(seed)
    radii = torch.randint(-3, 12, (n_cameras, n), generator=g, dtype=torch.int32).clamp_min(0)
    means2d = torch.zeros(n_cameras, n, 2, requires_grad=True)
    means2d.grad = torch.randn(n_cameras, n, 2, generator=g) * (radii > 0)[..., None]
    means2d.absgrad = means2d.grad.abs() * 1.5
    return {
        "width": 96,
        "height": 64,
        "n_cameras": n_cameras,
        "radii": radii,
        "gaussian_ids": None,
        "means2d": means2d,
    }


@pytest.mark.parametrize("n_cameras", [1, 3])
@pytest.mark.parametrize("absgrad", [False, True])
@pytest.mark.parametrize("track_radii", [True, False])
@pytest.mark.parametrize("path", ["reference", pytest.param("compiled", marks=needs_cpp)])
def test_statistics_match_gsplat(
    n_cameras: int, absgrad: bool, track_radii: bool, path: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []
    kernel = densification._compiled_kernel
    monkeypatch.setattr(
        densification,
        "_compiled_kernel",
        lambda *a: calls.append(1) or (kernel(*a) if path == "compiled" else None),
    )
    n = 1000  # larger, gsplat's indexed assignment of duplicate rows (several cameras) is unordered
    params = {"means": torch.nn.Parameter(torch.zeros(n, 3))}
    stop = 100 if track_radii else 0
    ours, theirs = (
        cls(absgrad=absgrad, refine_scale2d_stop_iter=stop)
        for cls in (DenseStatisticsStrategy, DefaultStrategy)
    )
    state_ours, state_theirs = ours.initialize_state(), theirs.initialize_state()
    for step in range(3):  # the first call creates the state, later ones accumulate
        info = _info(n_cameras, n, seed=step)
        ours._update_state(params, state_ours, info)
        theirs._update_state(params, state_theirs, info)
    keys = ("grad2d", "count", "radii") if track_radii else ("grad2d", "count")
    for key in keys:
        assert torch.equal(state_ours[key], state_theirs[key]), key
        assert state_ours[key].abs().sum() > 0, key  # the inputs did exercise the statistics
    if not track_radii:
        assert state_ours.get("radii") is None
    assert len(calls) == 3
    if path == "compiled":
        assert kernel(info["means2d"].grad, info["radii"]) is not None


@needs_cpp
def test_compiled_statistics_keep_nan_and_large_values_as_torch_does() -> None:
    g = torch.Generator().manual_seed(3)
    n = 10000  # more than one task of the kernel
    grads = torch.randn(2, n, 2, generator=g) * torch.logspace(-30, 30, n)[None, :, None]
    grads[0, 5, 0] = float("nan")
    grads[1, 7, 1] = float("inf")
    radii = torch.randint(-2, 40, (2, n), generator=g, dtype=torch.int32).clamp_min(0)
    start = torch.rand(3, n, generator=g)
    start[2, 11] = float("nan")
    out = {}
    for name, fn in (
        ("reference", densification.accumulate_statistics),
        ("compiled", load_extension().densify_stats),
    ):
        grad2d, count, max_radii = (row.clone() for row in start)
        fn(grad2d, count, max_radii, grads, radii, 37.5, 21.0, 75.0)
        out[name] = (grad2d, count, max_radii)
    for ours, ref in zip(out["compiled"], out["reference"], strict=True):
        assert torch.equal(ours.nan_to_num(-1.0), ref.nan_to_num(-1.0))
        assert torch.equal(ours.isnan(), ref.isnan())
    assert out["compiled"][0].isnan().any() and out["compiled"][2].isnan().any()


def test_radii_are_updated_in_place() -> None:
    n = 50
    strategy = DenseStatisticsStrategy(refine_scale2d_stop_iter=10)
    state = strategy.initialize_state()
    params = {"means": torch.nn.Parameter(torch.zeros(n, 3))}
    strategy._update_state(params, state, _info(1, n, seed=0))
    radii = state["radii"]
    strategy._update_state(params, state, _info(1, n, seed=1))
    assert state["radii"] is radii
