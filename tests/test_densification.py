"""DenseStatisticsStrategy's per-step statistics against gsplat's DefaultStrategy (bitwise)."""

import pytest
import torch
from gsplat.strategy import DefaultStrategy

from stealth_ns.densification import DenseStatisticsStrategy


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
def test_statistics_match_gsplat(n_cameras: int, absgrad: bool, track_radii: bool) -> None:
    n = 1000
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


def test_radii_are_updated_in_place() -> None:
    n = 50
    strategy = DenseStatisticsStrategy(refine_scale2d_stop_iter=10)
    state = strategy.initialize_state()
    params = {"means": torch.nn.Parameter(torch.zeros(n, 3))}
    strategy._update_state(params, state, _info(1, n, seed=0))
    radii = state["radii"]
    strategy._update_state(params, state, _info(1, n, seed=1))
    assert state["radii"] is radii
