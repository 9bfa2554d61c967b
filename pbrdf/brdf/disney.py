"""The Disney principled BRDF (Burley 2012), split into diffuse and specular parts, and its fit.

One home for this math: the simulator, the decoder, the network's differentiable renderer and its
loss all call these functions. Every evaluation function accepts numpy arrays *and* torch tensors
(autograd-friendly, any float dtype and device) and returns the same kind; the backend is picked
from the arguments through a tiny private namespace, using only operations both libraries share
(``where``, ``clip``, ``sqrt`` and arithmetic). torch is never imported here: a tensor argument
can only exist once the caller has imported it.

Model (no cosine factor; ``l`` the light, ``v`` the view direction, ``h`` the half vector):

.. math::
    f = f_d + f_s,\\qquad
    f_d = (1 - m)\\,\\frac{\\rho}{\\pi}\\,\\bigl(1 + (F_{D90} - 1)(1 - \\cos\\theta_l)^5\\bigr)
          \\bigl(1 + (F_{D90} - 1)(1 - \\cos\\theta_v)^5\\bigr),\\quad
    F_{D90} = \\tfrac12 + 2 r \\cos^2\\theta_d

.. math::
    f_s = D(h)\\,\\frac{G_1(l) G_1(v)}{4 \\cos\\theta_l \\cos\\theta_v}\\,F(\\cos\\theta_d),\\quad
    D = \\frac{\\alpha^2}{\\pi\\,(\\cos^2\\theta_h(\\alpha^2 - 1) + 1)^2},\\quad
    G_1(x) = \\frac{2\\cos\\theta_x}{\\cos\\theta_x + \\sqrt{\\alpha^2 + (1-\\alpha^2)\\cos^2\\theta_x}}

.. math::
    F = F_0 + (1 - F_0)(1 - \\cos\\theta_d)^5,\\quad
    F_0 = \\mathrm{lerp}(0.08\\,s\\,[1,1,1],\\ \\rho,\\ m),\\quad \\alpha = \\max(r^2, 10^{-3})

with base colour (albedo) ``rho``, roughness ``r``, metallic ``m``, ``specular`` ``s`` (0.5 gives
F0 = 0.04, i.e. IOR 1.5) and ``theta_d`` the angle between ``l`` and ``h``.

Choices:
    * Smith G is the separable *exact* GGX masking with the plain ``alpha = r^2`` (Walter et al.
      2007), not Burley 2012's ``alpha_g = (0.5 + r/2)^2`` remap, which Burley dropped in 2015.
      This is the G of Mitsuba's ``principled``, ``roughconductor`` and ``pplastic`` (Baek 2018),
      so this model and the analytic polarimetric microfacet model share D and G.
    * ``alpha`` is clamped at 1e-3 (as Mitsuba's ``principled`` does): below roughness 0.0316 the
      lobe stops sharpening and the gradient with respect to roughness is zero. The peak value
      ``D(n) = 1 / (pi alpha^2)`` stays below 3.2e5, so float32 does not overflow.
    * The building blocks :func:`ggx_ndf` and :func:`smith_g1_ggx` take ``alpha`` directly (the
      microfacet models use a floor of 1e-4) and clamp it to :data:`ALPHA_RANGE` = [1e-4, 1e4]:
      ``alpha = 0`` (a perfect mirror, whose D is a delta) and a huge ``alpha`` (whose square
      overflows float32 beyond 1.8e19) both stay finite. ``G1`` uses the form
      ``sqrt(cos^2 + alpha^2 (1 - cos^2))``, a sum of non-negative terms, instead of
      ``alpha^2 + (1 - alpha^2) cos^2``, which cancels to 0 for large ``alpha`` (G1 was 2).
    * ``G / (4 cos_l cos_v)`` is evaluated as one visibility term
      ``1 / ((cos_l + sqrt(a^2 + (1-a^2) cos_l^2)) (cos_v + sqrt(...)))`` that never divides by a
      cosine: finite (and with finite gradients) at grazing incidence.
    * No sheen, clearcoat, subsurface, spec_tint, anisotropy or transmission.

Convention:
    Directions are unit vectors in the local shading frame (z = the normal), both pointing away
    from the surface. Below the horizon (``w.z <= 0`` for either direction) the BRDF is 0. The
    functions taking cosines clip them to [0, 1]. Parameters are assumed to lie in their ranges
    (albedo linear RGB in [0, 1], roughness and metallic in [0, 1]) and are not checked: they are
    network outputs in a hot loop, and a check would sync the GPU.

    The BRDF is reciprocal, so which of ``wi`` and ``wo`` is the light does not matter for the
    value; the *cosine-weighted* quantity fitted by :func:`fit_disney` uses ``cos(theta_o)`` of
    ``wo``, like Mitsuba's ``bsdf.eval(ctx, si, wo)`` with ``si.wi = wi`` (BRDF times
    ``Frame3f.cos_theta(wo)``).

References:
    B. Burley, "Physically-Based Shading at Disney", SIGGRAPH 2012 course notes (Appendix B).
    B. Burley, "Extending the Disney BRDF to a BSDF with Integrated Subsurface Scattering",
    SIGGRAPH 2015 course notes.
    B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for Refraction through Rough
    Surfaces", EGSR 2007.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from pbrdf._checks import as_float_array, check_last_dims

__all__ = [
    "ALPHA_MIN",
    "ALPHA_RANGE",
    "FitResult",
    "disney_brdf",
    "disney_diffuse",
    "disney_lobes",
    "disney_specular",
    "fit_disney",
    "ggx_ndf",
    "roughness_to_alpha",
    "schlick_fresnel",
    "smith_g1_ggx",
]

ALPHA_MIN = 1e-3
"""Smallest GGX alpha of the Disney model (roughness 0.0316); keeps D finite for a perfect mirror."""

ALPHA_RANGE = (1e-4, 1e4)
"""``(floor, ceiling)`` of the alpha taken by :func:`ggx_ndf` and :func:`smith_g1_ggx`; outside
values are clamped. The floor is the microfacet models' (Mitsuba's 1e-4, ``D(n) = 3.2e7``); at
the ceiling ``D`` and ``G1`` are within 1e-8 of their ``alpha -> inf`` limits (0), and
``alpha^2 cos^2`` squared stays far below float32's maximum."""

