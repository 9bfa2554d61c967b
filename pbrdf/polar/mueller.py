"""Mueller matrices of optical elements and Stokes-frame rotations.

Convention:
    Mueller matrices have shape ``(..., 4, 4)`` and act on column Stokes vectors ``(..., 4)``
    (:mod:`pbrdf.polar.stokes`). Angles are radians, measured from the reference x-axis towards the
    y-axis as seen looking *against* the propagation direction (into the beam), the convention
    of Mitsuba 3 and polanalyser. ``rotator(theta)`` re-expresses a Stokes vector in a frame
    rotated by ``theta``; an element rotated by ``theta`` is ``rotator(-theta) @ M @ rotator(theta)``.
    A quarter-wave plate with its fast axis horizontal maps ``[s0, s1, s2, s3]`` to
    ``[s0, s1, s3, -s2]``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_float_array, check_last_dims, double_angle

__all__ = [
    "apply",
    "rotator",
    "rotate_element",
    "linear_polarizer",
    "linear_diattenuator",
    "retarder",
    "qwp",
    "hwp",
    "depolarizer",
    "diagonal_depolarizer",
    "jones_to_mueller",
    "stokes_basis",
    "rotate_stokes_basis",
    "rotate_mueller_basis",
]


def _finite(out: NDArray, what: str) -> NDArray:
    """``out`` if every entry is finite, else a ValueError naming the arguments ``what`` (one vectorised check).

    Non-finite arguments, or finite ones so large that the result overflows, would otherwise
    return NaN or Inf.
    """
    if not np.isfinite(out).all():
        raise ValueError(f"{what} must be finite and small enough for a finite result (got NaN, Inf or an overflow)")
    return out


def _grid(rows: list[list[ArrayLike]]) -> NDArray:
    """Assemble a ``(..., 4, 4)`` matrix from a visible 4x4 grid of broadcastable entries."""
    flat = np.broadcast_arrays(*(as_float_array(v) for row in rows for v in row))
    return np.stack(flat, axis=-1).reshape(*flat[0].shape, 4, 4)


def apply(mueller: ArrayLike, stokes: ArrayLike) -> NDArray:
    """Apply Mueller matrices ``(..., 4, 4)`` to Stokes vectors ``(..., 4)``; broadcasts."""
    m = as_float_array(mueller)
    s = as_float_array(stokes)
    check_last_dims(m, (4, 4), "mueller")
    check_last_dims(s, (4,), "stokes")
    with np.errstate(over="ignore", invalid="ignore"):
        return _finite(np.einsum("...ij,...j->...i", m, s), "mueller and stokes")


def rotator(theta: ArrayLike) -> NDArray:
    """Stokes frame rotation by ``theta`` radians; shape ``(..., 4, 4)``.

    .. math:: R(\\theta) = [[1,0,0,0],[0,c,s,0],[0,-s,c,0],[0,0,0,1]],\\quad c=\\cos 2\\theta,\\ s=\\sin 2\\theta
    """
    t = as_float_array(theta)
    t2 = double_angle(t)
    c, s = np.cos(t2), np.sin(t2)
    o, z = np.ones_like(t), np.zeros_like(t)
    return _grid([[o, z, z, z], [z, c, s, z], [z, -s, c, z], [z, z, z, o]])


def rotate_element(mueller: ArrayLike, theta: ArrayLike) -> NDArray:
    """Mueller matrix of an element physically rotated by ``theta`` radians: ``R(-t) M R(t)``."""
    m = as_float_array(mueller)
    check_last_dims(m, (4, 4), "mueller")
    t = as_float_array(theta)
    with np.errstate(over="ignore", invalid="ignore"):
        return _finite(rotator(-t) @ m @ rotator(t), "mueller")


def linear_diattenuator(q: ArrayLike, r: ArrayLike, theta: ArrayLike = 0.0) -> NDArray:
    """Linear diattenuator with intensity transmittances ``q`` (along ``theta``) and ``r`` (across).

    .. math:: \\tfrac12 [[q+r, q-r, 0, 0], [q-r, q+r, 0, 0], [0, 0, 2\\sqrt{qr}, 0], [0, 0, 0, 2\\sqrt{qr}]]

    Args:
        q: transmittance for light polarized along the axis, in [0, 1].
        r: transmittance across the axis, in [0, 1].
        theta: axis angle in radians.
    """
    q, r = as_float_array(q), as_float_array(r)
    if not (np.isfinite(q).all() and np.isfinite(r).all() and (q >= 0).all() and (r >= 0).all()):
        raise ValueError("diattenuator transmittances q and r must be finite and >= 0")
    # 0.5 q + 0.5 r is 0.5 (q + r) to the bit (scaling by 2 is exact) without its overflow.
    a, b = 0.5 * q + 0.5 * r, 0.5 * q - 0.5 * r
    with np.errstate(over="ignore"):
        c = np.sqrt(q * r)
    if not np.isfinite(c).all():
        c = np.sqrt(q) * np.sqrt(r)
    z = np.zeros(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    m = _grid([[a, b, z, z], [b, a, z, z], [z, z, c, z], [z, z, z, c]])
    return rotate_element(m, theta)


def linear_polarizer(
    theta: ArrayLike = 0.0, *, extinction_ratio: ArrayLike = np.inf, transmittance: ArrayLike = 1.0
) -> NDArray:
    """Linear polarizer with its transmission axis at ``theta`` radians.

    Args:
        theta: transmission axis, radians from the x-axis.
        extinction_ratio: ratio of the transmittances along and across the axis (``inf`` = ideal).
            A camera's micro-polarizer with ratio ER has diattenuation ``(ER - 1) / (ER + 1)``.
        transmittance: transmittance along the axis.

    Example:
        An ideal horizontal polarizer passes half of unpolarized light, horizontally polarized:

        >>> apply(linear_polarizer(0.0), [1.0, 0.0, 0.0, 0.0])
        array([0.5, 0.5, 0. , 0. ])
    """
    er = as_float_array(extinction_ratio)
    if not (er >= 1).all():
        raise ValueError("extinction_ratio must be >= 1 (inf: ideal); got a smaller value or NaN")
    q = as_float_array(transmittance)
    if not np.isfinite(q).all():
        raise ValueError("transmittance must be finite and >= 0; got NaN or Inf")
    return linear_diattenuator(q, q / er, theta)


def retarder(delta: ArrayLike, theta: ArrayLike = 0.0) -> NDArray:
    """Linear retarder with retardance ``delta`` radians and fast axis at ``theta`` radians.

    .. math:: [[1,0,0,0],[0,1,0,0],[0,0,\\cos\\delta,\\sin\\delta],[0,0,-\\sin\\delta,\\cos\\delta]]
        \\text{ for } \\theta = 0

    Example:
        Quarter-wave plate, fast axis horizontal: +45 degree linear becomes left circular (s3 = -1)
        and right circular becomes +45 degree linear (Goldstein, Polarized Light, 3rd ed., 6.46):

        >>> apply(retarder(np.pi / 2), [[1, 0, 1, 0], [1, 0, 0, 1]]).round(12) + 0.0
        array([[ 1.,  0.,  0., -1.],
               [ 1.,  0.,  1.,  0.]])
    """
    d = as_float_array(delta)
    if not np.isfinite(d).all():
        raise ValueError("delta must be finite (radians); got NaN or Inf")
    c, s = np.cos(d), np.sin(d)
    o, z = np.ones_like(d), np.zeros_like(d)
    m = _grid([[o, z, z, z], [z, o, z, z], [z, z, c, s], [z, z, -s, c]])
    return rotate_element(m, theta)


def qwp(theta: ArrayLike = 0.0) -> NDArray:
    """Quarter-wave plate (retardance pi/2) with its fast axis at ``theta`` radians."""
    return retarder(np.pi / 2, theta)


def hwp(theta: ArrayLike = 0.0) -> NDArray:
    """Half-wave plate (retardance pi) with its fast axis at ``theta`` radians."""
    return retarder(np.pi, theta)


def depolarizer(a: ArrayLike = 0.0) -> NDArray:
    """Isotropic partial depolarizer ``diag(1, a, a, a)``; ``a = 0`` depolarizes fully.

    Args:
        a: preserved fraction of polarization in [-1, 1], shape ``(...)``.

    Returns:
        ``(..., 4, 4)``.
    """
    a = as_float_array(a)
    return diagonal_depolarizer(a, a, a)


def diagonal_depolarizer(a1: ArrayLike, a2: ArrayLike, a3: ArrayLike) -> NDArray:
    """Diagonal depolarizer ``diag(1, a1, a2, a3)`` with per-component factors in [-1, 1]."""
    a1, a2, a3 = np.broadcast_arrays(*(as_float_array(v) for v in (a1, a2, a3)))
    if not all((np.abs(v) <= 1).all() for v in (a1, a2, a3)):
        raise ValueError("depolarizer factors must be in [-1, 1] (not NaN)")
    o, z = np.ones_like(a1), np.zeros_like(a1)
    return _grid([[o, z, z, z], [z, a1, z, z], [z, z, a2, z], [z, z, z, a3]])


# Stokes map S = A (E (x) E*), E = (Ex, Ey): s3 = -2 Im(Ex Ey*) so that E = (1, i)/sqrt(2) is right circular.
_A = np.array([[1, 0, 0, 1], [1, 0, 0, -1], [0, 1, 1, 0], [0, 1j, -1j, 0]], dtype=np.complex128)
_A_INV = np.linalg.inv(_A)


def jones_to_mueller(jones: ArrayLike) -> NDArray:
    """Mueller matrix ``A (J (x) J*) A^-1`` of a Jones matrix; ``(..., 2, 2)`` complex -> ``(..., 4, 4)`` real.

    Convention: the Jones vector ``(1, i) / sqrt(2)`` is right circular (``s3 = +1``), matching
    :func:`retarder` (``jones_to_mueller(diag(1, -1j)) == qwp(0)``).
    """
    j = np.asarray(jones, dtype=np.complex128)
    check_last_dims(j, (2, 2), "jones")
    with np.errstate(over="ignore", invalid="ignore"):
        kron = np.einsum("...ab,...cd->...acbd", j, j.conj()).reshape(*j.shape[:-2], 4, 4)
        return _finite(np.real(_A @ kron @ _A_INV), "jones (entries up to about 1e150)")


def _normalize(v: NDArray) -> NDArray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def stokes_basis(w: ArrayLike) -> NDArray:
    """Mitsuba 3's implicit Stokes x-axis for a ray travelling along unit ``w``; ``(..., 3)``.

    This is the first vector of the Duff et al. (2017) orthonormal basis, as in Mitsuba's
    ``mueller::stokes_basis`` (``coordinate_system(w).first``).
    """
    w = as_float_array(w)
    check_last_dims(w, (3,), "w")
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    sign = np.copysign(1.0, z)  # z = -0.0 counts as negative, as in Mitsuba (the basis flips to -x otherwise)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        a = -1.0 / (sign + z)
        b = x * y * a
        return _finite(np.stack([1 + sign * x * x * a, sign * b, -sign * x], axis=-1), "w (unit vectors)")


def rotate_stokes_basis(forward: ArrayLike, basis_current: ArrayLike, basis_target: ArrayLike) -> NDArray:
    """Rotator taking Stokes vectors from x-axis ``basis_current`` to ``basis_target``; ``(..., 4, 4)``.

    Both bases must be perpendicular to the propagation direction ``forward`` (all ``(..., 3)``).
    Same sign rule as Mitsuba's ``rotate_stokes_basis``.
    """
    f, cur, tgt = (as_float_array(v) for v in (forward, basis_current, basis_target))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        cur, tgt = _normalize(cur), _normalize(tgt)
        cross = np.cross(cur, tgt)
        # atan2 of (|sin|, cos) stays accurate near 0 and pi, where arccos loses half the digits.
        theta = np.arctan2(np.linalg.norm(cross, axis=-1), np.sum(cur * tgt, axis=-1))
        flip = np.sum(f * cross, axis=-1) < 0
    _finite(theta, "basis_current and basis_target (nonzero, finite vectors)")
    return rotator(np.where(flip, -theta, theta))


def rotate_mueller_basis(
    mueller: ArrayLike,
    in_forward: ArrayLike,
    in_basis_current: ArrayLike,
    in_basis_target: ArrayLike,
    out_forward: ArrayLike,
    out_basis_current: ArrayLike,
    out_basis_target: ArrayLike,
) -> NDArray:
    """Re-express a Mueller matrix in new input and output Stokes frames: ``R_out M R_in^T``."""
    m = as_float_array(mueller)
    check_last_dims(m, (4, 4), "mueller")
    r_in = rotate_stokes_basis(in_forward, in_basis_current, in_basis_target)
    r_out = rotate_stokes_basis(out_forward, out_basis_current, out_basis_target)
    with np.errstate(over="ignore", invalid="ignore"):
        return _finite(r_out @ m @ np.swapaxes(r_in, -1, -2), "mueller")
