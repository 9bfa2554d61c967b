"""Rusinkiewicz angles of direction pairs and the plane-of-reflection Stokes frames of pBRDF tables.

The geometry behind :mod:`pbrdf.brdf.table`: a measured isotropic pBRDF is tabulated over the
half-vector angle ``theta_h``, the difference angle ``theta_d`` and the difference azimuth
``phi_d`` (Rusinkiewicz 1998), and its Mueller matrices act on Stokes vectors whose x-axis is
perpendicular to the plane of reflection.

Convention:
    Directions are unit vectors ``(..., 3)`` in the local shading frame (``z`` = normal), named as
    in Mitsuba's BSDF interface in radiance mode: ``wi`` points towards the camera (the side light
    leaves along) and ``wo`` towards the light. This is how Mitsuba's ``measured_polarized``
    plugin (``src/bsdfs/measured_polarized.cpp``, mitsuba 3.9.1) reads its table.

    * Rusinkiewicz angles: ``h = normalize(wi + wo)``, ``theta_h = angle(n, h)``,
      ``theta_d = angle(h, wo)``; ``b = normalize(n x h)``, ``t = b x h`` and
      ``phi_d = atan2(b . wo, t . wo)`` in ``[-pi, pi]``: the azimuth of the *light-side*
      direction about ``h``. The plugin first rotates both directions about ``n`` so that the
      *camera-side* direction ``wi`` has azimuth 0; the Rusinkiewicz angles do not depend on that
      rotation. Where ``h = n`` (``n x h = 0``), ``b = (0, 1, 0)`` here (the plugin gets NaN).
      Examples: camera ``wi = n``, light ``wo = (sin 60deg, 0, cos 60deg)`` gives ``theta_h =
      theta_d = 30deg`` and ``phi_d = 0`` (the light lies along ``+t``, away from the normal);
      the mirror configuration ``wi = (sin 30deg, 0, cos 30deg)``, ``wo = (-sin 30deg, 0,
      cos 30deg)`` gives ``theta_h = 0``, ``theta_d = 30deg``, ``phi_d = pi``.
    * Stokes frames of a table: both the incident beam (travelling along ``-wo``) and the
      reflected beam (along ``wi``) have their Stokes x-axis ``x = normalize(wo x wi)``
      (:func:`reflection_frame_x`), *perpendicular* to the plane of reflection (the s-direction,
      as in :func:`pbrdf.polar.fresnel.reflection_mueller`): the plugin builds
      ``t = normalize((wo - wi) x -wo)``, ``y = normalize(t x z)`` and ``x = y x z``, which is
      ``-t``; its y-axis lies in the plane (its source comment says the reference vector "lies in
      the plane of reflection"). For ``wi == wo`` the plane is undefined (the plugin gets NaN);
      here it is the plane of incidence of ``wi``.

References:
    S. Rusinkiewicz, "A new change of variables for efficient BRDF representation", EGWR 1998.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_unit_vectors

__all__ = ["rusinkiewicz_from_directions", "directions_from_rusinkiewicz", "reflection_frame_x"]


def _dot(a: NDArray, b: NDArray) -> NDArray:
    return np.einsum("...i,...i->...", a, b)


def rusinkiewicz_from_directions(wi: ArrayLike, wo: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Rusinkiewicz angles ``(theta_h, theta_d, phi_d)`` of direction pairs, as ``measured_polarized`` computes them.

    Convention: ``wi`` is the camera side and ``wo`` the light side (Mitsuba's names in radiance
    mode); ``phi_d`` is the azimuth of ``wo`` about ``h = normalize(wi + wo)`` measured from
    ``t = b x h`` towards ``b = normalize(n x h)``, so it changes sign under ``y -> -y`` mirroring.
    The angles are computed with ``atan2``, accurate near 0 (where the plugin's float32 ``acos``
    loses digits). Where ``h = n`` (mirror configuration) ``b = (0, 1, 0)``; where ``wo = h``
    (``theta_d = 0``) ``phi_d = 0``.

    Args:
        wi: ``(..., 3)`` unit directions towards the camera, local frame (``z`` = normal).
        wo: ``(..., 3)`` unit directions towards the light; broadcast against ``wi``.

    Returns:
        ``theta_h`` in ``[0, pi]``, ``theta_d`` in ``[0, pi]`` (both ``<= pi/2`` on the upper
        hemisphere) and ``phi_d`` in ``[-pi, pi]``, radians, shape ``(...)``.

    Raises:
        ValueError: directions that are not ``(..., 3)`` unit vectors.

    Example:
        Light at 30 degrees on the -x side, camera at 30 degrees on +x (mirror configuration):

        >>> s, c = np.sin(np.pi / 6), np.cos(np.pi / 6)
        >>> [float(np.round(np.degrees(a), 9)) for a in rusinkiewicz_from_directions([s, 0, c], [-s, 0, c])]
        [0.0, 30.0, 180.0]
    """
    camera, light = np.broadcast_arrays(as_unit_vectors(wi, "wi"), as_unit_vectors(wo, "wo"))
    s = camera + light
    norm = np.linalg.norm(s, axis=-1, keepdims=True)
    h = np.where(norm > 0, s / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 1.0]))
    theta_h = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
    theta_d = np.arctan2(np.linalg.norm(np.cross(h, light), axis=-1), _dot(h, light))
    # b = normalize(n x h) = (-sin phi_h, cos phi_h, 0); phi_h = 0 where h = n.
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    b = np.stack([-np.sin(phi_h), np.cos(phi_h), np.zeros_like(phi_h)], axis=-1)
    t = np.cross(b, h)
    phi_d = np.arctan2(_dot(b, light), _dot(t, light))
    return theta_h, theta_d, phi_d


