"""Calibration of the display's emission profile and tone response from captures of the white standard.

The white target (:mod:`pbrdf.sensor.calibration`) is a Lambertian plane facing the camera at
``distance_m``, lit by one display primary at a commanded ``level``. Its radiance is ``albedo / pi``
times the display's irradiance there (:func:`white_radiance`: Lambert's polygons with the
``cos^p`` emission profile, the primary's tone response at the level). Two ratios of such captures
cancel everything else the camera does (cross-talk, vignetting, analyzers, radiometric scale):

* **Tone response**: the same primary at a level ``v < 1`` and at full level, same pose: their
  dark-subtracted frames, summed over the pixels valid in both, differ by exactly ``v ** gamma_r``.
  ``gamma_r`` is the least-squares slope of ``ln ratio`` on ``ln v`` through the origin.
* **Emission profile**: the same primary at full level at a second distance: pixel by pixel the
  ratio of the two frames is ``E_p(d2) / E_p(d1)`` (the vignetting and cross-talk of a pixel are the
  same in both), and that ratio depends on ``p``: closer, the display is seen at larger emission
  angles. Block sums of the ratio over the frame are fitted for ``p`` by bounded scalar least
  squares. The distances must be known well: a relative error ``e`` in one of them moves the
  inverse-square part of the ratio by about ``2 e`` (docs/calibration.md).

Without such captures the field keeps the value of the capture's rig and the report says so.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RectBivariateSpline
from scipy.optimize import minimize_scalar

from pbrdf.sensor.display_response import PROFILE_RANGES, emission_profile, tone_response
from pbrdf.sensor.irradiance import irradiance_vectors, profile_terms
from pbrdf.sensor.patches import constant_patches
from pbrdf.sensor.projection import pinhole_intrinsics, transform_points

if TYPE_CHECKING:
    from pbrdf.sensor.rig import Rig

#: A :class:`pbrdf.sensor.calibration.Target` (not imported: that module imports this one).
_Target = Any

__all__ = ["PROFILE_BLOCKS", "WHITE_GRID", "white_radiance", "target_intrinsics", "split_whites", "display_response"]

#: Most blocks per side of the frame in the profile fit (their sums are the fitted samples).
PROFILE_BLOCKS = 16
#: Fewest blocks (over all second-distance targets) the profile fit accepts.
MIN_PROFILE_BLOCKS = 8
#: Rays per side at which :func:`white_radiance` evaluates a larger separable ray grid exactly; the rest
#: is interpolated by a bicubic spline (the target's radiance is smooth over the frame).
WHITE_GRID = 12
_CHANNELS = ("R", "G", "B")


def white_radiance(
    rig: Rig, rays: NDArray, distance_m: float, albedo: float, *, channel: int = 0, level: float = 1.0
) -> NDArray:
    """Radiance of a Lambertian target lit by one display primary over the whole area, seen along camera rays.

    The target is the plane ``z = -distance_m`` of the camera frame, facing the camera; a ray
    meets it at ``distance_m * ray``, whose radiance is ``albedo / pi`` times the irradiance of the
    whole active area at ``rig.display.radiance`` times the primary's tone response at ``level``
    (Lambert's polygon formula with the display's emission profile; no occlusion by the camera).

    Args:
        rig: display geometry, radiance, profile and tone response; camera pose.
        rays: ``(..., 3)`` camera-frame rays scaled to ``z = -1``
            (:func:`pbrdf.sensor.projection.pixel_rays`).
        distance_m: the plane's distance in m.
        albedo: Lambertian reflectance in ``[0, 1]``.
        channel: the primary shown (0, 1, 2): whose tone response applies.
        level: the commanded level in ``[0, 1]``.

    Returns:
        ``(...)`` float64 radiance in the renderer's units. A grid of rays ``(H, W, 3)`` whose ``x``
        depends on the column only and ``y`` on the row only (a pinhole's pixel grid, or rows and
        columns of it) with more than ``WHITE_GRID^2`` rays is evaluated at ``WHITE_GRID`` values of
        each and interpolated by a bicubic spline (relative error under 1e-4, tested).

    Example:
        Straight ahead of a small display far away, ``E ~ L A / d^2``:

        >>> from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig
        >>> rig = Rig(DisplaySpec(width=0.01, height=0.01, center=(0.0, 0.0, 0.0), radiance=2.0), CameraSpec())
        >>> l = white_radiance(rig, np.array([0.0, 0.0, -1.0]), 1.0, math.pi)
        >>> round(float(l) / 2e-4, 4)
        1.0
    """
    r = np.asarray(rays, dtype=np.float64)
    if r.ndim == 3 and r.shape[0] * r.shape[1] > WHITE_GRID**2 and min(r.shape[:2]) > 1 and _separable(r):
        ys, xs = r[:, 0, 1], r[0, :, 0]
        gy, gx = (np.linspace(v.min(), v.max(), WHITE_GRID) for v in (ys, xs))
        coarse_rays = np.stack([*np.meshgrid(gx, gy), -np.ones((WHITE_GRID, WHITE_GRID))], axis=-1)
        coarse = white_radiance(rig, coarse_rays, distance_m, albedo, channel=channel, level=level)
        yy, xx = np.meshgrid(ys, xs, indexing="ij")
        return RectBivariateSpline(gy, gx, coarse, kx=3, ky=3).ev(yy, xx)
    points = distance_m * r.reshape(-1, 3)
    display = dataclasses.replace(rig.display, pattern="white")
    white = constant_patches(display)  # radiance: display.radiance in every channel
    verts = transform_points(rig.camera.world_to_camera(), white.vertices.reshape(-1, 3)).reshape(white.vertices.shape)
    normals = np.broadcast_to(np.array([0.0, 0.0, 1.0]), points.shape)
    emitted = float(tone_response(np.full(3, float(level)), display.tone_gamma)[channel])
    phi = irradiance_vectors(
        verts, white.radiance[:, :1] * emitted, points, normals, exponent=display.emission_exponent
    )
    e = np.einsum("pk,pk->p", phi[:, 0], normals)
    return (albedo / math.pi) * e.reshape(r.shape[:-1])


def _separable(rays: NDArray) -> bool:
    """Whether a ray grid ``(H, W, 3)`` has ``x`` per column, ``y`` per row and ``z = -1``."""
    return bool(
        np.all(rays[..., 2] == -1.0)
        and np.all(rays[..., 0] == rays[:1, :, 0])
        and np.all(rays[..., 1] == rays[:, :1, 1])
    )


def target_intrinsics(target: _Target) -> NDArray:
    """``K (3, 3)`` of a target's raw grid: its own, else the rig camera's focal length, centred."""
    if target.intrinsics is not None:
        return np.asarray(target.intrinsics, dtype=np.float64)
    h, w = target.raws.shape[1:]
    return pinhole_intrinsics(target.rig.camera.focal_length_px, w, h)


def split_whites(whites: list[_Target]) -> tuple[list[_Target], list[_Target], list[_Target]]:
    """The white targets as ``(base, second distance, partial level)``.

    ``base``: the full-level targets at the distance with the most white targets, then the farthest
    (the cross-talk and vignetting fit, which needs all three primaries there); ``second distance``:
    full-level targets at other distances (the profile); ``partial level``: targets below full level,
    which must be at the base distance (the tone response).

    Raises:
        ValueError: two targets of one primary at the same distance and level, or a partial-level
            target away from the base distance.
    """
    seen: dict[tuple, _Target] = {}
    for t in whites:
        key = (t.display_channel, t.distance_m, t.level)
        if key in seen:
            raise ValueError(
                f"two white targets for display channel {_CHANNELS[t.display_channel]} at {t.distance_m} m and level "
                f"{t.level:g}: {seen[key].name} and {t.name}"
            )
        seen[key] = t
    full = [t for t in whites if t.level == 1.0]
    distances = sorted({t.distance_m for t in full if t.distance_m is not None})
    d0 = max(distances, key=lambda d: (sum(t.distance_m == d for t in whites), d)) if distances else None
    base = [t for t in full if t.distance_m in (d0, None)]  # a missing distance is refused by the white fit
    partial = [t for t in whites if t.level < 1.0]
    for t in partial:
        if t.distance_m != d0:
            raise ValueError(
                f"{t.name}: a white target below full level (level {t.level:g}) must be at the full-level targets' "
                f"distance {d0} m, got {t.distance_m} m"
            )
    return base, [t for t in full if t not in base], partial


def _block_sums(merged: NDArray, ok: NDArray, block: int) -> tuple[NDArray, NDArray]:
    """Sums of ``merged`` over ``ok`` pixels and the counts, per ``block x block`` tile ``(h // block, w // block)``."""
    h, w = (s // block * block for s in merged.shape)

    def tiles(x: NDArray) -> NDArray:
        return x[:h, :w].reshape(h // block, block, w // block, block).sum(axis=(1, 3))

    return tiles(np.where(ok, merged, 0.0).astype(np.float64)), tiles(ok.astype(np.float64))


def _profile_samples(near: _Target, far: _Target, merge: Callable) -> tuple[NDArray, NDArray]:
    """Measured ``far / near`` ratios per block ``(n,)`` (albedos divided out), the blocks' centre rays ``(n, 3)``."""
    (mn, vn), (mf, vf) = merge(near), merge(far)
    if mn.shape != mf.shape:
        raise ValueError(
            f"{far.name}: its frame size differs from {near.name}'s (the profile compares them pixel by pixel)"
        )
    h, w = mn.shape
    block = 4 * max(1, math.ceil(max(h, w) / (4 * PROFILE_BLOCKS)))
    ok = vn & vf
    sn, count = _block_sums(mn, ok, block)
    sf, _ = _block_sums(mf, ok, block)
    keep = (count >= block * block / 2) & (sn > 0) & (sf > 0)
    k = target_intrinsics(near)
    v, u = (np.mgrid[0 : sn.shape[0], 0 : sn.shape[1]] + 0.5) * block
    rays = np.stack([(u - k[0, 2]) / k[0, 0], -(v - k[1, 2]) / k[1, 1], -np.ones_like(u)], axis=-1)
    return (sf / np.maximum(sn, 1e-300) * (near.albedo / far.albedo))[keep], rays[keep]


def _camera_terms(rig: Rig, rays: NDArray, distance_m: float) -> tuple[NDArray, NDArray]:
    """:func:`pbrdf.sensor.irradiance.profile_terms` of the whole display at the white plane's points along ``rays``."""
    white = constant_patches(dataclasses.replace(rig.display, pattern="white"))
    verts = transform_points(rig.camera.world_to_camera(), white.vertices.reshape(-1, 3)).reshape(white.vertices.shape)
    points = distance_m * rays.reshape(-1, 3)
    return profile_terms(verts, points, np.broadcast_to(np.array([0.0, 0.0, 1.0]), points.shape))


def _fit_exponent(samples: list[tuple[NDArray, NDArray, Rig, float, float]]) -> tuple[float, float]:
    """``p`` and its standard error from ``(ratio, rays, rig, d_near, d_far)`` samples (module docs)."""
    terms = [(_camera_terms(rig, rays, d1), _camera_terms(rig, rays, d2)) for _, rays, rig, d1, d2 in samples]

    def residual(p: float) -> NDArray:
        out = []
        for (ratio, *_), ((e1, c1), (e2, c2)) in zip(samples, terms, strict=True):
            model = (e2 * emission_profile(c2, p)).sum(-1) / np.maximum((e1 * emission_profile(c1, p)).sum(-1), 1e-300)
            out.append(ratio / model - 1.0)
        return np.concatenate(out)

    lo, hi = PROFILE_RANGES["emission_exponent"]
    p = float(minimize_scalar(lambda x: float(np.sum(residual(x) ** 2)), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-4}).x)  # fmt: skip
    step = 0.05
    slope = (residual(min(p + step, hi)) - residual(max(p - step, lo))) / (min(p + step, hi) - max(p - step, lo))
    res = residual(p)
    se = math.sqrt(float(np.sum(res**2)) / max(len(res) - 1, 1) / max(float(np.sum(slope**2)), 1e-300))
    return (0.0 if p < 1e-3 else p), se


def _fit_gamma(base: dict[int, _Target], partial: list[_Target], merge: Callable) -> dict[int, float]:
    """``gamma_r`` per primary with partial-level targets (module docs)."""
    logs: dict[int, list[tuple[float, float]]] = {}
    for t in partial:
        if not 0.0 < t.level < 1.0:
            raise ValueError(f"{t.name}: level must be in (0, 1]; got {t.level:g}")
        full = base.get(t.display_channel)
        if full is None:
            continue  # the white fit names the missing full-level target
        (mp, vp), (mf, vf) = merge(t), merge(full)
        ok = vp & vf
        ratio = float(mp[ok].sum(dtype=np.float64) / mf[ok].sum(dtype=np.float64)) * (full.albedo / t.albedo)
        if not ratio > 0.0:
            raise ValueError(
                f"{t.name}: no light above the dark frame at level {t.level:g}: the tone response is not measurable"
            )
        logs.setdefault(t.display_channel, []).append((math.log(t.level), math.log(ratio)))
    return {c: sum(a * b for a, b in v) / sum(a * a for a, _ in v) for c, v in logs.items()}


def display_response(
    base: list[_Target],
    second: list[_Target],
    partial: list[_Target],
    merge: Callable[[_Target], tuple[NDArray, NDArray]],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Estimate the emission profile and tone response (module docs).

    Args:
        base: the full-level white targets at the base distance (:func:`split_whites`).
        second: the full-level white targets at other distances.
        partial: the white targets below full level.
        merge: a target's dark-subtracted HDR merge and validity ``((H, W), (H, W))``.

    Returns:
        ``(fields, report)``: the display fields ``emission_exponent`` and ``tone_gamma`` (the
        rig's own where not measured) and a report entry per field.
    """
    if not base:
        return {}, {}  # the white fit names what is missing
    by_channel = {t.display_channel: t for t in base}
    display = base[0].rig.display
    report: dict[str, Any] = {}
    pairs = [(by_channel[t.display_channel], t) for t in second if t.display_channel in by_channel]
    if pairs:
        samples = [(*_profile_samples(n, f, merge), n.rig, n.distance_m, f.distance_m) for n, f in pairs]
        if sum(len(s[0]) for s in samples) < MIN_PROFILE_BLOCKS:
            names = ", ".join(f.name for _, f in pairs)
            raise ValueError(f"{names}: too few pixels valid at both distances to measure the emission profile")
        p, se = _fit_exponent(samples)
        note = "estimated (white target at two distances)" + (", on its bound 0" if p == 0.0 else "")
        report["display.emission_exponent"] = {"value": p, "note": note, "se": se}
    else:
        p = display.emission_exponent
        report["display.emission_exponent"] = {
            "value": p,
            "note": "not measured (needs the white target at a second distance); kept",
        }
    gammas = _fit_gamma(by_channel, partial, merge)
    gamma = tuple(gammas.get(c, display.tone_gamma[c]) for c in range(3))
    for c in range(3):
        note = (
            "estimated (white target at partial levels)"
            if c in gammas
            else "not measured (needs the white target below full level); kept"
        )
        report[f"display.tone_gamma[{_CHANNELS[c]}]"] = {"value": gamma[c], "note": note}
    return {"emission_exponent": p, "tone_gamma": gamma}, report
