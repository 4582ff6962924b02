"""The scene's near depth (the scan's near lines are shares of it): each view's low quantile of the
surface depths, and the median over the views of its share of the view's median depth."""

import math

import numpy as np
import pytest
import torch

from stealth_ns.attack.injection import median_scene_depth
from stealth_ns.defences.signals import (
    NEAR_DEPTH_QUANTILE,
    near_depth_share,
    surface_median_and_near,
)


def test_a_views_near_depth_is_a_low_quantile_of_what_shows_a_surface():
    depth = torch.arange(1, 101, dtype=torch.float32).reshape(10, 10)
    alpha = torch.ones(10, 10)
    assert surface_median_and_near(depth, alpha)[1] == math.ceil(
        100 * NEAR_DEPTH_QUANTILE
    )  # the k-th nearest, k rounded up
    alpha[0] = 0.0  # the nearest row shows no surface (sky, empty background)
    assert surface_median_and_near(depth, alpha)[1] == 10 + math.ceil(90 * NEAR_DEPTH_QUANTILE)
    assert np.isnan(surface_median_and_near(depth, torch.zeros(10, 10))[1])
    assert np.isnan(surface_median_and_near(torch.full((4, 4), float("nan")), torch.ones(4, 4))[1])


def test_one_view_filled_by_something_close_moves_the_scenes_share_little():
    medians = np.array([10.0, 10.0, 10.0, 10.0, 10.0, 8.0])
    nears = np.array([6.0, 6.2, 5.8, 6.0, 1.0, np.nan])  # view 4 filled by an illusion; view 5 empty
    assert near_depth_share(medians, nears) == pytest.approx(0.6)
    assert near_depth_share(np.array([np.nan]), np.array([np.nan])) == 1.0


@pytest.mark.parametrize("size", [(9, 11), (10, 10), (1, 1)])
def test_one_partition_gives_the_median_and_the_near_depth_of_their_own_functions(size):
    gen = torch.Generator().manual_seed(sum(size))
    depth = torch.rand(size, generator=gen) * 5
    alpha = (torch.rand(size, generator=gen) > 0.3).float()
    alpha.view(-1)[0] = 1.0  # at least one surface pixel
    median, near = surface_median_and_near(depth, alpha)
    assert median == median_scene_depth(depth, alpha, np.nan)  # the lower median on an even count
    surface = depth[alpha >= 0.5]
    assert near == float(surface.kthvalue(max(1, math.ceil(NEAR_DEPTH_QUANTILE * surface.numel()))).values)
    assert all(math.isnan(x) for x in surface_median_and_near(depth, torch.zeros(size)))
