"""Suspicion scores (stealth_ns.defences.scores) and detection metrics / pruning rules
(stealth_ns.defences.detection) on hand-made clouds with known answers; SOR against open3d itself."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stealth_ns.defences import detection, scores
from stealth_ns.defences.detection import (
    detection_metrics,
    operating_point,
    prune_mask_threshold,
    prune_mask_top_fraction,
    sweep_fractions,
)
from stealth_ns.defences.scores import (
    concentration_scores,
    count_cap_mask,
    count_cap_scores,
    prune_mask_top_count,
    pruning_order,
    robust_zscore,
    sor_scores,
    zscore_features,
    zscore_scores,
)


def top(s: np.ndarray, n: int) -> set[int]:
    return set(pruning_order(s)[:n].tolist())


# ---------------------------------------------------------------------------------- robust z-score


def test_robust_zscore_is_the_modified_zscore():
    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0])  # median 3, |x - 3| = [2, 1, 0, 1, 97], MAD = 1
    np.testing.assert_allclose(robust_zscore(x), np.array([2, 1, 0, 1, 97]) / 1.4826)
    # shift and scale invariant
    np.testing.assert_allclose(robust_zscore(5.0 - 3.0 * x), robust_zscore(x))


def test_robust_zscore_falls_back_to_the_mean_absolute_deviation_then_zeros():
    x = np.array([5.0, 5.0, 5.0, 5.0, 9.0])  # MAD 0; mean |x - 5| = 0.8
    np.testing.assert_allclose(robust_zscore(x), [0, 0, 0, 0, 4 / (1.2533 * 0.8)])
    np.testing.assert_array_equal(robust_zscore(np.full(4, 2.5)), np.zeros(4))
    assert robust_zscore(np.zeros(0)).shape == (0,)
    with pytest.raises(ValueError, match="1-D"):
        robust_zscore(np.zeros((2, 2)))


def test_robust_zscore_nonfinite_values_are_maximally_suspicious_and_left_out():
    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    with_bad = np.array([1.0, np.nan, 2.0, 3.0, np.inf, 4.0, -np.inf, 100.0])
    z = robust_zscore(with_bad)
    assert np.isposinf(z[[1, 4, 6]]).all()
    np.testing.assert_allclose(z[[0, 2, 3, 5, 7]], robust_zscore(x))  # the others are unmoved
    assert np.isposinf(robust_zscore(np.array([np.nan, np.nan]))).all()


# --------------------------------------------------------------------------------------- zscore


def gaussian_cloud(n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(n, 3))
    log_scales = rng.normal(-3.0, 0.3, size=(n, 3))
    logits = rng.normal(3.0, 0.2, size=n)  # opacity ~0.95 +- 0.01, as trained 3DGS tends to
    return means, log_scales, logits


def test_zscore_ranks_planted_outliers_first_and_names_their_feature():
    means, log_scales, logits = gaussian_cloud()
    log_scales[7] = [2.0, -3.0, -3.0]  # one huge axis: log_max_scale (and log_volume)
    logits[11] = -3.0  # nearly transparent: opacity
    means[13] = [40.0, 0.0, 0.0]  # far centre
    s = zscore_scores(means, log_scales, logits)
    assert s.shape == (300,)
    assert top(s, 3) == {7, 11, 13}
    assert (s[[7, 11, 13]] > scores.ZSCORE_THRESHOLD).all()
    features = zscore_features(means, log_scales, logits)
    assert tuple(features) == scores.ZSCORE_FEATURES
    argmax = np.argmax(np.stack(list(features.values())), axis=0)
    assert [scores.ZSCORE_FEATURES[argmax[i]] for i in (7, 11, 13)] == [
        "log_max_scale",
        "opacity",
        "centre_distance",
    ]
    np.testing.assert_allclose(s, np.max(np.stack(list(features.values())), axis=0))


def test_zscore_nan_rows_score_inf_without_moving_the_others():
    means, log_scales, logits = gaussian_cloud(50)
    clean = zscore_scores(means, log_scales, logits)
    means2 = np.vstack([means, [[np.nan, 0, 0]], [[0, 0, 0]]])
    log_scales2 = np.vstack([log_scales, [[0, 0, 0]], [[0, np.inf, 0]]])
    logits2 = np.concatenate([logits, [0.0, 0.0]])
    s = zscore_scores(means2, log_scales2, logits2)
    assert np.isposinf(s[50:]).all()
    np.testing.assert_allclose(s[:50], clean)
    assert zscore_scores(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)).shape == (0,)
    with pytest.raises(ValueError, match="same number of rows"):
        zscore_scores(means, log_scales, logits[:-1])
    with pytest.raises(ValueError, match="means"):
        zscore_scores(means[:, :2], log_scales, logits)


# ------------------------------------------------------------------------------------------ SOR


def open3d_removed(points: np.ndarray, k: int, std_ratio: float) -> set[int]:
    o3d = pytest.importorskip("open3d")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=k, std_ratio=std_ratio)
    return set(range(len(points))) - set(kept)


def test_sor_ranks_planted_far_points_first():
    rng = np.random.default_rng(1)
    blob = rng.normal(size=(500, 3)) * 0.3
    far = rng.normal(size=(5, 3))
    far = 8.0 * far / np.linalg.norm(far, axis=1, keepdims=True)
    s = sor_scores(np.vstack([blob, far]), k=20)
    assert top(s, 5) == set(range(500, 505))
    assert (s[500:] > 2.0).all()


def between_scores(s: np.ndarray) -> np.ndarray:
    """Positive thresholds halfway between consecutive distinct scores (none on a boundary)."""
    u = np.unique(s)
    mid = (u[1:] + u[:-1]) / 2
    return mid[mid > 0]


def just_below_scores(s: np.ndarray) -> np.ndarray:
    """A threshold a hair (1e-9 relative) below each positive score: sensitive to any rescaling."""
    return s[s > 0] * (1 - 1e-9)


@pytest.mark.parametrize(("n", "k"), [(400, 20), (60, 5), (12, 20)])
def test_sor_matches_open3d_remove_statistical_outlier(n, k):
    """``score > r`` removes exactly what open3d's remove_statistical_outlier(k, r) removes, at r = 2
    and at every threshold between two scores; N <= k (12 < 20) included."""
    rng = np.random.default_rng(n)
    points = np.vstack([rng.normal(size=(n, 3)), rng.uniform(-6, 6, size=(4, 3))])
    s = sor_scores(points, k=k)
    assert set(np.flatnonzero(s > 2.0)) == open3d_removed(points, k, 2.0)
    thresholds = np.concatenate([between_scores(s), just_below_scores(s)])
    for r in thresholds[:: max(1, len(thresholds) // 60)]:
        assert set(np.flatnonzero(s > r)) == open3d_removed(points, k, float(r)), r


def test_open3d_counts_the_point_itself_and_uses_the_sample_std():
    """The two facts sor_scores relies on: the alternatives (self excluded, population std) disagree
    with open3d somewhere on this cloud."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    points = rng.normal(size=(200, 3))
    k = 5
    dist, _ = cKDTree(points).query(points, k=k + 1)
    variants = {"self excluded": dist[:, 1:].mean(1), "self included": dist[:, :k].mean(1)}
    for name, d in variants.items():
        for ddof in (0, 1):
            z = (d - d.mean()) / d.std(ddof=ddof)
            rs = np.concatenate([between_scores(z), just_below_scores(z)])
            agree = all(set(np.flatnonzero(z > r)) == open3d_removed(points, k, r) for r in rs)
            assert agree == (name == "self included" and ddof == 1), (name, ddof)
    d = variants["self included"]
    np.testing.assert_allclose(sor_scores(points, k), (d - d.mean()) / d.std(ddof=1))