_INV_PI = 1.0 / np.pi


# --- backend shim ------------------------------------------------------------------------------


class _Ops(NamedTuple):
    """The few array operations the BRDF needs, from numpy or from torch."""

    clip: Callable[..., Any]
    sqrt: Callable[..., Any]
    where: Callable[..., Any]
    out: Callable[[Any], Any]  # final cast: numpy scalars (0-d) promote float32 to float64 mid-way


def _identity(x: Any) -> Any:
    return x


def _numpy_ops(dtype: type) -> _Ops:
    return _Ops(clip=np.clip, sqrt=np.sqrt, where=np.where, out=lambda x: np.asarray(x, dtype=dtype))


_NUMPY_OPS = _numpy_ops(np.float64)


def _backend(*args: Any) -> tuple[_Ops, list[Any]]:
    """Pick numpy or torch from the arguments and convert all of them to that backend.

    torch is chosen when any argument is a ``torch.Tensor`` (looked up in ``sys.modules``, so this
    never imports torch). The float dtype is the promotion of the tensors' float dtypes (torch's
    default dtype if none is floating) and the device is the first tensor's; tensors keep their
    autograd graph. Otherwise every argument becomes an ndarray of one float dtype: float32 when
    all array arguments are float32 (Python scalars do not promote), else float64.
    """
    torch = sys.modules.get("torch")
    if torch is not None:
        tensors = [a for a in args if isinstance(a, torch.Tensor)]
        if tensors:
            dtype = None
            for t in tensors:
                if t.is_floating_point():
                    dtype = t.dtype if dtype is None else torch.promote_types(dtype, t.dtype)
            dtype = dtype or torch.get_default_dtype()
            device = tensors[0].device
            out = [
                a.to(dtype=dtype, device=device)
                if isinstance(a, torch.Tensor)
                else torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype, device=device)
                for a in args
            ]
            return _Ops(clip=torch.clamp, sqrt=torch.sqrt, where=torch.where, out=_identity), out
    # numpy: float32 only when every array argument is float32; Python scalars and lists follow.
    typed = [a.dtype for a in args if isinstance(a, np.ndarray | np.generic)]
    dtype = np.result_type(*typed, np.float32) if typed else np.float64
    if dtype not in (np.float32, np.float64):
        dtype = np.float64
    return _numpy_ops(dtype), [np.asarray(a, dtype=dtype) for a in args]


def _pow5(x: Any) -> Any:
    x2 = x * x
    return x2 * x2 * x


# --- building blocks -----------------------------------------------------------------------------


def roughness_to_alpha(roughness: Any) -> Any:
    """GGX alpha from perceptual roughness: ``alpha = clip(roughness^2, 1e-3, 1e4)``; shape ``(...)``."""
    ops, (r,) = _backend(roughness)
    return ops.out(ops.clip(r * r, ALPHA_MIN, ALPHA_RANGE[1]))


def ggx_ndf(n_dot_h: Any, alpha: Any) -> Any:
    """GGX (Trowbridge-Reitz) normal distribution ``D(h)`` in 1/sr; shape ``(...)``.

    .. math::
        D = \\frac{\\alpha^2}{\\pi\\,\\bigl((1 - \\cos^2\\theta_h) + \\alpha^2\\cos^2\\theta_h\\bigr)^2}

    (the usual denominator rearranged to avoid cancellation near the peak). Normalised so that the
    projected integral ``int D cos(theta_h) d omega_h`` over the hemisphere is 1 (tested).

    Args:
        n_dot_h: cosine of the half vector's polar angle, clipped to [0, 1], shape ``(...)``.
        alpha: GGX alpha (see :func:`roughness_to_alpha`), broadcastable; clamped to
            :data:`ALPHA_RANGE` ([1e-4, 1e4]), so ``alpha = 0`` gives the floor's finite peak.

    Returns:
        ``D >= 0``, finite for finite inputs (at most ``1 / (pi 1e-8) = 3.2e7``), the broadcast
        shape, same backend and dtype as the inputs.
    """
    ops, (c, a) = _backend(n_dot_h, alpha)
    c2 = ops.clip(c, 0.0, 1.0) ** 2
    a = ops.clip(a, *ALPHA_RANGE)
    a2 = a * a
    d = (1.0 - c2) + a2 * c2
    return ops.out(a2 * _INV_PI / (d * d))


