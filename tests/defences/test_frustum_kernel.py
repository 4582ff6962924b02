"""camera-proximity's depth ratios: the compiled kernel (raster/csrc/frustum_cpu.cpp) against its numpy
reference (stealth_ns.defences.scores.frustum_depth_ratios)."""

from __future__ import annotations

import numpy as np
import pytest

from stealth_ns.defences import scores, signals
from stealth_ns.raster.cpp_backend import load_extension


def _cameras(rng: np.random.Generator, v: int) -> tuple[np.ndarray, ...]:
    """``v`` cameras on a ring of radius 4 looking at the origin (OpenCV world-to-camera)."""
    viewmats = np.zeros((v, 4, 4))
    for i, angle in enumerate(np.linspace(0, 2 * np.pi, v, endpoint=False)):
        centre = np.array([4 * np.cos(angle), 0.3 * rng.normal(), 4 * np.sin(angle)])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rotation = np.stack([right, down, forward])
        viewmats[i, :3, :3] = rotation
        viewmats[i, :3, 3] = -rotation @ centre
        viewmats[i, 3, 3] = 1.0
    Ks = np.tile(np.array([[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]]), (v, 1, 1))
    sizes = np.tile([64.0, 48.0], (v, 1))
    return viewmats, Ks, sizes, rng.uniform(2.0, 5.0, v)


def test_compiled_ratios_equal_the_numpy_reference():
    """Points in and out of every view, behind cameras, on an image border, NaN and inf rows: the same
    ratios to float64 rounding, the same rows in view, 0 for a non-finite row."""
    if load_extension() is None:
        pytest.skip("compiled kernels unavailable")
    rng = np.random.default_rng(0)
    viewmats, Ks, sizes, depths = _cameras(rng, 7)
    points = rng.uniform(-6, 6, (5000, 3))
    # a point on camera 0's left image border (u = 0 exactly) at depth 2
    on_border = np.linalg.solve(Ks[0], [0.0, 20.0, 1.0]) * 2.0
    border_world = viewmats[0, :3, :3].T @ (on_border - viewmats[0, :3, 3])
    broken = [[np.nan, 0.0, 0.0], [np.inf, 1.0, 1.0], [0.0, 0.0, -np.inf]]
    points = np.concatenate([points, border_world[None], broken])
    compiled = signals.frustum_depth_ratios(points, viewmats, Ks, sizes, depths)
    reference = scores.frustum_depth_ratios(points, viewmats, Ks, sizes, depths)
    assert compiled.dtype == np.float64 and compiled.shape == (len(points),)
    assert np.array_equal(np.isfinite(compiled), np.isfinite(reference))
    assert 0.2 < np.isfinite(reference).mean() < 0.95  # some points in view, not all
    finite = np.isfinite(reference)
    np.testing.assert_allclose(compiled[finite], reference[finite], rtol=1e-12, atol=0)
    assert compiled[-3:].tolist() == [0.0, 0.0, 0.0]
    assert np.isfinite(compiled[-4])  # the border point is in view of camera 0


def test_compiled_ratios_check_their_arguments_as_the_reference():
    rng = np.random.default_rng(1)
    viewmats, Ks, sizes, depths = _cameras(rng, 3)
    points = rng.uniform(-1, 1, (10, 3))
    with pytest.raises(ValueError, match="need \\(V, 4, 4\\)"):
        signals.frustum_depth_ratios(points, viewmats, Ks[:2], sizes, depths)
    with pytest.raises(ValueError, match="finite and > 0"):
        signals.frustum_depth_ratios(points, viewmats, Ks, sizes, np.array([1.0, 0.0, 2.0]))
    empty = signals.frustum_depth_ratios(np.zeros((0, 3)), viewmats, Ks, sizes, depths)
    assert empty.shape == (0,)
