"""Fresnel equations for dielectrics and conductors, as amplitudes and as Mueller matrices.

Convention:
    The relative index of refraction is complex ``eta = n - i k`` (absorbing media have a
    negative imaginary part), as in Mitsuba 3. An ``eta`` given as ``n + i k`` is conjugated, so
    tables with either sign work. Amplitudes follow the Verdet sign convention used by Mitsuba's
    ``fresnel_polarized``; at normal incidence ``r_p = -r_s``.

    Mueller matrices are expressed in the s/p frame: the Stokes x-axis is perpendicular to the
    plane of incidence (s-polarization is ``s1 > 0``). With that frame a mirror at normal
    incidence is ``R0 * diag(1, 1, -1, -1)``, and gold (eta = 0.27 - 2.78i, 60 degrees) turns
    +45 degree linear light into light with ``s3 > 0`` (right circular).

    ``cos_theta_i < 0`` means the ray arrives from inside (below the normal); ``eta`` is then
    inverted, exactly like Mitsuba.

Range:
    ``eta`` must be finite with ``Re(eta) > 0`` and ``|eta|`` in [:data:`ETA_MIN`, :data:`ETA_MAX`]
    = [1e-6, 1e6] (every real material is far inside; beyond it ``eta**2`` under- or overflows
    and the amplitudes turn into 0/0); ``cos_theta_i`` must be finite and is clipped to [-1, 1].
    Anything else raises ValueError. Inside the range every output is finite and the
    reflectances lie in [0, 1].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_float_array
from pbrdf.polar.mueller import _grid

__all__ = [
    "ETA_MIN",
    "ETA_MAX",
    "MAX_METAL_R0",
    "METAL_N",
    "conductor_extinction",
    "dielectric_transmittance",
    "fresnel_amplitudes",
    "fresnel_reflectance",
    "reflection_mueller",
    "transmission_mueller",
]


#: Smallest accepted modulus of the relative IOR.
ETA_MIN = 1e-6
#: Largest accepted modulus of the relative IOR.
ETA_MAX = 1e6
#: Real index of a metal known only by its normal-incidence reflectance (a base colour, a glTF
#: metal): with ``n = 1`` every ``R0`` in ``[0, 1)`` is reached by a real extinction,
#: ``R0 = k^2 / (4 + k^2)``.
METAL_N = 1.0
#: Largest normal-incidence reflectance given to such a metal (``k`` grows without bound toward 1).
MAX_METAL_R0 = 0.999


def conductor_extinction(r0: ArrayLike, n: ArrayLike = METAL_N) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Extinction ``k`` of a metal with real index ``n`` whose normal-incidence reflectance is ``r0``.

    From ``R0 = ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2)``: ``k^2 = (R0 (n + 1)^2 - (n - 1)^2) / (1 - R0)``.
    ``r0`` is clipped to what ``n`` reaches, ``[((n - 1) / (n + 1))^2, MAX_METAL_R0]``.

    Args:
        r0: normal-incidence reflectance (e.g. a base colour per channel), any shape.
        n: the real part of the index, broadcast against ``r0``.

    Returns:
        ``(k, r0_reached)``, broadcast shapes.

    Example:
        >>> k, r = conductor_extinction(0.5)
        >>> float(k), float(r)  # R0 = k^2 / (4 + k^2) at n = 1
        (2.0, 0.5)
    """
    n = np.asarray(n, dtype=np.float64)
    r0 = np.asarray(r0, dtype=np.float64)
    if not (np.isfinite(r0).all() and np.isfinite(n).all() and (n > 0).all()):
        raise ValueError("conductor_extinction needs a finite r0 and a finite n > 0")
    with np.errstate(over="ignore", invalid="ignore"):
        lo = ((n - 1) / (n + 1)) ** 2
        r = np.clip(r0, lo, MAX_METAL_R0)
        k2 = (r * (n + 1) ** 2 - (n - 1) ** 2) / (1 - r)
    if not np.isfinite(k2).all():
        raise ValueError("conductor_extinction: n is too large for a finite extinction")
    return np.sqrt(np.maximum(k2, 0.0)), r


def _eta(eta: ArrayLike) -> NDArray[np.complexfloating]:
    e = np.asarray(eta, dtype=np.complex128)
    if not np.all(np.isfinite(e)) or np.any(~((np.abs(e) >= ETA_MIN) & (np.abs(e) <= ETA_MAX))):
        raise ValueError(f"eta must be finite with |eta| in [{ETA_MIN:g}, {ETA_MAX:g}]; got {_extremes(np.abs(e))}")
    if np.any(e.real <= 0):
        raise ValueError("eta must have a positive real part (eta = n - ik with n > 0)")
    return np.where(e.imag > 0, e.conj(), e)


def _extremes(a: NDArray) -> str:
    if a.size == 1:
        return f"|eta| = {float(a.flat[0]):g}"
    return f"|eta| in [{float(np.min(a)):g}, {float(np.max(a)):g}]"