def smith_g1_ggx(n_dot_w: Any, alpha: Any) -> Any:
    """Exact Smith masking for GGX, ``G1 = 2 cos / (cos + sqrt(alpha^2 + (1 - alpha^2) cos^2))``.

    Equal to ``2 / (1 + sqrt(1 + alpha^2 tan^2 theta))`` (Walter et al. 2007, eq. 34) without the
    division by the cosine.

    Args:
        n_dot_w: cosine of the direction's polar angle, clipped to [0, 1], shape ``(...)``.
        alpha: GGX alpha, broadcastable; clamped to :data:`ALPHA_RANGE` ([1e-4, 1e4]).

    Returns:
        ``G1`` in [0, 1], the broadcast shape: exactly 0 at grazing (``cos = 0``) and exactly 1 at
        normal incidence (``cos = 1``) for every ``alpha``, ``alpha = 0`` and ``1e150`` included.
        Same backend and dtype as the inputs; finite torch gradients everywhere.
    """
    ops, (c, a) = _backend(n_dot_w, alpha)
    c = ops.clip(c, 0.0, 1.0)
    a = ops.clip(a, *ALPHA_RANGE)
    return ops.out(2.0 * c / (c + _lambda_root(ops, c, a * a)))


def _lambda_root(ops: _Ops, c: Any, a2: Any) -> Any:
    """``sqrt(cos^2 + alpha^2 (1 - cos^2))`` (>= min(alpha, cos) > 0; both terms >= 0, no cancellation)."""
    c2 = c * c
    return ops.sqrt(c2 + a2 * (1.0 - c2))


def schlick_fresnel(cos_theta_d: Any, f0: Any) -> Any:
    """Schlick's Fresnel approximation ``F0 + (1 - F0)(1 - cos)^5``; equals ``F0`` at normal incidence.

    Args:
        cos_theta_d: cosine between the light and the half vector, clipped to [0, 1], shape ``(...)``.
        f0: reflectance at normal incidence, broadcastable (e.g. ``(..., 3)`` with ``cos[..., None]``).
    """
    ops, (c, f) = _backend(cos_theta_d, f0)
    w = _pow5(ops.clip(1.0 - c, 0.0, 1.0))
    return ops.out(f + (1.0 - f) * w)


# --- the two lobes ----------------------------------------------------------------------------


def _check_albedo(albedo: Any) -> None:
    if albedo.ndim < 1 or albedo.shape[-1] != 3:
        raise ValueError(f"albedo must have shape (..., 3); got {tuple(albedo.shape)}")


def disney_diffuse(n_dot_l: Any, n_dot_v: Any, l_dot_h: Any, albedo: Any, roughness: Any, metallic: Any) -> Any:
    """Burley diffuse lobe with retro-reflection, without the cosine factor; shape ``(..., 3)``.

    .. math::
        f_d = (1 - m)\\frac{\\rho}{\\pi}(1 + (F_{D90} - 1)(1 - \\cos\\theta_l)^5)
              (1 + (F_{D90} - 1)(1 - \\cos\\theta_v)^5),\\quad F_{D90} = 0.5 + 2 r \\cos^2\\theta_d

    At normal incidence (both cosines 1) the shape factor is exactly 1, so ``f_d = (1-m) rho/pi``;
    at grazing angles it ranges from ``0.25`` (smooth) to ``6.25`` (rough, retro-reflection).

    Args:
        n_dot_l: cosine of the light direction, clipped to [0, 1], shape ``(...)``.
        n_dot_v: cosine of the view direction, clipped to [0, 1], shape ``(...)``.
        l_dot_h: cosine of the difference angle theta_d (light vs half vector), clipped to [0, 1].
        albedo: base colour, linear RGB in [0, 1], ``(..., 3)``.
        roughness: perceptual roughness in [0, 1], shape ``(...)``.
        metallic: metallic weight in [0, 1], shape ``(...)``.

    Returns:
        The diffuse BRDF in 1/sr, the broadcast shape with the channel axis last, ``(..., 3)``.
        numpy in, numpy out; a torch tensor anywhere gives a tensor.

    Raises:
        ValueError: if ``albedo`` does not end in 3 channels.
    """
    ops, (nl, nv, lh, rho, r, m) = _backend(n_dot_l, n_dot_v, l_dot_h, albedo, roughness, metallic)
    _check_albedo(rho)
    fl = _pow5(ops.clip(1.0 - nl, 0.0, 1.0))
    fv = _pow5(ops.clip(1.0 - nv, 0.0, 1.0))
    lh = ops.clip(lh, 0.0, 1.0)
    fd90_m1 = 2.0 * r * lh * lh - 0.5  # F_D90 - 1
    shape = (1.0 + fd90_m1 * fl) * (1.0 + fd90_m1 * fv)
    return ops.out(((1.0 - m) * shape * _INV_PI)[..., None] * rho)


