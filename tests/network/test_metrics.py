"""Tests of network/metrics.py against hand-computed values."""

import numpy as np
import pytest

from network import metrics


def test_metrics_hand_computed():
    t = np.zeros((2, 2, 1))
    p = np.full((2, 2, 1), 0.1)
    m = np.array([[True, True], [False, True]])
    assert metrics.rmse(p, t, m) == pytest.approx(0.1)
    assert metrics.psnr(p, t, m) == pytest.approx(20.0)  # 20 log10(1 / 0.1)
    y = np.array([[[0.2], [0.4]], [[9.0], [0.6]]])
    x = y / 2  # half as bright: scale-invariant metrics forgive it
    assert metrics.ls_scale(x, y, m) == pytest.approx(2.0)
    assert metrics.si_rmse(x, y, m) == pytest.approx(0.0, abs=1e-12)
    assert metrics.si_psnr(x, y, m) == float("inf")
    n1 = np.array([[[0, 0, 1.0]]])
    n2 = np.array([[[0, 1.0, 1.0]]])
    assert metrics.normal_mae_deg(n2, n1, np.ones((1, 1), bool)) == pytest.approx(45.0)
    with pytest.raises(ValueError, match="empty mask"):
        metrics.rmse(p, t, np.zeros((2, 2), bool))


def test_mse_and_scale_invariant_metrics_by_hand():
    pred = np.array([[[1.0], [2.0]]])
    target = np.array([[[2.0], [2.0]]])
    m = np.ones((1, 2), bool)
    # s = (1*2 + 2*2) / (1 + 4) = 1.2; residuals (1.2 - 2, 2.4 - 2) = (-0.8, 0.4); MSE = (0.64 + 0.16) / 2 = 0.4.
    assert metrics.ls_scale(pred, target, m) == pytest.approx(1.2)
    assert metrics.si_mse(pred, target, m) == pytest.approx(0.4)
    assert metrics.si_rmse(pred, target, m) == pytest.approx(np.sqrt(0.4))
    assert metrics.si_psnr(pred, target, m) == pytest.approx(10 * np.log10(1 / 0.4))
    assert metrics.mse(pred, target, m) == pytest.approx(0.5)  # (1 + 0) / 2
    assert metrics.si_psnr(pred, target, m, peak=2.0) == pytest.approx(10 * np.log10(4 / 0.4))


def test_normal_angle_matches_atan2_of_cross_and_dot(rng):
    # Independent formula: angle = atan2(|a x b|, a . b), unaffected by the lengths of a and b.
    a = rng.normal(size=(200, 3)) * rng.uniform(0.1, 10, (200, 1))
    b = rng.normal(size=(200, 3)) * rng.uniform(0.1, 10, (200, 1))
    want = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, -1)))
    got = metrics.normal_angle_deg(a, b)
    np.testing.assert_allclose(got, want, atol=1e-5)
    mask = np.ones((10, 20), bool)
    assert metrics.normal_mae_deg(a.reshape(10, 20, 3), b.reshape(10, 20, 3), mask) == pytest.approx(want.mean())
