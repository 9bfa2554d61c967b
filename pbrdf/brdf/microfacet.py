"""Analytic polarimetric microfacet pBRDFs: a Baek-2018 dielectric and a rough conductor.

The two models are numpy (float64) ports of the maths behind Mitsuba 3's ``pplastic`` and
``roughconductor`` plugins (GGX distribution), written against this project's Fresnel
(:mod:`pbrdf.polar.fresnel`) and Stokes-frame (:mod:`pbrdf.polar.mueller`) code and tested against the
plugins themselves.

Convention:
    Directions are unit vectors ``(..., 3)`` in the local shading frame (``z`` = surface normal),
    named as in Mitsuba's ``bsdf.eval(ctx, si, wo)`` in radiance mode:

    - ``wi`` points from the surface *towards the camera* (Mitsuba's ``si.wi``);
    - ``wo`` points from the surface *towards the light* (Mitsuba's ``wo``).

    The returned Mueller matrix ``M`` maps the Stokes vector of light arriving along ``-wo``,
    expressed with the x-axis ``mueller.stokes_basis(-wo)``, to the Stokes vector of light leaving
    along ``wi``, expressed with the x-axis ``mueller.stokes_basis(wi)``: the implicit frames of
    Mitsuba's polarized variants. Each frame's y-axis is ``w x x`` for the propagation direction
    ``w`` (right-handed), so although ``stokes_basis(-w) == stokes_basis(w)`` for ``w_z != 0``,
    the frame of the arriving light (``w = -wo``) has the opposite y-axis (and s2, s3 signs) to
    one that took ``+wo`` as the propagation direction. ``tests/pbrdf/brdf/test_microfacet.py``
    checks this against Mitsuba itself: all 16 entries agree with ``pplastic`` and
    ``roughconductor``, s-polarized light (field along ``wo x wi``) comes back s-polarized and p
    comes back p, and mirrored y-axes or swapped camera/light roles disagree.

    ``M`` includes the foreshortening factor of the light, ``cos(theta_o) = wo[..., 2]``, exactly
    as Mitsuba's ``eval`` returns it: the reflected Stokes radiance is the integral of
    ``M @ S_light`` over the light directions. Pairs with a direction at or below the horizon
    (``z <= 0``) give zero matrices.

    Example: gold (``eta = 0.18 - 3.2i``, ``alpha = 0.1``) lit and seen at 45 degrees in the
    xz-plane, ``wi = (0.7071, 0, 0.7071)``, ``wo = (-0.7071, 0, 0.7071)``. Both Stokes bases then lie
    in the plane of incidence (``stokes_basis(wi) = (0.7071, 0, -0.7071)``), so s-polarized light is
    ``s1 = -1``: ``m00 = 10.483``, ``m01 = m10 = -0.231`` (s reflects more than p),
    ``m22 = m33 = -9.553`` (mirror signs) and ``m23 = -m32 = 4.311`` (retardance: +45 degree
    linear light comes back with ``s3 < 0``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_float_array, check_last_dims
from pbrdf.brdf import disney
from pbrdf.polar.fresnel import reflection_mueller, transmission_mueller
from pbrdf.polar.mueller import rotate_mueller_basis, rotate_stokes_basis, stokes_basis

__all__ = ["ALPHA_MIN", "ALPHA_MAX", "ggx_d", "smith_g1", "dielectric_pbrdf", "conductor_pbrdf"]

#: Smallest GGX roughness used; smaller ``alpha`` is clamped to it, as Mitsuba does, so that the
#: distribution stays a finite (if very peaked) function: ``D(n) = 1 / (pi alpha^2) = 3.2e7``.
ALPHA_MIN = 1e-4
#: Largest GGX roughness used; larger ``alpha`` (``inf`` included) is clamped to it, where ``D``
#: and ``G1`` are already within 1e-8 of their ``alpha -> inf`` limit 0 (``G1(1) = 1`` stays).
#: The ceiling of :data:`pbrdf.brdf.disney.ALPHA_RANGE`.
ALPHA_MAX = disney.ALPHA_RANGE[1]


def _alpha(alpha: ArrayLike) -> NDArray:
    a = as_float_array(alpha).astype(np.float64)
    if np.any(~(a >= 0)):
        raise ValueError("alpha must be >= 0 (GGX roughness, alpha = roughness**2)")
    return np.clip(a, ALPHA_MIN, ALPHA_MAX)


def ggx_d(cos_theta_h: ArrayLike, alpha: ArrayLike) -> NDArray:
    """Isotropic GGX (Trowbridge-Reitz) microfacet distribution ``D(h)``, in 1/sr; shape ``(...)``.

    .. math::
        D = \\frac{\\alpha^2}{\\pi\\,(\\sin^2\\theta_h + \\alpha^2\\cos^2\\theta_h)^2}
        \\quad (\\cos\\theta_h > 0), \\qquad D = 0 \\text{ otherwise}

    Normalised so that ``int D(h) cos(theta_h) dh = 1`` over the hemisphere. The form above has
    no division by ``cos_theta_h``, so it is finite at grazing half vectors.

    Args:
        cos_theta_h: cosine between the half vector and the normal, shape ``(...)``.
        alpha: GGX roughness (``alpha = roughness**2`` in this project), broadcastable, ``>= 0``;
            clamped to [:data:`ALPHA_MIN`, :data:`ALPHA_MAX`] = [1e-4, 1e4].

    Returns:
        ``D`` in 1/sr, float64, the broadcast shape.

    Example:
        At the normal ``D = 1 / (pi alpha^2)``:

        >>> float(ggx_d(1.0, 0.5)) * np.pi * 0.25
        1.0

    References:
        B. Walter, S. R. Marschner, H. Li, K. E. Torrance, "Microfacet models for refraction
        through rough surfaces", EGSR 2007, eq. 33.
    """
    c = np.clip(as_float_array(cos_theta_h).astype(np.float64), -1.0, 1.0)
    # The formula has one home, shared with the Disney model (pbrdf.brdf.disney); the clamp is this
    # module's (Mitsuba's microfacet plugins clamp alpha to 1e-4).
    return np.where(c > 0, disney.ggx_ndf(c, _alpha(alpha)), 0.0)


def smith_g1(cos_theta_v: ArrayLike, alpha: ArrayLike) -> NDArray:
    """Smith masking term of the GGX distribution for a direction ``v``; shape ``(...)``, in [0, 1].

    .. math::
        G_1 = \\frac{2}{1 + \\sqrt{1 + \\alpha^2\\tan^2\\theta_v}}
            = \\frac{2\\cos\\theta_v}{\\cos\\theta_v + \\sqrt{\\cos^2\\theta_v + \\alpha^2\\sin^2\\theta_v}}

    The second form is used: it tends to 0 at grazing ``v`` instead of evaluating ``tan`` there.
    Directions below the horizon (``cos_theta_v <= 0``) give 0. The microfacet-side condition
    ``(v . h) cos_theta_v > 0`` always holds for the reflection half vector of two directions above
    the horizon, so it is not an argument here.

    Args:
        cos_theta_v: cosine between ``v`` and the normal, shape ``(...)``.
        alpha: GGX roughness, broadcastable, ``>= 0``; clamped to [:data:`ALPHA_MIN`,
            :data:`ALPHA_MAX`] = [1e-4, 1e4].

    Returns:
        ``G1`` in [0, 1], float64, the broadcast shape; exactly 1 at normal incidence and 0 at
        grazing, for every ``alpha``.

    Raises:
        ValueError: if ``alpha`` is negative or NaN.

    Example:
        >>> float(smith_g1(1.0, 0.3)), float(smith_g1(0.0, 0.3))
        (1.0, 0.0)

    References:
        Walter et al. 2007 (see :func:`ggx_d`), eq. 34.
    """
    c = np.clip(as_float_array(cos_theta_v).astype(np.float64), -1.0, 1.0)
    return np.where(c > 0, disney.smith_g1_ggx(np.maximum(c, 0.0), _alpha(alpha)), 0.0)


def _unit(v: NDArray) -> NDArray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _prepare(wi: ArrayLike, wo: ArrayLike, *params: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Check and broadcast ``wi``, ``wo`` ``(..., 3)`` against the parameters' shapes ``(...)``.

    Returns ``wi``, ``wo`` (float64, pairs with a direction at or below the horizon replaced by
    ``+z`` so that everything downstream stays finite) and the mask of valid pairs.
    """
    wi, wo = (as_float_array(w).astype(np.float64) for w in (wi, wo))
    check_last_dims(wi, (3,), "wi")
    check_last_dims(wo, (3,), "wo")
    for name, w in (("wi", wi), ("wo", wo)):
        with np.errstate(over="ignore", invalid="ignore"):
            if not np.isfinite(np.einsum("...k,...k->...", w, w)).all():  # NaN, Inf or a component near 1e154+
                raise ValueError(f"{name} must hold finite unit vectors; got NaN, Inf or a huge component")
    shape = np.broadcast_shapes(wi.shape[:-1], wo.shape[:-1], *(np.shape(p) for p in params))
    wi, wo = np.broadcast_to(wi, (*shape, 3)), np.broadcast_to(wo, (*shape, 3))
    valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    up = np.array([0.0, 0.0, 1.0])
    wi = np.where(valid[..., None], wi, up)
    wo = np.where(valid[..., None], wo, up)
    return wi, wo, valid