def disney_specular(
    n_dot_l: Any,
    n_dot_v: Any,
    n_dot_h: Any,
    l_dot_h: Any,
    albedo: Any,
    roughness: Any,
    metallic: Any,
    *,
    specular: Any = 0.5,
) -> Any:
    """GGX specular lobe ``D G F / (4 cos_l cos_v)`` without the cosine factor; shape ``(..., 3)``.

    ``D``: :func:`ggx_ndf` with ``alpha = max(roughness^2, 1e-3)``; ``G``: separable exact Smith
    (:func:`smith_g1_ggx` for light and view); ``F``: :func:`schlick_fresnel` with
    ``F0 = lerp(0.08 specular [1,1,1], albedo, metallic)``. The visibility ``G / (4 cos_l cos_v)``
    is computed without dividing by the cosines, so grazing directions stay finite.

    Args:
        n_dot_l: cosine of the light direction, clipped to [0, 1], shape ``(...)``.
        n_dot_v: cosine of the view direction, clipped to [0, 1], shape ``(...)``.
        n_dot_h: cosine of the half vector, clipped to [0, 1], shape ``(...)``.
        l_dot_h: cosine between light and half vector (theta_d), clipped to [0, 1], shape ``(...)``.
        albedo: base colour, linear RGB in [0, 1], ``(..., 3)``; tints F0 for metals.
        roughness: perceptual roughness in [0, 1], shape ``(...)``.
        metallic: metallic weight in [0, 1], shape ``(...)``.
        specular: Disney "specular" in [0, 1], shape ``(...)``. Default 0.5 = F0 0.04 (IOR 1.5), the
            value every Principled BSDF uses unless told otherwise.

    Returns:
        The specular BRDF in 1/sr, ``(..., 3)``, same backend as the inputs.

    Raises:
        ValueError: if ``albedo`` does not end in 3 channels.
    """
    ops, (nl, nv, nh, lh, rho, r, m, s) = _backend(
        n_dot_l, n_dot_v, n_dot_h, l_dot_h, albedo, roughness, metallic, specular
    )
    _check_albedo(rho)
    nl = ops.clip(nl, 0.0, 1.0)
    nv = ops.clip(nv, 0.0, 1.0)
    alpha = ops.clip(r * r, ALPHA_MIN, ALPHA_RANGE[1])
    a2 = alpha * alpha
    d = ggx_ndf(nh, alpha)
    # G1(l) G1(v) / (4 cos_l cos_v), the 2 cos factors of G1 cancelled against the denominator.
    vis = 1.0 / ((nl + _lambda_root(ops, nl, a2)) * (nv + _lambda_root(ops, nv, a2)))
    m3 = m[..., None]
    f0 = (0.08 * s * (1.0 - m))[..., None] + m3 * rho
    f = schlick_fresnel(lh[..., None], f0)
    return ops.out((d * vis)[..., None] * f)