def test_sor_small_degenerate_and_nonfinite_clouds():
    assert sor_scores(np.zeros((0, 3))).shape == (0,)
    np.testing.assert_array_equal(sor_scores(np.ones((1, 3))), [0.0])
    np.testing.assert_array_equal(sor_scores(np.zeros((5, 3))), np.zeros(5))  # std 0
    rng = np.random.default_rng(4)
    points = rng.normal(size=(30, 3))
    bad = np.vstack([points[:10], [[np.nan, 0, 0]], points[10:], [[np.inf, 1, 1]]])
    s = sor_scores(bad, k=6)
    assert np.isposinf(s[[10, 31]]).all()
    np.testing.assert_allclose(np.delete(s, [10, 31]), sor_scores(points, k=6))
    with pytest.raises(ValueError, match="at least 1"):
        sor_scores(points, k=0)


# -------------------------------------------------------------------------------- concentration


def test_concentration_is_one_over_the_effective_number_of_views():
    w = np.array(
        [
            [0.0, 3.0, 0.0, 0.0],  # one view -> 1
            [1.0, 1.0, 1.0, 1.0],  # all V equally -> 1/V
            [2.0, 2.0, 0.0, 0.0],  # two equal views -> 1/2
            [0.0, 0.0, 0.0, 0.0],  # never seen -> 0
            [1e-15, 0.0, 0.0, 0.0],  # below eps -> 0
            [1.0, 2.0, 3.0, 4.0],
        ]
    )
    s = concentration_scores(w)
    p = np.array([1, 2, 3, 4]) / 10
    np.testing.assert_allclose(s, [1.0, 0.25, 0.5, 0.0, 0.0, np.exp(np.sum(p * np.log(p)))])
    assert s[0] == 1.0
    np.testing.assert_allclose(concentration_scores(7.5 * w), s)  # unit-free
    np.testing.assert_allclose(concentration_scores(w.astype(np.float32)), s, rtol=1e-6)
    assert concentration_scores(np.zeros((0, 4))).shape == (0,)


