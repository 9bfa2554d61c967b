"""Summary statistics of per-scene scores: means with 95 % bootstrap confidence intervals.

Two means of a metric over the scenes of a split:

* the per-scene mean, every scene counting once;
* the pixel-weighted mean, every scene weighted by its number of scored pixels (what one gets by
  pooling all pixels, for per-pixel means such as the normal MAE).

Both come with a percentile bootstrap interval that resamples whole scenes (scenes are the
independent units; pixels of one scene are not). Non-finite scores (e.g. PSNR of a perfect
prediction) are left out and counted.

Example:
    >>> s = summarize([1.0, 2.0, 3.0, 4.0], weights=[1, 1, 1, 5], seed=0)
    >>> s["mean"], s["weighted_mean"], s["count"]
    (2.5, 3.25, 4)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["bootstrap_ci", "correlation", "summarize", "summary_text"]


def bootstrap_ci(
    values: Sequence[float],
    weights: Sequence[float] | None = None,
    *,
    level: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap interval of the (weighted) mean, resampling the entries.

    Args:
        values: ``(N,)`` finite per-scene scores.
        weights: ``(N,)`` non-negative weights (pixel counts); None for the plain mean.
        level: coverage of the interval.
        resamples: bootstrap resamples (2000 gives the 2.5 % and 97.5 % quantiles to about
            +-0.5 % of the interval's width).
        seed: seed of the resampling, so the interval is reproducible.

    Returns:
        ``(low, high)``; ``(mean, mean)`` for a single value; NaN for none.

    Example:
        >>> lo, hi = bootstrap_ci(np.arange(100.0), seed=1)
        >>> bool(lo < 49.5 < hi), bool(hi - lo < 25)
        (True, True)
    """
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan
    w = np.ones_like(v) if weights is None else np.asarray(weights, dtype=np.float64)
    if v.size == 1:
        return float(v[0]), float(v[0])
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, v.size, size=(resamples, v.size))
    ws = w[idx]
    total = ws.sum(axis=1)
    means = np.where(total > 0, (v[idx] * ws).sum(axis=1) / np.where(total > 0, total, 1.0), np.nan)
    means = means[np.isfinite(means)]
    alpha = (1.0 - level) / 2.0
    return float(np.quantile(means, alpha)), float(np.quantile(means, 1.0 - alpha))