def directions_from_rusinkiewicz(
    theta_h: ArrayLike, theta_d: ArrayLike, phi_d: ArrayLike, phi_h: ArrayLike = 0.0
) -> tuple[NDArray, NDArray]:
    """Inverse of :func:`rusinkiewicz_from_directions`: the direction pair ``(wi, wo)``.

    ``h = (sin theta_h cos phi_h, sin theta_h sin phi_h, cos theta_h)``, ``b = (-sin phi_h, cos phi_h, 0)``,
    ``t = b x h``; the light side is ``wo = sin theta_d (cos phi_d t + sin phi_d b) + cos theta_d h``
    and the camera side its mirror image about ``h``, ``wi = 2 cos theta_d h - wo``. Angle
    combinations that put a direction below the horizon (e.g. ``theta_h + theta_d > pi/2`` in the
    plane of ``h``) are returned as they are (``z < 0``).

    Args:
        theta_h: half-vector angle, radians, shape ``(...)``.
        theta_d: difference angle, radians.
        phi_d: difference azimuth, radians.
        phi_h: azimuth of ``h`` about the normal, radians (isotropic tables do not depend on it).

    Returns:
        ``(wi, wo)``, unit vectors ``(..., 3)`` in the local frame.

    Example:
        Half vector at the normal, difference angle 30 degrees, light on the -x side:

        >>> wi, wo = directions_from_rusinkiewicz(0.0, np.pi / 6, np.pi)
        >>> np.round(wi, 6).tolist(), np.round(wo, 6).tolist()
        ([0.5, 0.0, 0.866025], [-0.5, 0.0, 0.866025])
    """
    th, td, pd, ph = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d, phi_h)))
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    b = np.stack([-np.sin(ph), np.cos(ph), np.zeros_like(ph)], axis=-1)
    t = np.cross(b, h)
    wo = np.sin(td)[..., None] * (np.cos(pd)[..., None] * t + np.sin(pd)[..., None] * b) + np.cos(td)[..., None] * h
    wi = 2.0 * np.cos(td)[..., None] * h - wo
    return wi, wo


def reflection_frame_x(wi: ArrayLike, wo: ArrayLike) -> NDArray[np.float64]:
    """Stokes x-axis of both beams of a table entry: ``normalize(wo x wi)``, perpendicular to the plane of reflection.

    For ``wo == wi`` the plane is undefined; the limit of ``wo`` approaching ``wi`` in the plane
    of incidence is used, ``normalize(n x wi)``, and ``(0, 1, 0)`` at normal incidence. Sign flips
    of ``x`` do not change Stokes vectors.

    Args:
        wi: ``(..., 3)`` unit directions towards the camera, local frame.
        wo: ``(..., 3)`` unit directions towards the light; broadcast against ``wi``.

    Returns:
        ``(..., 3)`` unit vectors.

    Raises:
        ValueError: directions that are not ``(..., 3)`` unit vectors.

    Example:
        Camera and light in the xz-plane: the x-axis is ``+y`` (the s-direction).

        >>> reflection_frame_x([0.6, 0.0, 0.8], [-0.6, 0.0, 0.8]).tolist()
        [0.0, 1.0, 0.0]
    """
    camera, light = np.broadcast_arrays(as_unit_vectors(wi, "wi"), as_unit_vectors(wo, "wo"))
    x = np.cross(light, camera)
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    alt = np.stack([-camera[..., 1], camera[..., 0], np.zeros_like(camera[..., 0])], axis=-1)
    alt_norm = np.linalg.norm(alt, axis=-1, keepdims=True)
    alt = np.where(alt_norm > 1e-12, alt / np.where(alt_norm > 0, alt_norm, 1.0), np.array([0.0, 1.0, 0.0]))
    return np.where(norm > 1e-12, x / np.where(norm > 0, norm, 1.0), alt)
