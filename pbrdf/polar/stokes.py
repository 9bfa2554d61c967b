"""Stokes vectors: construction, derived quantities and physicality.

Convention:
    Stokes vectors are arrays of shape ``(..., 4)`` holding ``(s0, s1, s2, s3)``. The reference
    x-axis is the camera image's horizontal axis: ``s1 > 0`` is horizontal, ``s1 < 0`` vertical,
    ``s2 > 0`` is +45 degrees (counter-clockwise from x as seen by the camera), and ``s3 > 0`` is
    right-circular in Mitsuba 3's and polanalyser's convention. The display's light is
    ``intensity * [1, -1, 0, 0]`` (vertical linear polarization).

Range: every function accepts any finite float32/float64 input and returns finite values. The
norms ``|(s1, s2, s3)|`` and ``|(s1, s2)|`` are computed with ``hypot``, which scales instead of
squaring, so a float32 vector of magnitude 1e30 (or 1e-30) gives the same ratios as one of
magnitude 1. All ratios over ``s0`` are zero-safe: they return 0 where ``s0 <= 0`` instead of
NaN. They lie in [0, 1] for physical vectors (up to rounding); an unphysical one can give more
than 1, and a ratio beyond the dtype's largest value (e.g. ``1e300 / 1e-300``) is clamped to it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_float_array, check_last_dims, double_angle

__all__ = [
    "stokes",
    "intensity",
    "dop",
    "dolp",
    "docp",
    "aolp",
    "ellipticity_angle",
    "is_physical_stokes",
]


def stokes(s0: ArrayLike, dop: ArrayLike, aolp: ArrayLike, ellipticity: ArrayLike) -> NDArray:
    """Build Stokes vectors from intensity, degree of polarization and the ellipse angles.

    .. math::
        s = s_0 [1,\\ p\\cos 2\\chi \\cos 2\\psi,\\ p\\cos 2\\chi \\sin 2\\psi,\\ p \\sin 2\\chi]

    Args:
        s0: intensity, ``>= 0``, shape broadcastable.
        dop: degree of polarization in [0, 1].
        aolp: angle of linear polarization psi in radians (0 = horizontal).
        ellipticity: ellipticity angle chi in radians, in [-pi/4, pi/4] (pi/4 = right circular).

    Returns:
        Stokes vectors, shape ``(..., 4)``.

    Raises:
        ValueError: if ``s0 < 0`` or ``dop`` is outside [0, 1].

    Example:
        Vertical linear polarization (the display's light):

        >>> stokes(1.0, 1.0, np.pi / 2, 0.0).round(12) + 0.0
        array([ 1., -1.,  0.,  0.])
    """
    s0, p, psi, chi = np.broadcast_arrays(*(as_float_array(v) for v in (s0, dop, aolp, ellipticity)))
    if not ((s0 >= 0).all() and np.isfinite(s0).all()):
        raise ValueError("s0 must be finite and >= 0")
    if not ((p >= 0) & (p <= 1)).all():
        raise ValueError("dop must be in [0, 1]")
    psi2, chi2 = double_angle(psi, "aolp"), double_angle(chi, "ellipticity")
    c2chi = np.cos(chi2)
    return np.stack(
        [s0, s0 * p * c2chi * np.cos(psi2), s0 * p * c2chi * np.sin(psi2), s0 * p * np.sin(chi2)],
        axis=-1,
    )


def _checked(s: ArrayLike) -> NDArray:
    s = as_float_array(s)
    check_last_dims(s, (4,), "stokes")
    return s


def _ratio(num: NDArray, den: NDArray) -> NDArray:
    """``num / den`` where ``den > 0`` and 0 elsewhere.

    An overflowing quotient is clamped to the dtype's largest value (no warnings, no Inf).
    """
    num, den = np.broadcast_arrays(num, den)
    out = np.zeros(num.shape, dtype=np.result_type(num, den))
    with np.errstate(over="ignore"):
        np.divide(num, den, out=out, where=den > 0)
    return np.minimum(out, np.finfo(out.dtype).max, out=out)


def _polarized_norm(s: NDArray) -> NDArray:
    """``|(s1, s2, s3)|`` without squaring in the input's dtype (no overflow or underflow)."""
    return np.hypot(np.hypot(s[..., 1], s[..., 2]), s[..., 3])


def intensity(s: ArrayLike) -> NDArray:
    """Total intensity ``s0``; shape ``(...)``. NaN or Inf in ``s0`` is refused (ValueError)."""
    s0 = _checked(s)[..., 0]
    if not np.isfinite(s0).all():
        raise ValueError("stokes s0 must be finite; got NaN or Inf")
    return s0


def dop(s: ArrayLike) -> NDArray:
    """Degree of polarization ``|(s1,s2,s3)| / s0``.

    Args:
        s: Stokes vectors, shape ``(..., 4)``, any finite magnitude.

    Returns:
        Shape ``(...)``, the input's float dtype; 0 where ``s0 <= 0``; in [0, 1] for physical
        vectors, finite always (see the module docs).

    Example:
        The display's light at a magnitude whose square overflows float32:

        >>> float(dop(np.array([1e30, -1e30, 0.0, 0.0], dtype=np.float32)))
        1.0
    """
    s = _checked(s)
    return _ratio(_polarized_norm(s), s[..., 0])


def dolp(s: ArrayLike) -> NDArray:
    """Degree of linear polarization ``|(s1,s2)| / s0`` (0 where ``s0 <= 0``); shape ``(...)``.

    Same range as :func:`dop`.
    """
    s = _checked(s)
    return _ratio(np.hypot(s[..., 1], s[..., 2]), s[..., 0])


def docp(s: ArrayLike) -> NDArray:
    """Degree of circular polarization ``|s3| / s0`` (0 where ``s0 <= 0``); shape ``(...)``.

    Same range as :func:`dop`.
    """
    s = _checked(s)
    return _ratio(np.abs(s[..., 3]), s[..., 0])


def aolp(s: ArrayLike) -> NDArray:
    """Angle of linear polarization ``atan2(s2, s1) / 2`` in [0, pi) radians; shape ``(...)``.

    Undefined for ``s1 = s2 = 0``; returns 0 there.
    """
    s = _checked(s)
    # arctan2(+-0, -0) is +-pi, not 0, and np.mod(-tiny, pi) rounds up to pi: pin both back to 0.
    psi = np.mod(0.5 * np.arctan2(s[..., 2], s[..., 1]), np.pi)
    return np.where((psi >= np.pi) | ((s[..., 1] == 0) & (s[..., 2] == 0)), np.zeros_like(psi), psi)


def ellipticity_angle(s: ArrayLike) -> NDArray:
    """Ellipticity angle ``atan2(s3, |(s1,s2)|) / 2`` in [-pi/4, pi/4] radians; shape ``(...)``."""
    s = _checked(s)
    return 0.5 * np.arctan2(s[..., 3], np.hypot(s[..., 1], s[..., 2]))


def is_physical_stokes(s: ArrayLike, *, rtol: float = 1e-6, atol: float = 0.0) -> NDArray[np.bool_]:
    """True where ``s0 >= 0`` and ``s0**2 >= s1**2 + s2**2 + s3**2`` (up to tolerance).

    The tolerance is relative to ``s0``: ``|(s1,s2,s3)| <= s0 * (1 + rtol) + atol``, so float32
    round-off on a fully polarized state is accepted, at any finite magnitude (the norm does not
    square in the input's dtype). NaN entries are never physical.

    Args:
        s: Stokes vectors, shape ``(..., 4)``.
        rtol: relative tolerance on the polarized part.
        atol: absolute tolerance.

    Returns:
        Boolean array of shape ``(...)``.
    """
    s = _checked(s)
    s0 = s[..., 0]
    pol = _polarized_norm(s)
    with np.errstate(invalid="ignore"):
        return (s0 >= -atol) & (pol <= s0 * (1 + rtol) + atol)
