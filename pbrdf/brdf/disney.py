"""The Disney principled BRDF (Burley 2012), split into diffuse and specular parts.

One home for this math: the simulator, the decoder, the network's re-renderer and its loss call
these functions. Every evaluation function takes numpy arrays or torch tensors (any float dtype
and device, autograd-friendly) and returns the same kind; torch is never imported here.

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
F0 = 0.04, i.e. IOR 1.5) and ``theta_d`` the angle between ``l`` and ``h``. G is the exact
separable GGX masking with the plain ``alpha = r^2`` (Walter et al. 2007), the G of Mitsuba's
``principled``, ``roughconductor`` and ``pplastic``. No sheen, clearcoat, subsurface, spec_tint,
anisotropy or transmission. Values and gradients stay finite for any alpha and at grazing angles
(the choices behind that: docs/measurements/pbrdf.md, "Disney BRDF").

Convention:
    Directions are unit vectors in the local shading frame (z = the normal), both pointing away
    from the surface; below the horizon (``w.z <= 0`` for either) the BRDF is 0, and cosines are
    clipped to [0, 1]. Parameters (albedo linear RGB, roughness, metallic, all in [0, 1]) are not
    checked: they are network outputs in a hot loop, and a check would sync the GPU. The value is
    reciprocal in ``wi`` and ``wo``; the cosine-weighted quantity fitted by
    :func:`pbrdf.brdf.disney_fit.fit_disney` is Mitsuba's ``bsdf.eval(ctx, si, wo)`` with
    ``si.wi = wi`` (BRDF times ``cos(theta_o)`` of ``wo``).

Example:
    >>> import torch
    >>> n = torch.tensor([0.0, 0.0, 1.0])
    >>> fd, fs = disney_brdf(n, n, torch.full((3,), 0.5), torch.tensor(0.5), torch.tensor(0.0))
    >>> type(fd).__name__, round(float(fd[0]), 6)  # torch in, torch out; f_d = 0.5 / pi at normal incidence
    ('Tensor', 0.159155)

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
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "ALPHA_MIN",
    "ALPHA_RANGE",
    "disney_brdf",
    "disney_diffuse",
    "disney_lobes",
    "disney_specular",
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