def _cos(cos_theta_i: ArrayLike) -> NDArray[np.float64]:
    c = as_float_array(cos_theta_i).astype(np.float64)
    if not np.all(np.isfinite(c)):
        raise ValueError("cos_theta_i must be finite")
    return np.clip(c, -1.0, 1.0)


def fresnel_amplitudes(cos_theta_i: ArrayLike, eta: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Complex s and p reflection amplitudes and the transmitted cosine.

    .. math::
        r_s = \\frac{\\cos\\theta_i - \\eta\\cos\\theta_t}{\\cos\\theta_i + \\eta\\cos\\theta_t},\\quad
        r_p = \\frac{\\eta\\cos\\theta_i - \\cos\\theta_t}{\\eta\\cos\\theta_i + \\cos\\theta_t},\\quad
        \\cos\\theta_t = \\sqrt{1 - \\sin^2\\theta_i / \\eta^2}

    Args:
        cos_theta_i: cosine of the incidence angle, finite, clipped to [-1, 1], shape ``(...)``.
        eta: relative complex IOR (transmitted over incident side), broadcastable; finite,
            ``Re(eta) > 0``, ``|eta|`` in [1e-6, 1e6].

    Returns:
        ``(r_s, r_p, cos_theta_t)``, complex128 arrays of the broadcast shape, finite, with
        ``|r_s|, |r_p| <= 1``. ``cos_theta_t`` is the complex square root with ``Im <= 0``
        (negative imaginary under total internal reflection). For conductors only
        ``cos_theta_i >= 0`` is physically meaningful.

    Raises:
        ValueError: if ``cos_theta_i`` is not finite or ``eta`` is outside its range.
    """
    cos_i = _cos(cos_theta_i)
    e = _eta(eta)
    e = np.where(cos_i >= 0, e, 1.0 / e)
    c = np.abs(cos_i)
    sin2 = np.maximum(1.0 - c * c, 0.0)
    cos_t = np.sqrt(1.0 - sin2 / (e * e))
    # eta = n - ik implies Im(cos_t) <= 0 (decaying wave); pick that branch under total internal
    # reflection too, which makes the TIR phase match Mitsuba's.
    cos_t = np.where(cos_t.imag > 0, cos_t.conj(), cos_t)
    # An index-matched interface (eta == 1) reflects nothing, as in Mitsuba; set it exactly instead of
    # evaluating 0/0 at grazing incidence (and R = 1 from the round-off in 1 - sin2 for cos_i < 1e-8).
    matched = e == 1
    cos_t = np.where(matched, c, cos_t)
    r_s = (c - e * cos_t) / np.where(matched, 1.0, c + e * cos_t)
    r_p = (e * c - cos_t) / np.where(matched, 1.0, e * c + cos_t)
    return r_s, r_p, cos_t


def fresnel_reflectance(cos_theta_i: ArrayLike, eta: ArrayLike) -> NDArray:
    """Unpolarized Fresnel reflectance ``(|r_s|^2 + |r_p|^2) / 2``.

    Args:
        cos_theta_i: cosine of the incidence angle, finite, clipped to [-1, 1], shape ``(...)``.
        eta: relative complex IOR, broadcastable; finite, ``Re(eta) > 0``, ``|eta|`` in [1e-6, 1e6].

    Returns:
        float64, the broadcast shape, in [0, 1] (clamped against rounding): 1 at grazing
        incidence, ``|(eta - 1) / (eta + 1)|^2`` at normal incidence.

    Raises:
        ValueError: if ``cos_theta_i`` is not finite or ``eta`` is outside its range.

    Example:
        >>> round(float(fresnel_reflectance(1.0, 1.5)), 6)
        0.04
    """
    r_s, r_p, _ = fresnel_amplitudes(cos_theta_i, eta)
    return np.clip(0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2), 0.0, 1.0)


def dielectric_transmittance(cos_theta_i, eta: float):
    """Unpolarized Fresnel transmittance ``1 - (r_s^2 + r_p^2) / 2`` from air into a real index, array or tensor.

    The same physics as ``1 - fresnel_reflectance(cos, eta)`` for a real ``eta >= 1``, written with
    operators only so that a torch tensor stays a differentiable tensor (the re-renderer's diffuse
    lobe of a coated plastic) and a numpy array stays an array. A numpy input must be finite; a
    tensor is not checked (a hot path inside training, whose NaN guards are the network's own).

    Args:
        cos_theta_i: cosine of the incidence angle, shape ``(...)``, a numpy array or torch tensor;
            clipped to [0, 1] (light from below is treated as grazing).
        eta: real relative index of refraction, ``>= 1``.

    Returns:
        the transmittance, the input's type and shape, in [0, 1]: ``4 eta / (1 + eta)^2`` at normal
        incidence, 0 at grazing.

    Raises:
        ValueError: if ``eta`` is not a real number in [1, 1e6], or a numpy ``cos_theta_i`` is not finite.

    Example:
        >>> round(float(dielectric_transmittance(np.array(1.0), 1.5)), 6)
        0.96
    """
    if not (isinstance(eta, (int, float)) and 1.0 <= eta <= ETA_MAX):
        raise ValueError(f"eta must be a real index of refraction in [1, {ETA_MAX:g}], got {eta!r}")
    if isinstance(cos_theta_i, np.ndarray | float | int) and not np.isfinite(cos_theta_i).all():
        raise ValueError(f"cos_theta_i must be finite, got {_extremes(np.asarray(cos_theta_i))}")
    c = np.asarray(cos_theta_i).clip(0.0, 1.0) if isinstance(cos_theta_i, float | int) else cos_theta_i.clip(0.0, 1.0)
    # clip before the root: a tiny positive floor keeps the torch gradient finite at grazing
    c_t = (1.0 - (1.0 - c * c) / (eta * eta)).clip(1e-12, None) ** 0.5
    r_s = (c - eta * c_t) / (c + eta * c_t)
    r_p = (eta * c - c_t) / (eta * c + c_t)
    return 1.0 - 0.5 * (r_s * r_s + r_p * r_p)


def reflection_mueller(cos_theta_i: ArrayLike, eta: ArrayLike) -> NDArray:
    """Mueller matrix of specular reflection in the s/p frame; shape ``(..., 4, 4)``.

    .. math::
        \\tfrac12 [[R_s+R_p, R_s-R_p, 0, 0], [R_s-R_p, R_s+R_p, 0, 0],
        [0, 0, 2\\Re(r_s r_p^*), 2\\Im(r_s r_p^*)], [0, 0, -2\\Im(r_s r_p^*), 2\\Re(r_s r_p^*)]]

    Equal to Mitsuba 3's ``mueller::specular_reflection`` (tested). Arguments and their ranges
    as in :func:`fresnel_amplitudes` (ValueError outside them); the matrix is finite there.
    """
    r_s, r_p, _ = fresnel_amplitudes(cos_theta_i, eta)
    rs2, rp2 = np.abs(r_s) ** 2, np.abs(r_p) ** 2
    x = r_s * r_p.conj()
    a, b = 0.5 * (rs2 + rp2), 0.5 * (rs2 - rp2)
    c, s = x.real, x.imag
    z = np.zeros_like(a)
    return _grid([[a, b, z, z], [b, a, z, z], [z, z, c, s], [z, z, -s, c]])


def transmission_mueller(cos_theta_i: ArrayLike, eta: ArrayLike) -> NDArray:
    """Mueller matrix of specular transmission through a dielectric interface; ``(..., 4, 4)``.

    Power (flux) transmittance, including the beam-area factor ``f = eta cos_t / cos_i`` so that
    reflectance plus transmittance is 1 (tested); radiance would carry a further ``1 / eta^2``, not
    included here. With ``t_s = 1 + r_s`` and ``t_p = (1 + r_p) / eta``:

    .. math::
        \\tfrac{f}{2}[[T_s+T_p, T_s-T_p, 0, 0], [T_s-T_p, T_s+T_p, 0, 0],
        [0,0,2\\sqrt{T_sT_p},0], [0,0,0,2\\sqrt{T_sT_p}]]

    For real ``eta`` only (dielectrics); zero under total internal reflection. Equal to Mitsuba
    3's ``mueller::specular_transmission`` (tested). Ranges as in :func:`fresnel_amplitudes`
    (ValueError outside them); the matrix is finite there.
    """
    e_in = np.asarray(eta, dtype=np.complex128)
    if np.any(np.abs(e_in.imag) > 0):
        raise ValueError("transmission_mueller needs a real eta (dielectric)")
    cos_i = _cos(cos_theta_i)
    _, _, cos_t = fresnel_amplitudes(cos_i, e_in)
    e = np.where(cos_i >= 0, e_in.real, 1.0 / e_in.real)
    tir = np.abs(cos_t.imag) > 0
    ct = np.where(tir, 0.0, cos_t.real)
    ci = np.abs(cos_i)
    # f |t|^2 with f = eta cos_t / cos_i, |t_s|^2 = |2 cos_i / (cos_i + eta cos_t)|^2 and
    # |t_p|^2 = |2 cos_i / (eta cos_i + cos_t)|^2, multiplied out so that nothing is divided by cos_i:
    # f times the round-off in |1 + r|^2 gave T >> 1 for cos_i < 1e-29 and NaN for subnormal cos_i.
    num = 4.0 * e * ct * ci  # 0 at grazing incidence and under TIR
    t_s = num / np.where(num > 0, np.abs(ci + e * ct) ** 2, 1.0)
    t_p = num / np.where(num > 0, np.abs(e * ci + ct) ** 2, 1.0)
    matched = e == 1  # index-matched: everything passes, grazing incidence included
    t_s, t_p = np.where(matched, 1.0, t_s), np.where(matched, 1.0, t_p)
    a, b = 0.5 * (t_s + t_p), 0.5 * (t_s - t_p)
    c = np.sqrt(t_s * t_p)
    z = np.zeros_like(a)
    return _grid([[a, b, z, z], [b, a, z, z], [z, z, c, z], [z, z, z, c]])