def test_concentration_nonfinite_rows_negative_weights_and_blocks(monkeypatch):
    w = np.array([[1.0, np.nan], [np.inf, 1.0], [1.0, 1.0]])
    np.testing.assert_array_equal(concentration_scores(w), [np.inf, np.inf, 0.5])
    with pytest.raises(ValueError, match="non-negative"):
        concentration_scores(np.array([[1.0, -0.5], [1.0, 1.0]]))
    with pytest.raises(ValueError, match=r"\(N, V\)"):
        concentration_scores(np.ones(3))
    big = np.random.default_rng(5).exponential(size=(37, 6)) * (np.arange(6) < 4)
    whole = concentration_scores(big)
    monkeypatch.setattr(scores, "_ROWS_PER_BLOCK", 5)
    np.testing.assert_array_equal(concentration_scores(big), whole)


# ------------------------------------------------------------------------------------ count cap


def test_count_cap_keeps_the_most_important():
    importance = np.array([5.0, 0.1, 3.0, 9.0, 0.5, 7.0])
    np.testing.assert_array_equal(count_cap_scores(importance), -importance)
    pruned = count_cap_mask(importance, keep=3)
    np.testing.assert_array_equal(np.flatnonzero(~pruned), [0, 3, 5])  # the 3 largest kept
    assert not count_cap_mask(importance, keep=6).any()
    assert not count_cap_mask(importance, keep=10).any()
    assert count_cap_mask(importance, keep=0).all()
    with pytest.raises(ValueError, match="keep"):
        count_cap_mask(importance, keep=-1)


def test_count_cap_ties_and_nonfinite_are_deterministic():
    importance = np.array([1.0, 1.0, 1.0, 2.0, np.nan])
    # nan pruned first, then the tied 1.0s by ascending index: keep 2 -> 3 and 2 kept
    np.testing.assert_array_equal(count_cap_mask(importance, keep=2), [True, True, False, False, True])
    for keep in range(6):
        np.testing.assert_array_equal(
            count_cap_mask(importance, keep), prune_mask_top_count(count_cap_scores(importance), 5 - keep)
        )


# ----------------------------------------------------------------------------- detection metrics


def test_detection_metrics_known_answer():
    # descending: 0.8 (poison), 0.4 (clean), 0.35 (poison), 0.1 (clean).
    # AUROC: poison-clean pairs ranked right: 0.8>0.4, 0.8>0.1, 0.35>0.1, but 0.35<0.4 -> 3/4.
    # AP = sum over poison hits of (recall step) * precision = 0.5 * 1/1 + 0.5 * 2/3 = 5/6.
    m = detection_metrics(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1], dtype=bool))
    assert m["auroc"] == 0.75
    assert m["average_precision"] == pytest.approx(5 / 6, abs=1e-6)  # torchmetrics counts in float32
    assert (m["n_poison"], m["n_clean"], m["prevalence"], m["reason"]) == (2, 2, 0.5, None)


