"""Evaluation metrics over valid pixels (numpy; images ``(H, W, C)``, mask ``(H, W)``).

- ``psnr``: ``10 log10(peak^2 / MSE)`` over masked pixels (peak 1 for maps in [0, 1]).
- ``si_psnr``: PSNR after one global least-squares scale ``s = <x, y> / <x, x>`` applied to the
  prediction (the display's absolute brightness is unknown: albedo is defined up to scale).
- ``rmse`` and ``si_rmse`` likewise.
- ``normal_mae_deg``: mean angle between unit normals, in degrees.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["psnr", "si_psnr", "rmse", "si_rmse", "ls_scale", "normal_mae_deg"]


def _masked(pred: NDArray, target: NDArray, mask: NDArray) -> tuple[NDArray, NDArray]:
    pred, target = np.asarray(pred, dtype=np.float64), np.asarray(target, dtype=np.float64)
    if pred.shape != target.shape:
        raise ValueError(f"prediction {pred.shape} and target {target.shape} differ in shape")
    m = np.asarray(mask, dtype=bool)
    if m.shape != pred.shape[: m.ndim]:
        raise ValueError(f"mask {m.shape} does not match images {pred.shape}")
    if not m.any():
        raise ValueError("empty mask: no pixel to evaluate")
    return pred[m], target[m]


def ls_scale(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """Least-squares scale ``s`` minimising ``|s * pred - target|^2`` over the mask (1 if pred = 0)."""
    x, y = _masked(pred, target, mask)
    den = float(np.sum(x * x))
    return float(np.sum(x * y) / den) if den > 0 else 1.0


def rmse(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """Root-mean-square error over masked pixels and channels."""
    x, y = _masked(pred, target, mask)
    return float(np.sqrt(np.mean((x - y) ** 2)))


def si_rmse(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """:func:`rmse` after the global least-squares scale."""
    return rmse(ls_scale(pred, target, mask) * np.asarray(pred, dtype=np.float64), target, mask)


def psnr(pred: NDArray, target: NDArray, mask: NDArray, *, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB over masked pixels (``inf`` for a perfect prediction)."""
    e = rmse(pred, target, mask)
    return float("inf") if e == 0 else float(20 * np.log10(peak / e))


def si_psnr(pred: NDArray, target: NDArray, mask: NDArray, *, peak: float = 1.0) -> float:
    """:func:`psnr` after the global least-squares scale."""
    return psnr(ls_scale(pred, target, mask) * np.asarray(pred, dtype=np.float64), target, mask, peak=peak)


def normal_mae_deg(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """Mean angular error in degrees between normal maps ``(H, W, 3)`` (renormalised first)."""
    x, y = _masked(pred, target, mask)
    x = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
    y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-12)
    return float(np.degrees(np.arccos(np.clip(np.sum(x * y, axis=-1), -1.0, 1.0))).mean())
