"""network/statistics.py: bootstrap intervals that cover, weights that weigh."""

import numpy as np
import pytest

from network.statistics import bootstrap_ci, correlation, summarize, summary_text


def test_interval_covers_the_true_mean_about_95_percent_of_the_time():
    rng = np.random.default_rng(0)
    hits = 0
    trials = 200
    for t in range(trials):
        x = rng.exponential(2.0, size=48)  # skewed, like per-scene errors; true mean 2
        lo, hi = bootstrap_ci(x, seed=t, resamples=1000)
        hits += lo <= 2.0 <= hi
    # Percentile bootstrap of a skewed mean at n = 48 under-covers slightly; 95 % +- 5 % here.
    assert 0.88 <= hits / trials <= 0.99


def test_weighted_mean_and_interval_follow_the_weights():
    s = summarize([1.0, 10.0], [99, 1], seed=0)
    assert s["mean"] == pytest.approx(5.5)
    assert s["weighted_mean"] == pytest.approx((99 + 10) / 100)
    assert s["weighted_ci"][0] <= s["weighted_mean"] <= s["weighted_ci"][1]


def test_non_finite_and_missing_values_are_dropped_and_counted():
    s = summarize([1.0, None, float("inf"), 3.0])
    assert (s["mean"], s["count"], s["dropped"]) == (2.0, 2, 2)
    empty = summarize([None, float("nan")])
    assert empty["mean"] is None and empty["ci"] is None and empty["count"] == 0


def test_single_value_interval_is_the_value():
    assert bootstrap_ci([3.0]) == (3.0, 3.0)
    assert all(np.isnan(bootstrap_ci([])))


def test_correlation_matches_numpy_and_its_interval_covers_the_population_value():
    rng = np.random.default_rng(3)
    x = rng.uniform(0.05, 0.95, 200)
    y = 0.6 * x + rng.normal(0.0, 0.15, 200)  # population r = 0.6 sd(x) / sqrt(0.36 var(x) + 0.0225)
    c = correlation(x, y)
    assert c["r"] == pytest.approx(np.corrcoef(x, y)[0, 1], abs=1e-12)
    sx = np.sqrt(0.9**2 / 12)
    rho = 0.6 * sx / np.sqrt(0.36 * sx**2 + 0.15**2)
    assert c["ci"][0] < rho < c["ci"][1] and c["ci"][1] - c["ci"][0] < 0.2
    assert c["count"] == 200


def test_correlation_of_a_constant_or_too_few_pairs_is_none_and_bad_pairs_are_dropped():
    assert correlation([0.1, 0.5, 0.9], [0.4, 0.4, 0.4])["r"] is None  # a constant predictor
    assert correlation([0.1, 0.5, 0.9], [0.4, 0.4 + 3e-8, 0.4 - 2e-8])["r"] is None  # float32 means of a constant
    assert correlation([0.1, 0.5], [0.2, 0.6])["r"] is None
    c = correlation([0.1, None, 0.5, 0.9, float("nan")], [0.2, 0.3, 0.55, 0.8, 0.1])
    assert c["count"] == 3 and c["r"] == pytest.approx(np.corrcoef([0.1, 0.5, 0.9], [0.2, 0.55, 0.8])[0, 1])
    assert correlation([0.1, 0.5, 0.9], [-0.1, -0.5, -0.9])["r"] == pytest.approx(-1.0)


def test_summary_text_is_the_report_tables_form():
    s = summarize([1.0, 2.0, 4.0], weights=[1, 1, 2], seed=0)
    lo, hi = s["ci"]
    assert summary_text(s, 3) == f"2.333 [{lo:.3f}, {hi:.3f}]"  # (1 + 2 + 4) / 3
    both = {"mean": 2.0, "ci": [1.0, 4.0], "weighted_mean": 2.75, "weighted_ci": [2.5, 3.0]}
    assert summary_text(both, 2, key="weighted_mean") == "2.75 [2.50, 3.00]"  # the weighted mean's own interval
    assert summary_text({"mean": -0.25, "ci": [-0.5, 0.125]}, 2, signed=True) == "-0.25 [-0.50, +0.12]"
    assert summary_text({"mean": 0.0, "ci": [None, None]}, 1, signed=True) == "+0.0"  # no interval to show
    assert summary_text({"r": 0.91, "ci": [0.8, 0.97]}, 2, key="r") == "0.91 [0.80, 0.97]"
    assert summary_text(summarize([None, float("nan")]), 2) == "n/a"