def summarize(
    values: Sequence[float | None], weights: Sequence[float] | None = None, *, seed: int = 0
) -> dict[str, float | int | None]:
    """Per-scene mean and pixel-weighted mean of one metric, each with a 95 % bootstrap interval.

    Args:
        values: ``(N,)`` per-scene scores; None or non-finite entries are left out.
        weights: ``(N,)`` pixel counts of the scenes (None: the weighted mean equals the mean).
        seed: bootstrap seed.

    Returns:
        JSON-ready dict: ``mean``, ``ci`` ``[low, high]``, ``weighted_mean``, ``weighted_ci``,
        ``count`` (finite values used) and ``dropped`` (None or non-finite values); numbers are
        None where there is nothing to average.
    """
    v = np.array([np.nan if x is None else float(x) for x in values], dtype=np.float64)
    w = np.ones_like(v) if weights is None else np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(v)
    v, w = v[ok], w[ok]

    def num(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    if v.size == 0:
        return {"mean": None, "ci": None, "weighted_mean": None, "weighted_ci": None, "count": 0,
                "dropped": int((~ok).sum())}  # fmt: skip
    lo, hi = bootstrap_ci(v, seed=seed)
    wlo, whi = bootstrap_ci(v, w, seed=seed)
    wmean = float((v * w).sum() / w.sum()) if w.sum() > 0 else math.nan
    return {
        "mean": num(float(v.mean())),
        "ci": [num(lo), num(hi)],
        "weighted_mean": num(wmean),
        "weighted_ci": [num(wlo), num(whi)],
        "count": int(v.size),
        "dropped": int((~ok).sum()),
    }


def correlation(
    x: Sequence[float | None], y: Sequence[float | None], *, resamples: int = 2000, seed: int = 0
) -> dict[str, float | int | None]:
    """Pearson correlation of paired values with a 95 % percentile bootstrap interval over the pairs.

    Used per object: does a method's mean roughness follow the true one, beyond its RMSE (a
    constant answer has a fine RMSE on a narrow split and no correlation at all).

    Args:
        x: ``(N,)`` first values (e.g. the true per-object roughness); None or non-finite pairs are left out.
        y: ``(N,)`` second values (the predicted ones).
        resamples: bootstrap resamples.
        seed: bootstrap seed.

    Returns:
        JSON-ready dict: ``r``, ``ci`` ``[low, high]`` and ``count`` (pairs used); ``r`` is None with
        fewer than 3 pairs or when either side is constant (a constant predictor has no correlation).

    Example:
        >>> c = correlation([0.1, 0.2, 0.3, 0.4, 0.5], [0.12, 0.18, 0.33, 0.41, 0.49])
        >>> round(c["r"], 3), c["count"], c["ci"][0] > 0.9
        (0.991, 5, True)
    """
    a = np.array([np.nan if v is None else float(v) for v in x], dtype=np.float64)
    b = np.array([np.nan if v is None else float(v) for v in y], dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    empty = {"r": None, "ci": None, "count": int(a.size)}
    # "constant" up to float32 rounding (a constant map's per-object means differ in the 8th digit)
    if a.size < 3 or np.ptp(a) <= 1e-6 * max(1.0, np.abs(a).max()) or np.ptp(b) <= 1e-6 * max(1.0, np.abs(b).max()):
        return empty

    def pearson(p: np.ndarray, q: np.ndarray) -> np.ndarray:  # rows of resampled pairs -> r per row
        p = p - p.mean(-1, keepdims=True)
        q = q - q.mean(-1, keepdims=True)
        den = np.sqrt((p * p).sum(-1) * (q * q).sum(-1))
        return np.where(den > 0, (p * q).sum(-1) / np.where(den > 0, den, 1.0), np.nan)

    idx = np.random.default_rng(seed).integers(0, a.size, size=(resamples, a.size))
    boot = pearson(a[idx], b[idx])
    boot = boot[np.isfinite(boot)]  # a resample of one repeated pair has no correlation
    r = float(np.clip(pearson(a, b), -1.0, 1.0))
    ci = [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))] if boot.size else None
    return {"r": r, "ci": ci, "count": int(a.size)}


def summary_text(s: Mapping[str, Any], digits: int, *, key: str = "mean", signed: bool = False) -> str:
    """``mean [low, high]`` of a summary, as every report table writes it; ``n/a`` without a value.

    Args:
        s: a summary with the value under ``key`` and its interval under ``"weighted_ci"`` for
            ``key="weighted_mean"``, else ``"ci"`` (:func:`summarize`, :func:`correlation` with
            ``key="r"``, a paired difference); the interval is left out where it is missing or None.
        digits: decimals of every number.
        key: the value's key.
        signed: a ``+`` before positive numbers (differences).

    Returns:
        The text, e.g. ``"1.23 [1.00, 1.50]"``.

    Example:
        >>> summary_text({"mean": 1.234, "ci": [1.0, 1.5]}, 2)
        '1.23 [1.00, 1.50]'
        >>> summary_text({"mean": -0.5, "ci": None}, 1, signed=True)
        '-0.5'
        >>> summary_text({"weighted_mean": 0.26, "weighted_ci": [0.21, 0.3]}, 1, key="weighted_mean", signed=True)
        '+0.3 [+0.2, +0.3]'
        >>> summary_text(summarize([]), 2)
        'n/a'
    """
    value, ci = s.get(key), s.get("weighted_ci" if key == "weighted_mean" else "ci")
    if value is None:
        return "n/a"
    form = f"{{:{'+' if signed else ''}.{digits}f}}"
    if not ci or ci[0] is None:
        return form.format(value)
    return f"{form.format(value)} [{form.format(ci[0])}, {form.format(ci[1])}]"