def _nonnegative(x: ArrayLike, name: str, upper: float = np.inf) -> NDArray:
    a = as_float_array(x).astype(np.float64)
    if np.any(~((a >= 0) & (a <= upper))):
        raise ValueError(f"{name} must be in [0, {upper}]; got values in [{np.min(a)}, {np.max(a)}]")
    return a


def _plane_axis(a: NDArray, b: NDArray, fallback: NDArray) -> NDArray:
    """Unit ``a x b`` (the normal of the plane spanned by ``a`` and ``b``), or ``fallback`` where ``a || b``."""
    c = np.cross(a, b)
    degenerate = np.linalg.norm(c, axis=-1, keepdims=True) == 0
    return np.where(degenerate, fallback, _unit(c))


def _microfacet_specular(wi: NDArray, wo: NDArray, eta: ArrayLike, alpha: ArrayLike) -> NDArray:
    """Specular microfacet lobe ``F D G / (4 cos_i)`` in the Mitsuba frames; ``(..., 4, 4)``.

    ``wi``, ``wo`` must be above the horizon. The Fresnel matrix is built in the s/p frame of the
    microfacet: the same x-axis ``s = wo x wi / |wo x wi|`` (perpendicular to the plane of
    reflection through ``h``) for the incident ``-wo`` and the reflected ``wi`` beam, then rotated
    into ``stokes_basis(-wo)`` and ``stokes_basis(wi)``. For ``wi == wo`` (normal incidence on the
    microfacet) the plane is undefined and so is ``s``; any ``s`` perpendicular to ``wi`` gives the
    same matrix there, and ``stokes_basis(wi)`` is used.
    """
    h = _unit(wi + wo)  # never zero: both z > 0
    cos_d = np.clip(np.sum(wo * h, axis=-1), 0.0, 1.0)
    d = ggx_d(h[..., 2], alpha)
    g = smith_g1(wi[..., 2], alpha) * smith_g1(wo[..., 2], alpha)
    f = reflection_mueller(cos_d, eta)
    s = _plane_axis(wo, wi, stokes_basis(wi))
    f = rotate_mueller_basis(f, -wo, s, stokes_basis(-wo), wi, s, stokes_basis(wi))
    return f * (d * g / (4.0 * wi[..., 2]))[..., None, None]