def test_detection_metrics_perfect_reversed_and_one_class():
    y = np.array([False, False, True, True])
    perfect = detection_metrics(np.array([0.0, 1.0, 2.0, 3.0]), y)
    assert (perfect["auroc"], perfect["average_precision"]) == (1.0, 1.0)
    assert detection_metrics(np.array([3.0, 2.0, 1.0, 0.0]), y)["auroc"] == 0.0
    # scores far outside [0, 1] keep their order (torchmetrics alone would sigmoid them to 1.0)
    assert detection_metrics(np.array([30.0, 40.0, 50.0, 60.0]), y)["auroc"] == 1.0
    # NaN is the most suspicious score
    nan_case = detection_metrics(np.array([0.1, 0.2, 0.05, np.nan]), np.array([0, 0, 1, 1]))
    assert nan_case["auroc"] == 0.5 and nan_case["n_nonfinite"] == 1
    for labels in (np.zeros(4, bool), np.ones(4, bool)):
        m = detection_metrics(np.arange(4.0), labels)
        assert m["auroc"] is None and m["average_precision"] is None
        assert "both classes" in m["reason"]
    assert detection_metrics(np.zeros(0), np.zeros(0, bool))["reason"]
    with pytest.raises(ValueError, match="is_poison"):
        detection_metrics(np.arange(4.0), np.array([0, 1, 2, 0]))


def test_detection_metrics_agree_with_sklearn():
    metrics = pytest.importorskip("sklearn.metrics")
    rng = np.random.default_rng(6)
    y = rng.random(400) < 0.05
    s = np.round(rng.normal(size=400) + 1.5 * y, 1) * 10  # ties, values far outside [0, 1]
    m = detection_metrics(s, y)
    assert m["auroc"] == pytest.approx(metrics.roc_auc_score(y, s), abs=1e-6)
    assert m["average_precision"] == pytest.approx(metrics.average_precision_score(y, s), abs=1e-6)


# ------------------------------------------------------------------------------ pruning rules


def test_prune_masks_are_deterministic_nested_and_rounded_half_up():
    s = np.array([1.0, 2.0, 2.0, 2.0, 0.0])
    np.testing.assert_array_equal(prune_mask_top_fraction(s, 0.4), [False, True, True, False, False])
    assert prune_mask_top_fraction(s, 0.5).sum() == 3  # 2.5 -> 3
    assert prune_mask_top_fraction(s, 0.1).sum() == 1  # 0.5 -> 1
    assert not prune_mask_top_fraction(s, 0.0).any() and prune_mask_top_fraction(s, 1.0).all()
    rng = np.random.default_rng(7)
    r = rng.integers(0, 5, size=200).astype(float)
    masks = [prune_mask_top_fraction(r, f) for f in sweep_fractions()]
    for small, large in zip(masks, masks[1:], strict=False):
        assert (large | ~small).all()  # nested
    np.testing.assert_array_equal(prune_mask_top_fraction(np.array([0.3, np.nan, 0.9]), 1 / 3), [0, 1, 0])
    with pytest.raises(ValueError, match="fraction"):
        prune_mask_top_fraction(s, 1.5)


def test_prune_mask_threshold_is_strict():
    s = np.array([3.5, 3.6, np.nan, -np.inf, np.inf])
    np.testing.assert_array_equal(prune_mask_threshold(s, 3.5), [False, True, True, False, True])


def test_operating_point_counts():
    y = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=bool)
    pruned = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], dtype=bool)
    op = operating_point(y, pruned)
    assert op == {
        "n_pruned": 4,
        "n_poison": 4,
        "n_clean": 6,
        "n_poison_pruned": 3,
        "n_clean_pruned": 1,
        "poison_removed": 0.75,
        "clean_removed": 1 / 6,
    }
    no_poison = operating_point(np.zeros(3, bool), np.array([True, False, False]))
    assert no_poison["poison_removed"] is None and no_poison["clean_removed"] == pytest.approx(1 / 3)
    assert operating_point(np.ones(2, bool), np.ones(2, bool))["clean_removed"] is None
    with pytest.raises(ValueError):
        operating_point(y, pruned[:-1])


def test_sweep_fractions():
    assert sweep_fractions() == [0.0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.2, 0.3, 0.5]
    assert sweep_fractions() == list(detection.DEFAULT_SWEEP)
    f = sweep_fractions(5)
    assert f[0] == 0.0 and f[1] == 0.001 and f[-1] == 0.5 and len(f) == 5
    assert f == sorted(f)
    assert math.isclose(f[2] / f[1], f[3] / f[2], rel_tol=0.01)
    with pytest.raises(ValueError):
        sweep_fractions(1)