def _dot3(a: Any, b: Any) -> Any:
    """Dot product over the last axis, summed in a fixed order (numpy and torch agree bit for bit)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _half_vector_cosines(
    ops: _Ops, wi: Any, wo: Any, cos_i: Any = None, cos_o: Any = None
) -> tuple[Any, Any, Any, Any, Any]:
    """``(cos_i, cos_o, n_dot_h, i_dot_h, above)`` for unit directions ``(..., 3)``.

    ``cos_i`` and ``cos_o`` are the directions' cosines with the normal (default: their z
    components, the local frame). For unit vectors ``wi . h = wo . h = |wi + wo| / 2``; computing
    it that way, and ``n . h`` from ``cos_i + cos_o``, makes every quantity symmetric in ``wi`` and
    ``wo`` to the last bit, so swapping them gives the identical value (exact reciprocity).
    """
    h = wi + wo
    len2 = _dot3(h, h)
    nonzero = len2 > 0
    # wi = -wo only happens on the horizon, where the BRDF is masked to 0: any finite length will do,
    # and the sqrt never sees 0 (whose derivative is infinite).
    length = ops.sqrt(ops.where(nonzero, len2, 1.0))
    cos_i = wi[..., 2] if cos_i is None else cos_i
    cos_o = wo[..., 2] if cos_o is None else cos_o
    n_dot_h = (cos_i + cos_o) / length
    i_dot_h = ops.where(nonzero, 0.5 * length, 0.0)
    return cos_i, cos_o, n_dot_h, i_dot_h, (cos_i > 0) & (cos_o > 0)


def disney_brdf(
    wi: Any, wo: Any, albedo: Any, roughness: Any, metallic: Any, *, specular: Any = 0.5
) -> tuple[Any, Any]:
    """Disney BRDF from two directions in the local frame, as ``(diffuse, specular)``.

    No cosine factor. Zero where either direction is at or below the horizon; finite (values and
    torch gradients) at grazing and normal incidence and for ``wi == wo``.

    Args:
        wi: unit direction (light or view) in the local frame, z = normal, ``(..., 3)``. Not
            normalised here (``cos(theta_d)`` is taken as ``|wi + wo| / 2``).
        wo: the other unit direction, ``(..., 3)``. The BRDF is symmetric in ``wi`` and ``wo``.
        albedo: base colour, linear RGB in [0, 1], ``(..., 3)``.
        roughness: perceptual roughness in [0, 1] (GGX alpha = roughness^2), shape ``(...)``.
        metallic: metallic weight in [0, 1], shape ``(...)``.
        specular: Disney "specular" in [0, 1] (0.5 = F0 0.04), shape ``(...)``.

    Returns:
        ``(diffuse, specular)``, each ``(..., 3)`` in 1/sr, broadcast over all inputs.

    Raises:
        ValueError: if ``wi``, ``wo`` or ``albedo`` does not end in 3 components.

    Example:
        Normal incidence on grey plastic (albedo 0.5, roughness 0.5, so alpha = 0.25):
        ``f_d = 0.5 / pi`` and ``f_s = F0 / (4 pi alpha^2)`` with F0 = 0.04.

        >>> n = np.array([0.0, 0.0, 1.0])
        >>> fd, fs = disney_brdf(n, n, [0.5, 0.5, 0.5], 0.5, 0.0)
        >>> np.round(fd, 6), np.round(fs, 6)
        (array([0.159155, 0.159155, 0.159155]), array([0.050930, 0.050930, 0.050930]))
    """
    ops, (wi_, wo_, albedo, roughness, metallic, specular) = _backend(wi, wo, albedo, roughness, metallic, specular)
    if wi_.ndim < 1 or wi_.shape[-1] != 3 or wo_.ndim < 1 or wo_.shape[-1] != 3:
        raise ValueError(f"wi and wo must have shape (..., 3); got {tuple(wi_.shape)} and {tuple(wo_.shape)}")
    cos_i, cos_o, n_dot_h, i_dot_h, above = _half_vector_cosines(ops, wi_, wo_)
    fd = disney_diffuse(cos_i, cos_o, i_dot_h, albedo, roughness, metallic)
    fs = disney_specular(cos_i, cos_o, n_dot_h, i_dot_h, albedo, roughness, metallic, specular=specular)
    above = above[..., None]
    return ops.out(ops.where(above, fd, 0.0)), ops.out(ops.where(above, fs, 0.0))


def disney_lobes(
    normal: Any,
    wi: Any,
    wo: Any,
    albedo: Any,
    roughness: Any,
    metallic: Any,
    *,
    specular: Any = 0.5,
    specular_roughness: Any = None,
) -> tuple[Any, Any]:
    """Disney BRDF ``(diffuse, specular)`` for directions and normals in any common frame.

    The frame-free form of :func:`disney_brdf` (equal to it in the local frame, where ``normal``
    is ``(0, 0, 1)``): the cosines are dot products with ``normal``. Used by the network's
    differentiable re-renderer, where normals, light and view directions are all camera-frame.
    ``diffuse + specular`` is the full BRDF; the two parts are returned separately because they
    interact differently with the display's polarization (see :mod:`network.rerender`).

    Args:
        normal: unit surface normal, ``(..., 3)``. Not normalised here.
        wi: unit direction (light or view) pointing away from the surface, ``(..., 3)``.
        wo: the other unit direction, ``(..., 3)``; the BRDF is symmetric in ``wi`` and ``wo``.
        albedo: base colour, linear RGB in [0, 1], ``(..., 3)``.
        roughness: perceptual roughness in [0, 1], shape ``(...)``.
        metallic: metallic weight in [0, 1], shape ``(...)``.
        specular: Disney "specular" in [0, 1] (0.5 = F0 0.04), shape ``(...)``.
        specular_roughness: roughness of the specular lobe, shape ``(...)``, when it differs from
            the diffuse lobe's (e.g. a lobe widened by a quadrature's patch size); default
            ``roughness``.

    Returns:
        ``(diffuse, specular)``, each ``(..., 3)`` in 1/sr, 0 where either direction is at or
        below the horizon of ``normal``; finite values and torch gradients everywhere.

    Raises:
        ValueError: if ``normal``, ``wi``, ``wo`` or ``albedo`` does not end in 3 components.
    """
    spec_r = roughness if specular_roughness is None else specular_roughness
    ops, (n, wi_, wo_, albedo, roughness, metallic, specular, spec_r) = _backend(
        normal, wi, wo, albedo, roughness, metallic, specular, spec_r
    )
    for name, arr in (("normal", n), ("wi", wi_), ("wo", wo_)):
        if arr.ndim < 1 or arr.shape[-1] != 3:
            raise ValueError(f"{name} must have shape (..., 3); got {tuple(arr.shape)}")
    cos_i, cos_o, n_dot_h, i_dot_h, above = _half_vector_cosines(ops, wi_, wo_, _dot3(n, wi_), _dot3(n, wo_))
    fd = disney_diffuse(cos_i, cos_o, i_dot_h, albedo, roughness, metallic)
    fs = disney_specular(cos_i, cos_o, n_dot_h, i_dot_h, albedo, spec_r, metallic, specular=specular)
    above = above[..., None]
    return ops.out(ops.where(above, fd, 0.0)), ops.out(ops.where(above, fs, 0.0))


# --- fit -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FitResult:
    """Disney parameters fitted by :func:`fit_disney` and the fit error.

    Attributes:
        albedo: base colour, linear RGB in [0, 1], ``(3,)`` float64.
        roughness: perceptual roughness in [sqrt(ALPHA_MIN), 1] = [0.0316, 1].
        metallic: metallic weight in [0, 1].
        rmse: root-mean-square error of the fitted cosine-weighted BRDF against the samples, over all
            used samples and channels (weighted if weights were given), in the units of ``values``;
            outliers count in full here (the robust loss only shapes the fit).
        rel_rmse: ``rmse`` over the root-mean-square of the samples (dimensionless).
        success: True when the selected least-squares run converged and its result is finite.
    """

    albedo: NDArray[np.float64]
    roughness: float
    metallic: float
    rmse: float
    rel_rmse: float
    success: bool


# Robust loss in the log-compressed domain: a residual of 0.1 is a 10% (of the value, for values
# above the scale s) error; 2% measurement noise stays in the quadratic part, gross outliers are
# weighted like an L1 norm.
_FIT_LOSS = "soft_l1"
_FIT_F_SCALE = 0.1
# Starting points: both ends of metallic times a spread of roughness (the specular width is the
# multimodal parameter); albedo is then solved in closed form for each start.
_START_ROUGHNESS = (0.1, 0.3, 0.55, 0.85)
_START_METALLIC = (0.0, 1.0)
# Lower bound of the fitted roughness: below sqrt(ALPHA_MIN) alpha is clamped and the model no
# longer depends on roughness, a flat region that trapped the optimiser at roughness 0.
_ROUGHNESS_FLOOR = float(np.sqrt(ALPHA_MIN))


def _model(geom: tuple[NDArray, ...], albedo: NDArray, roughness: float, metallic: float) -> NDArray:
    cos_i, cos_o, n_dot_h, i_dot_h, cos_weight = geom
    fd = disney_diffuse(cos_i, cos_o, i_dot_h, albedo, roughness, metallic)
    fs = disney_specular(cos_i, cos_o, n_dot_h, i_dot_h, albedo, roughness, metallic)
    return (fd + fs) * cos_weight[..., None]


def _model_jacobian(geom: tuple[NDArray, ...], x: NDArray) -> NDArray:
    """Analytic derivative of :func:`_model` with respect to ``(albedo RGB, roughness, metallic)``.

    With ``S`` the diffuse shape factor, ``DV = D * vis`` the specular lobe without Fresnel,
    ``w = (1 - cos_d)^5`` and ``F = F0 (1 - w) + w``, ``F0 = 0.04 (1 - m) + m rho`` (specular 0.5),
    the model is ``cw [(1 - m) S rho / pi + DV F]``, so

    * ``d/d rho_c = cw [(1 - m) S / pi + DV m (1 - w)]`` (channel ``c`` only),
    * ``d/dm = cw [-S rho / pi + DV (1 - w)(rho - 0.04)]``,
    * ``d/dr = cw [(1 - m) rho / pi dS/dr + F d(DV)/d alpha * d alpha/dr]`` with
      ``d alpha/dr = 2 r`` where ``r^2`` is above the clamp (0 below), ``dS/dr = 2 cos_d^2
      (f_l (1 + k f_v) + f_v (1 + k f_l))``, ``k = F_D90 - 1``, ``dD/d alpha = 2 alpha / (pi d^2)
      (1 - 2 alpha^2 cos_h^2 / d)`` and ``d vis / d alpha = -vis sum_x (d Lambda_x / d alpha) /
      (cos_x + Lambda_x)``, ``d Lambda / d alpha = alpha (1 - cos^2) / Lambda``.

    Returns:
        ``(N, 3, 5)``.
    """
    cos_i, cos_o, n_dot_h, i_dot_h, cw = geom
    rho, r, m = x[:3], float(x[3]), float(x[4])
    nl, nv = np.clip(cos_i, 0.0, 1.0), np.clip(cos_o, 0.0, 1.0)
    nh2 = np.clip(n_dot_h, 0.0, 1.0) ** 2
    lh = np.clip(i_dot_h, 0.0, 1.0)
    # diffuse
    fl, fv = _pow5(np.clip(1.0 - nl, 0.0, 1.0)), _pow5(np.clip(1.0 - nv, 0.0, 1.0))
    k = 2.0 * r * lh * lh - 0.5
    shape = (1.0 + k * fl) * (1.0 + k * fv)
    dshape = 2.0 * lh * lh * (fl * (1.0 + k * fv) + fv * (1.0 + k * fl))
    # specular
    alpha = min(max(r * r, ALPHA_MIN), ALPHA_RANGE[1])
    dalpha = 2.0 * r if ALPHA_MIN < r * r < ALPHA_RANGE[1] else 0.0
    a2 = alpha * alpha
    d = (1.0 - nh2) + a2 * nh2
    dist = a2 * _INV_PI / (d * d)
    ddist = 2.0 * alpha * _INV_PI / (d * d) * (1.0 - 2.0 * a2 * nh2 / d)
    lam_l, lam_v = _lambda_root(_NUMPY_OPS, nl, a2), _lambda_root(_NUMPY_OPS, nv, a2)
    vis = 1.0 / ((nl + lam_l) * (nv + lam_v))
    dvis = -vis * alpha * ((1.0 - nl * nl) / (lam_l * (nl + lam_l)) + (1.0 - nv * nv) / (lam_v * (nv + lam_v)))
    dv, ddv = dist * vis, ddist * vis + dist * dvis
    w = _pow5(np.clip(1.0 - lh, 0.0, 1.0))
    f0 = 0.04 * (1.0 - m) + m * rho  # (3,)
    fres = f0 * (1.0 - w)[:, None] + w[:, None]  # (N, 3)
    jac = np.zeros((len(cw), 3, 5))
    diag = (1.0 - m) * shape * _INV_PI + dv * m * (1.0 - w)
    for c in range(3):
        jac[:, c, c] = cw * diag
    jac[:, :, 3] = cw[:, None] * ((1.0 - m) * _INV_PI * dshape[:, None] * rho + fres * (ddv * dalpha)[:, None])
    jac[:, :, 4] = cw[:, None] * (-shape[:, None] * _INV_PI * rho + (dv * (1.0 - w))[:, None] * (rho - 0.04))
    return jac


def _solve_albedo(
    geom: tuple[NDArray, ...], values: NDArray, w: NDArray, scale: NDArray, roughness: float, metallic: float
) -> NDArray:
    """Albedo for fixed roughness and metallic: the model is affine in albedo, per channel.

    Weighted linear least squares with weights ``1 / (s + v)^2``, the first-order version of the
    log-compressed residual used by the fit.
    """
    b = _model(geom, np.zeros(3), roughness, metallic)
    a = _model(geom, np.ones(3), roughness, metallic) - b
    ww = w / (scale + values) ** 2
    num = np.sum(ww * a * (values - b), axis=0)
    den = np.sum(ww * a * a, axis=0)
    return np.clip(num / np.where(den > 0, den, 1.0), 0.0, 1.0)


def fit_disney(
    wi: ArrayLike,
    wo: ArrayLike,
    values: ArrayLike,
    *,
    weights: ArrayLike | None = None,
    init: tuple[ArrayLike, float, float] | None = None,
    cosine: bool = True,
) -> FitResult:
    """Fit Disney parameters (albedo, roughness, metallic) to measured RGB BRDF samples.

    The fitted quantity is ``(f_d + f_s)(wi, wo) * cos(theta_o)``, with ``theta_o`` the polar angle
    of ``wo``, i.e. what Mitsuba's ``bsdf.eval(ctx, si, wo)`` returns for ``si.wi = wi`` and the
    m00 entry of a measured pBRDF stored with the cosine; ``cosine=False`` fits the plain BRDF.
    ``specular`` is fixed at 0.5 (F0 = 0.04).

    Residuals are compared after the compression ``log(1 + v / s_c)`` with ``s_c`` the median of
    channel ``c`` (so specular peaks, orders of magnitude above the diffuse level, do not swamp the
    diffuse samples), times ``sqrt(weights)``, under scipy's ``soft_l1`` loss with scale 0.1 (robust
    to outliers). Albedo and metallic are bounded to [0, 1], roughness to [0.0316, 1]: below
    ``sqrt(ALPHA_MIN)`` alpha is clamped and the model does not depend on roughness, a flat region
    where the optimiser used to stop. Eight starts (metallic 0 and 1 times roughness 0.1, 0.3,
    0.55, 0.85, plus ``init``), each with the albedo solved in closed form, are refined by
    ``scipy.optimize.least_squares`` (trf) with the analytic Jacobian of the model; the lowest
    robust cost wins. Deterministic. Samples with either direction at or below the horizon are
    ignored; negative values count as 0.

    The fit only sees the samples: a lobe much sharper than their spacing (e.g. a roughness-0.03
    spike on a near-Lambertian material) can fall between them. Sample the mirror directions
    (as :func:`pbrdf.expansion.expand.sample_directions` does) and check the result on other
    pairs (:func:`pbrdf.expansion.expand.fit_table_disney`).

    Args:
        wi: unit directions in the local frame (z = normal), ``(N, 3)``.
        wo: unit directions, ``(N, 3)``; the cosine factor is ``wo[:, 2]``.
        values: measured cosine-weighted BRDF (m00), RGB, ``(N, 3)``.
        weights: optional non-negative sample weights, ``(N,)`` or ``(N, 3)``.
        init: optional extra start ``(albedo (3,), roughness, metallic)``, clipped to the bounds.
        cosine: whether ``values`` include the ``cos(theta_o)`` factor (default True).

    Returns:
        A :class:`FitResult`; ``rmse`` and ``rel_rmse`` are computed in the units of ``values``;
        ``roughness`` in [0.0316, 1].

    Raises:
        ValueError: on wrong shapes, non-finite inputs, negative weights or fewer than 5 usable samples.
    """
    wi_a = as_float_array(wi).astype(np.float64)
    wo_a = as_float_array(wo).astype(np.float64)
    v = as_float_array(values).astype(np.float64)
    for name, arr in (("wi", wi_a), ("wo", wo_a), ("values", v)):
        check_last_dims(arr, (3,), name)
        if arr.ndim != 2:
            raise ValueError(f"{name} must have shape (N, 3); got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
    n = v.shape[0]
    if wi_a.shape[0] != n or wo_a.shape[0] != n:
        raise ValueError(f"wi, wo and values need the same N; got {wi_a.shape[0]}, {wo_a.shape[0]}, {n}")
    if weights is None:
        w = np.ones((n, 3))
    else:
        w = np.broadcast_to(as_float_array(weights).astype(np.float64).reshape(n, -1), (n, 3))
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError("weights must be finite and non-negative")

    cos_i, cos_o, n_dot_h, i_dot_h, above = _half_vector_cosines(_NUMPY_OPS, wi_a, wo_a)
    used = above & np.any(w > 0, axis=-1)
    if np.count_nonzero(used) < 5:
        raise ValueError(
            f"need at least 5 samples above the horizon with positive weight; got {np.count_nonzero(used)}"
        )
    cos_weight = cos_o if cosine else np.ones_like(cos_o)
    geom = tuple(x[used] for x in (cos_i, cos_o, n_dot_h, i_dot_h, cos_weight))
    v, w = np.maximum(v[used], 0.0), w[used]
    sqrt_w = np.sqrt(w)
    # Per-channel compression scale; the floor keeps an all-dark channel well defined.
    peak = max(float(np.max(v)), 1e-12)
    scale = np.maximum(np.median(v, axis=0), 1e-3 * peak)
    target = np.log1p(v / scale)

    last: dict[bytes, NDArray] = {}  # the model at the latest x: least_squares asks for jac(x) after fun(x)

    def model_at(x: NDArray) -> NDArray:
        key = x.tobytes()
        if key not in last:
            last.clear()
            last[key] = _model(geom, x[:3], x[3], x[4])
        return last[key]

    def residual(x: NDArray) -> NDArray:
        return (sqrt_w * (np.log1p(model_at(x) / scale) - target)).ravel()

    def jacobian(x: NDArray) -> NDArray:
        return ((sqrt_w / (scale + model_at(x)))[..., None] * _model_jacobian(geom, x)).reshape(-1, 5)

    lower = np.array([0.0, 0.0, 0.0, _ROUGHNESS_FLOOR, 0.0])
    starts = []
    if init is not None:
        a0 = np.clip(np.broadcast_to(as_float_array(init[0]).astype(np.float64), (3,)), 0.0, 1.0)
        starts.append(np.r_[a0, np.clip(init[1], _ROUGHNESS_FLOOR, 1.0), np.clip(init[2], 0.0, 1.0)])
    for m0 in _START_METALLIC:
        for r0 in _START_ROUGHNESS:
            starts.append(np.r_[_solve_albedo(geom, v, w, scale, r0, m0), r0, m0])

    best = None
    for x0 in starts:
        res = least_squares(
            residual, x0, jac=jacobian, bounds=(lower, 1.0), loss=_FIT_LOSS, f_scale=_FIT_F_SCALE, method="trf"
        )
        if best is None or res.cost < best.cost:
            best = res

    x = best.x
    err = _model(geom, x[:3], x[3], x[4]) - v
    rmse = float(np.sqrt(np.sum(w * err**2) / np.sum(w)))
    rms = float(np.sqrt(np.sum(w * v**2) / np.sum(w)))
    return FitResult(
        albedo=np.array(x[:3], dtype=np.float64),
        roughness=float(x[3]),
        metallic=float(x[4]),
        rmse=rmse,
        rel_rmse=rmse / rms if rms > 0 else float("inf"),
        success=bool(best.success) and bool(np.all(np.isfinite(x))),
    )