def _diffuse(wi: NDArray, wo: NDArray, eta: ArrayLike) -> NDArray:
    """Baek-2018 polarized diffuse lobe ``T_out diag(1,0,0,0) T_in / pi`` (no albedo, no cos); ``(..., 4, 4)``.

    Light refracts into the surface through the interface (``T_in`` at the light's angle), is fully
    depolarized underneath and refracts out towards the camera (``T_out``). The flux transmittance
    out of the surface at the internal angle ``theta'`` with ``1 / eta`` equals the transmittance
    into it at the camera angle with ``eta`` (reciprocity of the power Fresnel coefficients), which
    is what is evaluated. The s/p frames have their x-axis perpendicular to the plane through the
    normal and the direction (``n x w``); at normal incidence that plane is undefined but the
    transmission matrix is then unpolarizing, so any axis works.
    """
    n = np.zeros_like(wi)
    n[..., 2] = 1.0
    # T_in's s-axis is n x (-wo), T_out's n x wi; rotate them into the Stokes bases of -wo and wi.
    c_in = rotate_stokes_basis(-wo, _plane_axis(n, -wo, stokes_basis(-wo)), stokes_basis(-wo))
    c_out = rotate_stokes_basis(wi, _plane_axis(n, wi, stokes_basis(wi)), stokes_basis(wi))
    t_in = transmission_mueller(wo[..., 2], eta) @ np.swapaxes(c_in, -1, -2)
    t_out = c_out @ transmission_mueller(wi[..., 2], eta)
    # diag(1, 0, 0, 0) between the two: the outer product of T_out's first column and T_in's first row.
    return t_out[..., :, :1] * t_in[..., :1, :] / np.pi


