"""Rig imperfections of the forward model and their inverses: ambient light, spectral cross-talk, vignetting.

The forward chain (:func:`pbrdf.sensor.camera.simulate_capture`) applies them to the rendered
Stokes images ``(H, W, 3, 4)``, whose colour ``r`` is the light of display colour region ``r``:

1. cross-talk: camera channel ``c`` sees ``sum_r M[c, r] S_r`` (``M`` = ``crosstalk``, rows camera
   channel, columns display region; identity nominal);
2. ambient: unpolarized room light ``(a_c, 0, 0, 0)`` added per camera channel;
3. vignetting: every Stokes component times the lens falloff ``V(pixel)`` (below).

The decoder (:func:`pbrdf.sensor.decode.decode`) undoes them in reverse: the dark frame (display
off: ambient and sensor offset) is subtracted from each bracket in DN, the merged mosaic is divided
by ``V`` at every raw pixel, and the measured ``(s0, s1, s3)`` of the three channels are unmixed with
``M^-1``. Physical meaning and ranges: ``docs/rig_imperfections.md``.

Vignetting: ``V = cos^4(atan(d / f)) * (1 + k1 rho^2 + k2 rho^4 + k3 rho^6)`` with ``d`` the distance
in pixels of a pixel centre from the frame centre, ``f`` = ``vignetting_focal_px`` (``inf``: no
cos^4 term) and ``rho = d / d_max`` (``d_max`` the half-diagonal of the frame).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "IDENTITY3",
    "IMPERFECTION_RANGES",
    "CROSSTALK_MAX_COND",
    "VIGNETTING_MIN",
    "check_crosstalk",
    "check_vignetting_poly",
    "vignetting_map",
    "apply_rig_imperfections",
]

#: The nominal cross-talk: each display region reaches only its own camera channel.
IDENTITY3: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
#: Valid ranges ``(low, high)``, both inclusive, of the imperfection fields of ``CameraModel``.
IMPERFECTION_RANGES = {
    "ambient": (0.0, 1e4),  # radiance units, per camera channel
    "crosstalk": (0.0, 1.0),  # each entry of the 3 x 3 mixing
    "vignetting_focal_px": (1.0, math.inf),  # inf: no cos^4 falloff
    "vignetting_poly": (-10.0, 10.0),  # k1, k2, k3
}
#: Largest accepted condition number of the cross-talk matrix (beyond it the unmixing amplifies noise 100x).
CROSSTALK_MAX_COND = 100.0
#: Smallest accepted value of the polynomial factor over the frame (the decoder divides by it).
VIGNETTING_MIN = 0.05


def check_crosstalk(value: object) -> tuple[tuple[float, ...], ...]:
    """The 3 x 3 cross-talk matrix as nested tuples; ValueError naming ``crosstalk`` otherwise.

    Entries in ``[0, 1]``, condition number at most :data:`CROSSTALK_MAX_COND` (invertible).

    >>> check_crosstalk([[1, 0.1, 0], [0.05, 1, 0.02], [0, 0.1, 0.9]])[2]
    (0.0, 0.1, 0.9)
    """
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"crosstalk must be a 3 x 3 matrix of numbers; got {str(value)[:40]}") from None
    if m.shape != (3, 3):
        raise ValueError(
            f"crosstalk must be a 3 x 3 matrix (rows camera channel, columns display region); got {m.shape}"
        )
    lo, hi = IMPERFECTION_RANGES["crosstalk"]
    if not np.all((m >= lo) & (m <= hi)):
        raise ValueError(f"crosstalk entries must be in [{lo:g}, {hi:g}]; got {m.tolist()}")
    cond = np.linalg.cond(m)
    if not cond <= CROSSTALK_MAX_COND:
        raise ValueError(
            f"crosstalk is singular or ill-conditioned (condition number {cond:.3g} > {CROSSTALK_MAX_COND:g}): "
            "the colour channels cannot be unmixed"
        )
    return tuple(tuple(float(v) for v in row) for row in m)


def check_vignetting_poly(poly: tuple[float, float, float]) -> None:
    """Refuse a polynomial ``1 + k1 rho^2 + k2 rho^4 + k3 rho^6`` below :data:`VIGNETTING_MIN` on ``[0, 1]``."""
    rho2 = np.linspace(0.0, 1.0, 1001)
    low = float(np.min(1.0 + rho2 * (poly[0] + rho2 * (poly[1] + rho2 * poly[2]))))
    if low < VIGNETTING_MIN:
        raise ValueError(
            f"vignetting_poly {tuple(poly)} falls to {low:.3g} inside the frame; it must stay >= {VIGNETTING_MIN:g}"
        )


def vignetting_map(
    shape: tuple[int, int], focal_px: float, poly: tuple[float, float, float], *, grid: str = "full"
) -> NDArray[np.float64]:
    """The falloff ``V`` at the pixel centres of a raw frame ``(H, W)`` (module docs).

    Args:
        shape: ``(H, W)`` of the raw frame; the optical axis is at its centre ``(W/2, H/2)``.
        focal_px: focal length in pixels (``inf``: no cos^4 term).
        poly: ``(k1, k2, k3)`` in the normalised radius.
        grid: ``"full"`` (every raw pixel) or ``"half"`` (centres of the 2x2 blocks).

    Returns:
        ``(H, W)`` or ``(H/2, W/2)`` float64 in ``(0, ...]``; 1 at the centre.

    >>> v = vignetting_map((4, 4), 2.0, (0.0, 0.0, 0.0))  # corner pixel: d^2 = 4.5, cos^2 = 4 / 8.5
    >>> round(float(v[0, 0]), 4), round((4 / 8.5) ** 2, 4)
    (0.2215, 0.2215)
    """
    h, w = shape
    step, first = (2.0, 1.0) if grid == "half" else (1.0, 0.5)
    y = np.arange(first, h, step) - h / 2
    x = np.arange(first, w, step) - w / 2
    d2 = y[:, None] ** 2 + x[None, :] ** 2
    rho2 = d2 / ((h / 2) ** 2 + (w / 2) ** 2)
    v = 1.0 + rho2 * (poly[0] + rho2 * (poly[1] + rho2 * poly[2]))
    if math.isfinite(focal_px):
        cos2 = focal_px**2 / (focal_px**2 + d2)
        v = v * cos2 * cos2
    return v


def apply_rig_imperfections(stokes_rgb: ArrayLike, model) -> NDArray:
    """Cross-talk, ambient light and vignetting applied to per-region Stokes images (module docs).

    Args:
        stokes_rgb: ``(H, W, 3, 4)`` Stokes images, colour axis = display colour region.
        model: a :class:`pbrdf.sensor.camera.CameraModel` (its ``crosstalk``, ``ambient``,
            ``vignetting_focal_px`` and ``vignetting_poly``).

    Returns:
        ``(H, W, 3, 4)`` per camera channel, the input itself where every term is nominal.
    """
    s = np.asarray(stokes_rgb)
    if model.crosstalk != IDENTITY3:
        s = np.einsum("cr,...rk->...ck", np.asarray(model.crosstalk, dtype=s.dtype), s)
    if any(model.ambient):
        unpolarized = np.zeros((3, 4), dtype=s.dtype)
        unpolarized[:, 0] = model.ambient
        s = s + unpolarized
    if math.isfinite(model.vignetting_focal_px) or any(model.vignetting_poly):
        v = vignetting_map(s.shape[:2], model.vignetting_focal_px, model.vignetting_poly)
        s = s * v.astype(s.dtype)[:, :, None, None]
    return s
