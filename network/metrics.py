"""Evaluation metrics over valid pixels (numpy; images ``(H, W, C)``, mask ``(H, W)``).

- ``psnr``: ``10 log10(peak^2 / MSE)`` over masked pixels (peak 1 for maps in [0, 1]).
- ``si_psnr``: PSNR after one global least-squares scale ``s = <x, y> / <x, x>`` applied to the
  prediction (the display's absolute brightness is unknown: albedo is defined up to scale).
- ``rmse`` and ``si_rmse`` likewise.
- ``normal_mae_deg``: mean angle between unit normals, in degrees.
- ``mse`` and ``si_mse``: mean squared error (the re-rendering error on real data).
- ``lpips`` and ``si_lpips``: LPIPS v0.1 AlexNet (:mod:`network.lpips`) on the mask's bounding
  box, images divided by ``peak`` and clipped to [0, 1]; ``si_lpips`` after the global scale.
  They raise ``FileNotFoundError`` when no LPIPS weights are installed
  (:func:`network.lpips.lpips_status`).

Example:
    A prediction half as bright as the target: PSNR sees the error, the scale-invariant PSNR does not.

    >>> target = np.full((2, 2, 3), 0.4)
    >>> pred, mask = target / 2, np.ones((2, 2), bool)
    >>> round(psnr(pred, target, mask), 2), si_psnr(pred, target, mask), ls_scale(pred, target, mask)
    (13.98, inf, 2.0)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "normal_angle_deg",
    "psnr",
    "si_psnr",
    "rmse",
    "si_rmse",
    "mse",
    "si_mse",
    "ls_scale",
    "normal_mae_deg",
    "si_depth_error",
    "lpips",
    "si_lpips",
]

#: LPIPS inputs smaller than this (mask bounding box) are upsampled to it (AlexNet needs >= 31 px).
LPIPS_MIN_SIZE = 64


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


def normal_angle_deg(pred: ArrayLike, target: ArrayLike) -> NDArray[np.float64]:
    """Angle in degrees between normal vectors ``(..., 3)``, each renormalised first; in [0, 180].

    A zero vector has no direction: its angle to anything is 90 degrees (cosine 0).

    Example:
        >>> normal_angle_deg([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], [[0.0, 1.0, 1.0], [0.0, 0.0, -2.0]])
        array([ 45., 180.])
    """
    x = np.asarray(pred, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    x = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
    y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-12)
    return np.degrees(np.arccos(np.clip(np.sum(x * y, axis=-1), -1.0, 1.0)))


def normal_mae_deg(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """Mean angular error in degrees (:func:`normal_angle_deg`) between normal maps ``(H, W, 3)`` on the mask."""
    x, y = _masked(pred, target, mask)
    return float(normal_angle_deg(x, y).mean())


def si_depth_error(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """Scale-invariant depth error in percent: mean ``|ln(pred / target) - median(ln(pred / target))|``.

    Normals fix a surface's shape, not its distance: the median log ratio (the overall scale) is
    removed first. Pixels where either depth is not positive count as the largest error seen.

    Example:
        >>> t = np.array([[1.0, 2.0], [4.0, 8.0]])
        >>> si_depth_error(3 * t, t, np.ones((2, 2), bool))  # a scaled copy is exact
        0.0
        >>> round(si_depth_error(np.ones((2, 2)), t, np.ones((2, 2), bool)), 2)  # flat vs steep
        69.31
    """
    x, y = _masked(pred, target, mask)
    ok = (x > 0) & (y > 0)
    if not ok.any():
        return math.inf
    r = np.log(x[ok] / y[ok])
    err = np.abs(r - np.median(r))
    worst = float(err.max()) if err.size else 0.0
    return float(100.0 * np.concatenate([err, np.full(int((~ok).sum()), worst)]).mean())


def mse(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """Mean squared error over masked pixels and channels."""
    return rmse(pred, target, mask) ** 2


def si_mse(pred: NDArray, target: NDArray, mask: NDArray) -> float:
    """:func:`mse` after the global least-squares scale."""
    return si_rmse(pred, target, mask) ** 2


def _lpips_image(img: NDArray, mask: NDArray, box: tuple[int, int, int, int], peak: float):
    import torch  # noqa: PLC0415  (metrics stay importable without torch)
    import torch.nn.functional as F  # noqa: N812, PLC0415

    y0, x0, y1, x1 = box
    a = np.where(mask[..., None], np.asarray(img, dtype=np.float64), 0.0)[y0:y1, x0:x1]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    t = torch.from_numpy(np.clip(a / peak, 0.0, 1.0).astype(np.float32).transpose(2, 0, 1))[None] * 2 - 1
    h, w = t.shape[-2:]
    if min(h, w) < LPIPS_MIN_SIZE:
        f = LPIPS_MIN_SIZE / min(h, w)
        t = F.interpolate(t, size=(round(h * f), round(w * f)), mode="bilinear", align_corners=False)
    return t


def lpips(pred: NDArray, target: NDArray, mask: NDArray, *, peak: float = 1.0, weights: str | None = None) -> float:
    """LPIPS (AlexNet, v0.1) between ``(H, W, 3)`` (or ``(H, W, 1)``) images on the mask's bounding box.

    Pixels outside the mask are set to 0 in both images, the box is upsampled to at least
    :data:`LPIPS_MIN_SIZE` px, values are divided by ``peak`` and clipped to [0, 1] (then mapped to
    LPIPS's [-1, 1]). ``weights``: an LPIPS weight file (default: see :mod:`network.lpips`).
    """
    import torch  # noqa: PLC0415

    from .lpips import load_lpips  # noqa: PLC0415

    _masked(pred, target, mask)  # shape and empty-mask checks
    if np.asarray(pred).shape[-1] not in (1, 3):
        raise ValueError(f"LPIPS needs 1 or 3 channels, got {np.asarray(pred).shape}")
    m = np.asarray(mask, dtype=bool)
    ys, xs = np.nonzero(m)
    box = (int(ys.min()), int(xs.min()), int(ys.max()) + 1, int(xs.max()) + 1)
    model = load_lpips(weights)
    with torch.no_grad():
        return float(model(_lpips_image(pred, m, box, peak), _lpips_image(target, m, box, peak))[0])


def si_lpips(pred: NDArray, target: NDArray, mask: NDArray, *, peak: float = 1.0, weights: str | None = None) -> float:
    """:func:`lpips` after the global least-squares scale."""
    scaled = ls_scale(pred, target, mask) * np.asarray(pred, dtype=np.float64)
    return lpips(scaled, target, mask, peak=peak, weights=weights)