def dielectric_pbrdf(
    wi: ArrayLike, wo: ArrayLike, *, albedo: ArrayLike, eta: ArrayLike, alpha: ArrayLike, specular: ArrayLike = 1.0
) -> NDArray:
    """Polarimetric BRDF of a rough dielectric with a diffuse base (Baek et al. 2018), times ``cos_o``.

    Equal to Mitsuba 3's ``pplastic`` (``diffuse_reflectance = albedo``, ``int_ior = eta``,
    ``ext_ior = 1``, ``distribution = 'ggx'``, ``alpha``, ``specular_reflectance = specular``) in
    its polarized variants to float32 precision for directions more than 3 degrees above the
    horizon (Mitsuba computes in float32; see the warning for grazing angles).

    .. math::
        M = \\Big[k_s\\,\\frac{D\\,G}{4\\cos\\theta_i\\cos\\theta_o}\\,C_o R(\\theta_d;\\eta) C_i
          + \\frac{\\rho}{\\pi}\\,C'_o T(\\theta_i;\\eta)\\,\\mathrm{diag}(1,0,0,0)\\,T(\\theta_o;\\eta) C'_i\\Big]
          \\cos\\theta_o

    with the GGX ``D`` (:func:`ggx_d`) at ``h = (wi + wo) / |wi + wo|``, ``G = G1(wi) G1(wo)``
    (:func:`smith_g1`), ``theta_d`` the angle between ``wo`` and ``h``, ``R`` and ``T`` the Fresnel
    reflection and flux-transmission Mueller matrices (:mod:`pbrdf.polar.fresnel`) and ``C`` the
    rotations from the planes of reflection (through ``h``) and of refraction (through ``n``) to
    the Stokes bases of the module Convention. Mitsuba evaluates the exit transmittance at the
    refracted camera angle with ``1 / eta``; by reciprocity of the flux Fresnel coefficients that is
    ``T(theta_i; eta)``, which is what is computed.

    .. warning::
        Near grazing angles Mitsuba's float32 transmittances lose digits and its diffuse lobe drifts
        from this float64 one: relative to ``m00``, about ``1e-7 / cos_i^2`` (2.8e-2 at
        ``cos_i = 7e-4``) from its exit cosine ``sqrt(1 - eta^2 sin^2)``, and up to
        ``1.3e-6 / cos_o`` from ``specular_transmission`` at a grazing light. The specular lobe
        agrees to 2e-5 everywhere.

    Args:
        wi: unit direction towards the camera, local frame, ``(..., 3)``.
        wo: unit direction towards the light, ``(..., 3)``; broadcasts with ``wi``.
        albedo: diffuse reflectance ``rho`` in [0, 1], broadcastable to ``(...)``.
        eta: real relative index of refraction of the dielectric (e.g. 1.5), broadcastable.
        alpha: GGX roughness (``roughness**2``), clamped to [:data:`ALPHA_MIN`, :data:`ALPHA_MAX`].
        specular: scale ``k_s`` of the specular lobe (Mitsuba's ``specular_reflectance``).

    Returns:
        Mueller matrices ``(..., 4, 4)``, float64, in the frames of the module Convention; zero
        where ``wi`` or ``wo`` is below (or on) the horizon.

    Raises:
        ValueError: if a direction is not ``(..., 3)``, ``alpha < 0``, ``albedo`` is outside
            [0, 1], ``specular < 0``, ``eta`` is complex or ``eta <= 0``.

    Example:
        Normal incidence and viewing: the specular lobe has the mirror signs (m22, m33 < 0), the
        diffuse lobe only adds to m00:

        >>> m = dielectric_pbrdf([0, 0, 1.0], [0, 0, 1.0], albedo=0.5, eta=1.5, alpha=0.3)
        >>> np.round(np.diag(m), 4)
        array([ 0.182 ,  0.0354, -0.0354, -0.0354])

    References:
        S.-H. Baek, D. S. Jeon, X. Tong, M. H. Kim, "Simultaneous acquisition of polarimetric
        SVBRDF and normals", ACM Trans. Graph. 37(6):268 (SIGGRAPH Asia 2018).
        Walter et al. 2007 (see :func:`ggx_d`).
    """
    eta_arr = np.asarray(eta)
    if np.iscomplexobj(eta_arr) and np.any(eta_arr.imag != 0):
        raise ValueError("dielectric_pbrdf needs a real eta; use conductor_pbrdf for a complex IOR")
    eta_r = eta_arr.real.astype(np.float64)
    rho = _nonnegative(albedo, "albedo", 1.0)
    k_s = _nonnegative(specular, "specular")
    wi, wo, valid = _prepare(wi, wo, rho, eta_r, alpha, k_s)
    spec = _microfacet_specular(wi, wo, eta_r, alpha)
    diff = _diffuse(wi, wo, eta_r) * wo[..., 2, None, None]
    m = k_s[..., None, None] * spec + rho[..., None, None] * diff
    return np.where(valid[..., None, None], m, 0.0)


def conductor_pbrdf(
    wi: ArrayLike, wo: ArrayLike, *, eta: ArrayLike, alpha: ArrayLike, specular: ArrayLike = 1.0
) -> NDArray:
    """Polarimetric BRDF of a rough conductor (GGX microfacets, complex Fresnel), times ``cos_o``.

    Equal to Mitsuba 3's ``roughconductor`` (``eta = n``, ``k = k``, ``distribution = 'ggx'``,
    ``alpha``, ``specular_reflectance = specular``) in its polarized variants: every entry within
    1e-5 of ``m00`` over the whole upper hemisphere, grazing directions included (float32).

    .. math::
        M = k_s\\,\\frac{D\\,G}{4\\cos\\theta_i\\cos\\theta_o}\\,C_o R(\\theta_d;\\eta) C_i\\,\\cos\\theta_o

    (symbols as in :func:`dielectric_pbrdf`). The phase difference between ``r_s`` and ``r_p``
    of the complex ``eta`` makes ``R`` a retarder as well as a diattenuator: linear light
    oblique to the plane of reflection comes back elliptical (``m23 = -m32 != 0`` in the s/p frame).

    Args:
        wi: unit direction towards the camera, local frame, ``(..., 3)``.
        wo: unit direction towards the light, ``(..., 3)``; broadcasts with ``wi``.
        eta: complex relative IOR ``n - ik`` (``n + ik`` is read as ``n - ik``; see
            :mod:`pbrdf.polar.fresnel`), e.g. gold near 600 nm ``0.18 - 3.2j``; broadcastable.
        alpha: GGX roughness (``roughness**2``), clamped to [:data:`ALPHA_MIN`, :data:`ALPHA_MAX`].
        specular: scale ``k_s`` (Mitsuba's ``specular_reflectance``).

    Returns:
        Mueller matrices ``(..., 4, 4)``, float64, in the frames of the module Convention; zero
        where ``wi`` or ``wo`` is below (or on) the horizon.

    Raises:
        ValueError: if a direction is not ``(..., 3)``, ``alpha < 0``, ``specular < 0`` or
            ``Re(eta) <= 0``.

    Example:
        Gold lit and seen at 45 degrees in the xz-plane, where both Stokes bases lie in the plane
        of incidence (p-aligned), so circular polarization comes only from +-45 degree light
        (``m23 = -m32``); s- and p-polarized light stays linear (``m21 = m31 = 0``):

        >>> w = 0.5**0.5
        >>> np.round(conductor_pbrdf([w, 0, w], [-w, 0, w], eta=0.18 - 3.2j, alpha=0.1), 3) + 0.0
        array([[10.483, -0.231,  0.   ,  0.   ],
               [-0.231, 10.483,  0.   ,  0.   ],
               [ 0.   ,  0.   , -9.553,  4.311],
               [ 0.   ,  0.   , -4.311, -9.553]])
    """
    eta_c = np.asarray(eta, dtype=np.complex128)
    k_s = _nonnegative(specular, "specular")
    wi, wo, valid = _prepare(wi, wo, eta_c, alpha, k_s)
    m = k_s[..., None, None] * _microfacet_specular(wi, wo, eta_c, alpha)
    return np.where(valid[..., None, None], m, 0.0)
