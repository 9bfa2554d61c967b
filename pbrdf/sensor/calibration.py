"""Self-calibration of the rig's imperfections from captures of three kinds of lab target.

The targets (``docs/calibration.md`` says why this set makes every estimated field identifiable):

* ``dark``: the display off, the camera as for the other captures. The mean raw level per colour
  channel against exposure time is a straight line: its slope is the unpolarized ambient light
  (``ambient``, after the lens falloff and the analyzers' transmission are divided out), its
  intercept the sensor offset. Its frames are also the dark frames of the other targets that
  carry none of their own.
* ``white`` (one per display channel ``display_channel`` R, G, B): a flat Lambertian reflectance
  standard of known ``albedo``, facing the camera at ``distance_m``, lit by the display showing
  that one primary over its whole area. Its radiance is ``albedo / pi`` times the display's
  irradiance (Lambert's polygon formula, :mod:`pbrdf.sensor.irradiance`), so each camera channel
  measures ``V(p) M[c, r]`` per pixel: the cross-talk column ``r`` and the vignetting ``V``.
  Optionally the same at a second distance (the display's emission profile) and at commanded
  ``level`` s below 1 (its tone response): :mod:`pbrdf.sensor.calibration_display`.
* ``polarizer`` (at least three angles ``polarizer_angle_deg``): the camera faces the display
  (all white) through a linear polarizer at a known angle in the analyzers' frame. The light is
  fully linearly polarized at that angle whatever the display does, so the four analyzers of each
  channel give the QWP fast-axis angle and retardance and the analyzer extinction (a small
  nonlinear least-squares fit, the per-capture brightness solved in closed form); the brightness
  against the polarizer angle, ``1 + DoP cos 2 (phi - psi)``, gives the display's degree and
  angle of polarization.

Not identifiable from these targets, left as the captures give them: ``analyzer_transmittance``
and the radiometric scale (they multiply ``electrons_per_unit``; the cross-talk's diagonal carries
any error of that scale), the QWP's fast-versus-slow axis (a linear input cannot tell ``theta``
from ``theta + 90 deg`` with ``-delta``: the fit keeps the fast axis within 45 degrees of the
nominal 0), and the split of the falloff between the cos^4 term and the polynomial (only their
product is seen: the focal length is taken from the intrinsics or left out, whichever fits better).

Every estimate passes the field checks of :class:`~pbrdf.sensor.camera.CameraModel` and
:class:`~pbrdf.sensor.rig.DisplaySpec` (one home): a non-physical result is refused with one line
naming the field. Estimates within noise of a bound (a slightly negative ambient or cross-talk
entry, a DoP just above 1) are put on the bound.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from pbrdf.polar import mueller
from pbrdf.sensor.calibration_display import display_response, split_whites, target_intrinsics, white_radiance
from pbrdf.sensor.camera import ANGLES_DEG, CameraModel, mosaic_indices
from pbrdf.sensor.decode import hdr_merge, subtract_dark
from pbrdf.sensor.imperfections import vignetting_map
from pbrdf.sensor.projection import pixel_rays
from pbrdf.sensor.rig import Rig

__all__ = [
    "TARGET_KINDS",
    "CHANNELS",
    "MIN_SIGNAL_DN",
    "MIN_VALID_FRACTION",
    "Target",
    "Calibration",
    "calibrate",
    "rig_errors",
]

#: The target kinds a calibration reads (the ``target`` field of each capture).
TARGET_KINDS = ("dark", "white", "polarizer")
#: Display / camera channel names, in the order of the colour axis.
CHANNELS = ("R", "G", "B")
#: Least signal (DN above the dark frame, longest unsaturated exposure) of a lit target.
MIN_SIGNAL_DN = 20.0
#: Least fraction of a target's pixels measured unsaturated in some exposure.
MIN_VALID_FRACTION = 0.5
#: Most pixel rows (and columns) of a white target used in the fit: larger frames are sampled.
FIT_GRID = 128
#: How far (in standard errors) an estimate may fall outside its bound and still be put on it.
NOISE_SIGMAS = 5.0


@dataclass(frozen=True)
class Target:
    """One calibration capture: its kind, raw bracket and what the lab knows about it.

    Attributes:
        name: for messages (the capture folder's name).
        kind: one of :data:`TARGET_KINDS`.
        raws: ``(E, H, W)`` raw frames.
        model: the camera model the capture was taken with (sensor, exposures, pattern offset;
            its imperfection fields are not used).
        dark: ``(E, H, W)`` dark frames of the same bracket, or None (the ``dark`` target's are used).
        rig: the rig geometry (display pose and size, camera pose).
        display_channel: ``white``: the display primary shown (0, 1, 2).
        albedo: ``white``: the target's Lambertian reflectance.
        distance_m: ``white``: the target plane's distance along the viewing axis in m.
        level: ``white``: the commanded level of the primary, in ``(0, 1]`` (1: full on).
        intrinsics: ``K (3, 3)`` of the raw grid, or None (the rig camera's, centred).
        polarizer_angle: ``polarizer``: the polarizer's transmission axis in radians, in the
            analyzers' frame (0 = the 0-degree analyzer, increasing toward the 45-degree one).
    """

    name: str
    kind: str
    raws: NDArray
    model: CameraModel
    dark: NDArray | None = None
    rig: Rig = field(default_factory=Rig)
    display_channel: int | None = None
    albedo: float = 0.99
    distance_m: float | None = None
    level: float = 1.0
    intrinsics: NDArray | None = None
    polarizer_angle: float | None = None


@dataclass(frozen=True)
class Calibration:
    """The estimated rig and how each field was obtained.

    Attributes:
        rig: the calibrated rig (its ``camera.model`` is the ``camera_model`` a capture takes).
        report: per field, the estimate and a note (``"estimated"``, ``"on its bound"``, or why not).
        offset_dn: per camera channel, the sensor offset the dark target shows (DN; the decoder
            subtracts dark frames, so it is reported, not written).
    """

    rig: Rig
    report: dict[str, Any]
    offset_dn: tuple[float, float, float]


# ---------------------------------------------------------------------------- the targets' physics


def _analyzer_rows(theta: float, delta: NDArray, leak: NDArray, transmittance: float) -> NDArray:
    """``(3, 4, 4)`` first rows of analyzer @ QWP per channel, extinction as ``leak = 1 / ER``."""
    alpha = np.deg2rad(np.asarray(ANGLES_DEG, dtype=np.float64))
    rows = np.empty((3, 4, 4))
    for c in range(3):
        pol = 0.5 * transmittance * np.stack(
            [np.full(4, 1.0 + leak[c]), (1.0 - leak[c]) * np.cos(2 * alpha), (1.0 - leak[c]) * np.sin(2 * alpha),
             np.zeros(4)], axis=-1,
        )  # fmt: skip
        rows[c] = pol @ mueller.retarder(delta[c], theta)
    return rows


# ---------------------------------------------------------------------------- per-capture measurements


def _dark_frames(target: Target, dark: Target | None) -> NDArray:
    """The dark frames for ``target``: its own, else the dark target's (same bracket and size)."""
    if target.dark is not None:
        return target.dark
    if dark is None:
        raise ValueError(f"{target.name}: missing dark frame: no 'dark' target and no dark_files of its own")
    if dark.model.exposures != target.model.exposures or dark.raws.shape != target.raws.shape:
        raise ValueError(
            f"{target.name}: its exposures or frame size differ from the dark target {dark.name}'s; "
            "give it dark_files of its own"
        )
    return dark.raws


def _merged(target: Target, dark: Target | None, what: str, *, lit: bool = True) -> tuple[NDArray, NDArray]:
    """Dark-subtracted HDR merge ``(H, W)`` and its validity; refuses saturated (and, if ``lit``, too dark) targets."""
    model = target.model
    raws = subtract_dark(target.raws, _dark_frames(target, dark), model.sensor)
    merged, valid = hdr_merge(raws, model.exposures, model.sensor, pattern_offset=model.pattern_offset)
    color, _ = mosaic_indices(model.pattern_offset)
    h, w = valid.shape
    fraction = np.bincount(np.tile(color, (h // 4, w // 4)).ravel(), valid.ravel(), 3) / (h * w / np.array([4, 2, 4]))
    if fraction.min() < MIN_VALID_FRACTION:
        c = int(np.argmin(fraction))
        raise ValueError(
            f"{target.name}: {what} saturated in every exposure at {100 * (1 - fraction[c]):.0f} % of the "
            f"{CHANNELS[c]} pixels (shorten the exposures)"
        )
    if lit:  # the brightest colour channel (a primary alone lights one channel only)
        level = _lattice_means(merged, valid, model.pattern_offset).mean(axis=-1).max()
        _check_visible(target.name, what, float(level), model)
    return merged, valid


def _check_visible(name: str, what: str, level: float, model: CameraModel) -> None:
    """Refuse a lit target whose level (radiance units) gives under :data:`MIN_SIGNAL_DN` at the longest exposure."""
    longest = max(model.exposures)
    dn = level * model.sensor.dn_per_unit_second * longest
    if not dn >= MIN_SIGNAL_DN:
        raise ValueError(
            f"{name}: {what} not visible: {dn:.3g} DN above the dark frame at {longest:g} s "
            f"(needs {MIN_SIGNAL_DN:g}); target not found or display off?"
        )


def _lattice_means(merged: NDArray, valid: NDArray, pattern_offset: tuple[int, int]) -> NDArray:
    """Mean intensity ``(3, 4)`` per colour and analyzer angle over the valid pixels."""
    color, angle = mosaic_indices(pattern_offset)
    total, count = np.zeros((3, 4)), np.zeros((3, 4))
    for i in range(4):
        for j in range(4):
            v = valid[i::4, j::4]
            total[color[i, j], angle[i, j]] += float(merged[i::4, j::4][v].sum(dtype=np.float64))
            count[color[i, j], angle[i, j]] += float(v.sum())
    return total / np.maximum(count, 1.0)


# ---------------------------------------------------------------------------- polarizer: QWP, analyzers, display


def _polarizer_fit(intensity: NDArray, phi: NDArray, transmittance: float) -> tuple[float, NDArray, NDArray]:
    """QWP angle, retardance ``(3,)`` and leak ``1/ER`` ``(3,)`` from ``intensity (K, 3, 4)`` at angles ``phi (K,)``."""
    stokes = np.stack([np.ones_like(phi), np.cos(2 * phi), np.sin(2 * phi), np.zeros_like(phi)], axis=-1)  # (K, 4)
    # One scale per channel (its brightest capture): a capture near the crossed position weighs little.
    scale = intensity.mean(axis=-1, keepdims=True).max(axis=0, keepdims=True)

    def residual(p: NDArray) -> NDArray:
        rows = _analyzer_rows(p[0], p[1:4], p[4:7], transmittance)  # (3, 4, 4)
        pred = np.einsum("cak,nk->nca", rows, stokes)  # (K, 3, 4)
        gain = (pred * intensity).sum(-1, keepdims=True) / np.maximum((pred * pred).sum(-1, keepdims=True), 1e-300)
        return ((gain * pred - intensity) / scale).ravel()

    p0 = np.array([0.0, *[math.pi / 2] * 3, *[0.01] * 3])
    lo = np.array([-math.pi / 4, *[1e-3] * 3, *[0.0] * 3])
    hi = np.array([math.pi / 4, *[math.pi - 1e-3] * 3, *[0.999] * 3])
    fit = least_squares(residual, p0, bounds=(lo, hi), x_scale=np.array([0.1, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01]))
    return float(fit.x[0]), fit.x[1:4], fit.x[4:7]


def _display_fit(brightness: NDArray, phi: NDArray, se: NDArray) -> tuple[float, float, float]:
    """Display DoP, angle and DoP standard error from the brightness ``(K,)`` (standard errors ``se``) at ``phi``.

    ``b = A + B cos 2 phi + C sin 2 phi`` by least squares; ``DoP = sqrt(B^2 + C^2) / A``,
    ``psi = atan2(C, B) / 2`` in ``[0, pi)``. The standard error comes from the measurement noise
    alone (not from the misfit: a display that drifted between captures must not widen it).
    """
    design = np.stack([np.ones_like(phi), np.cos(2 * phi), np.sin(2 * phi)], axis=-1)
    coef, *_ = np.linalg.lstsq(design, brightness, rcond=None)
    a, b, c = coef
    dop = math.hypot(b, c) / a
    psi = (0.5 * math.atan2(c, b)) % math.pi
    return dop, psi, math.sqrt(2.0 / len(phi) * float(np.mean(se**2))) / a


def _mean_se(merged: NDArray, valid: NDArray) -> float:
    """Standard error of the frame's mean from the pixel noise (differences along each lattice's rows)."""
    d = merged[:, 4:] - merged[:, :-4]
    ok = valid[:, 4:] & valid[:, :-4]
    n = max(int(ok.sum()), 1)
    return math.sqrt(float(np.sum(d[ok].astype(np.float64) ** 2)) / 2.0 / n / n)


def _polarizers(targets: list[Target], dark: Target | None) -> dict[str, Any]:
    if not targets:
        raise ValueError("missing polarizer targets: need the display seen through a polarizer at >= 3 angles")
    phi = np.array([t.polarizer_angle for t in targets], dtype=np.float64)
    distinct = np.unique(np.round(np.rad2deg(phi) % 180.0, 3))
    if distinct.size < 3:
        raise ValueError(f"need polarizer targets at >= 3 distinct angles (mod 180 deg); got {distinct.tolist()} deg")
    model = targets[0].model
    merged = [_merged(t, dark, "display", lit=False) for t in targets]
    # (K, 3, 4); a capture near the crossed position may be dark, the brightest must not be
    intensity = np.stack([_lattice_means(*mv, t.model.pattern_offset) for mv, t in zip(merged, targets, strict=True)])
    mean_se = np.array([_mean_se(*mv) for mv in merged])  # of each capture's mean intensity
    brightest = int(np.argmax(intensity.sum(axis=(1, 2))))
    _check_visible(targets[brightest].name, "display (through the polarizer)", float(intensity[brightest].max()), model)
    theta, delta, leak = _polarizer_fit(intensity, phi, model.analyzer_transmittance)
    # Brightness behind the polarizer per capture: s0 of the fitted model, summed over channels.
    rows = _analyzer_rows(theta, delta, leak, model.analyzer_transmittance)
    stokes = np.stack([np.ones_like(phi), np.cos(2 * phi), np.sin(2 * phi), np.zeros_like(phi)], axis=-1)
    pred = np.einsum("cak,nk->nca", rows, stokes)
    gain = (pred * intensity).sum(-1) / (pred * pred).sum(-1)  # (K, 3)
    brightness = gain.sum(axis=-1)
    per_mean = brightness.sum() / intensity.mean(axis=(1, 2)).sum()  # brightness per unit of mean intensity
    dop, psi, dop_se = _display_fit(brightness, phi, mean_se * per_mean)
    return {"qwp_angle": theta, "qwp_retardance": delta, "leak": leak, "dop": dop, "psi": psi, "dop_se": dop_se}


# ---------------------------------------------------------------------------- white: cross-talk and vignetting


def _sample_rows(n: int) -> NDArray[np.intp]:
    """Raw rows (or columns) sampled for the fit: every one up to :data:`FIT_GRID`, else whole 4-pixel tiles."""
    tiles = n // 4
    keep = np.unique(np.linspace(0, tiles - 1, min(tiles, FIT_GRID // 4)).round().astype(np.intp))
    return (4 * keep[:, None] + np.arange(4)[None]).ravel()


def _white_samples(target: Target, dark: Target | None, leak: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """``(q, colour, rho2, d2)`` at the sampled valid pixels: measured s0 over ``albedo / pi E``."""
    merged, valid = _merged(target, dark, "white target")
    h, w = merged.shape
    rows, cols = _sample_rows(h), _sample_rows(w)
    if target.distance_m is None:
        raise ValueError(f"{target.name}: a white target needs distance_m (its distance along the viewing axis)")
    rays = pixel_rays(target_intrinsics(target), h, w)[np.ix_(rows, cols)]
    expected = white_radiance(target.rig, rays, target.distance_m, target.albedo)
    color, _ = mosaic_indices(target.model.pattern_offset)
    colour = color[np.ix_(rows % 4, cols % 4)]
    a0 = 0.5 * target.model.analyzer_transmittance * (1.0 + leak[colour])
    q = merged[np.ix_(rows, cols)] / a0 / expected
    y = rows[:, None] + 0.5 - h / 2
    x = cols[None, :] + 0.5 - w / 2
    d2 = y**2 + x**2
    rho2 = d2 / ((h / 2) ** 2 + (w / 2) ** 2)
    ok = valid[np.ix_(rows, cols)] & (expected > 0)
    return q[ok], colour[ok], rho2[ok], d2[ok]


def _vignetting_fit(samples: list[tuple], focal: float) -> tuple[NDArray, NDArray, float, NDArray]:
    """Cross-talk ``(3, 3)``, polynomial ``(3,)``, relative RMS residual and the entries' standard errors ``(3, 3)``.

    The cos^4 term has the focal length ``focal`` (px; ``inf``: none).

    ``q[c, r](p) = M[c, r] cos^4(p) (1 + k1 rho^2 + k2 rho^4 + k3 rho^6)``: least squares over
    ``k`` with ``M`` solved in closed form for each ``k`` (variable projection).
    """
    y = np.concatenate([s[0] for s in samples])
    group = np.concatenate([3 * s[1] + r for r, s in enumerate(samples)])  # 3 c + r
    rho2 = np.concatenate([s[2] for s in samples])
    cos4 = np.ones_like(y)
    if math.isfinite(focal):
        cos4 = (focal**2 / (focal**2 + np.concatenate([s[3] for s in samples]))) ** 2
        y = y / cos4
    powers = np.stack([rho2, rho2**2, rho2**3], axis=-1)

    def scale(k: NDArray) -> tuple[NDArray, NDArray]:
        poly = 1.0 + powers @ k
        m = np.bincount(group, y * poly, 9) / np.maximum(np.bincount(group, poly * poly, 9), 1e-300)
        return m, poly

    def residual(k: NDArray) -> NDArray:
        m, poly = scale(k)
        return y - m[group] * poly

    k = least_squares(residual, np.zeros(3), x_scale=0.1).x
    m, poly = scale(k)
    res = residual(k)
    # In the measured ratio's own units (not divided by cos^4), so the two falloff models compare on equal terms.
    rms = float(np.sqrt(np.mean((res * cos4) ** 2) / np.mean((y * cos4) ** 2)))
    # Standard error of each entry: its samples' residual spread over the root of their count.
    n = np.maximum(np.bincount(group, minlength=9), 1)
    mean_poly2 = np.maximum(np.bincount(group, poly**2, 9) / n, 1e-300)
    se = np.sqrt(np.bincount(group, res**2, 9) / n / n / mean_poly2)
    return m.reshape(3, 3), k, rms, se.reshape(3, 3)


def _whites(targets: list[Target], dark: Target | None, leak: NDArray) -> dict[str, Any]:
    by_channel: dict[int, Target] = {}
    for t in targets:
        if t.display_channel in by_channel:
            raise ValueError(
                f"two white targets for display channel {CHANNELS[t.display_channel]}: "
                f"{by_channel[t.display_channel].name} and {t.name}"
            )
        by_channel[t.display_channel] = t
    for r in range(3):
        if r not in by_channel:
            raise ValueError(
                f"missing white target for display channel {CHANNELS[r]} (need one white capture per display "
                "channel R, G, B, the display showing that primary alone)"
            )
    samples = [_white_samples(by_channel[r], dark, leak) for r in range(3)]
    focal = float(target_intrinsics(by_channel[0])[0, 0])
    fits = [(_vignetting_fit(samples, f), f) for f in (math.inf, focal)]
    (m, poly, rms, se), f = min(fits, key=lambda x: x[0][2])
    return {"crosstalk": m, "vignetting_poly": poly, "vignetting_focal_px": f, "rms": rms, "se": se}


# ---------------------------------------------------------------------------- dark: ambient and offset


def _ambient(dark: Target, leak: NDArray, focal: float, poly: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Ambient ``(3,)``, its standard error ``(3,)`` and the offset in DN ``(3,)`` from the dark target."""
    model = dark.model
    t = np.asarray(model.exposures)
    h, w = dark.raws.shape[1:]
    color, _ = mosaic_indices(model.pattern_offset)
    colour = np.tile(color, (h // 4, w // 4))
    vmap = vignetting_map((h, w), focal, tuple(poly))
    ambient, se, offset = np.zeros(3), np.zeros(3), np.zeros(3)
    white = model.sensor.saturation * model.sensor.white_level
    for c in range(3):
        sel = colour == c
        frames = dark.raws[:, sel].astype(np.float64)  # (E, N)
        ok = frames.max(axis=1) < white
        if not ok.any():
            raise ValueError(f"{dark.name}: dark target saturated in every exposure (is the display off?)")
        mean = frames[ok].mean(axis=1)
        err = frames[ok].std(axis=1) / math.sqrt(frames.shape[1]) + 1e-3
        tt = t[ok]
        if np.unique(tt).size >= 2:
            design = np.stack([np.ones_like(tt), tt], axis=-1) / err[:, None]
            coef, *_ = np.linalg.lstsq(design, mean / err, rcond=None)
            cov = np.linalg.inv(design.T @ design)
            off, slope, slope_se = coef[0], coef[1], math.sqrt(cov[1, 1])
        else:
            off = model.sensor.black_level
            slope, slope_se = (mean[0] - off) / tt[0], err[0] / tt[0]
        per_unit = model.sensor.dn_per_unit_second * 0.5 * model.analyzer_transmittance * (1.0 + leak[c])
        per_unit *= float(vmap[sel].mean())
        ambient[c], se[c], offset[c] = slope / per_unit, slope_se / per_unit, off
    return ambient, se, offset


# ---------------------------------------------------------------------------- the whole calibration


def _on_bound(value: float, lo: float, hi: float, se: float, name: str) -> tuple[float, str]:
    """``value`` put on ``[lo, hi]`` when within :data:`NOISE_SIGMAS` standard errors of it, else as it is."""
    if lo <= value <= hi:
        return value, "estimated"
    bound = lo if value < lo else hi
    if abs(value - bound) <= NOISE_SIGMAS * se:
        return bound, f"on its bound (estimate {value:.4g} within noise)"
    return value, f"outside [{lo:g}, {hi:g}] ({value:.4g}): {name}"


def _split(targets: list[Target]) -> tuple[Target | None, list[Target], list[Target]]:
    darks = [t for t in targets if t.kind == "dark"]
    for t in targets:
        if t.kind not in TARGET_KINDS:
            raise ValueError(f"{t.name}: unknown target kind {t.kind!r}; valid: {list(TARGET_KINDS)}")
    if len(darks) > 1:
        raise ValueError(f"more than one dark target: {[t.name for t in darks]}")
    if not darks:
        raise ValueError("missing dark frame: no 'dark' target (a capture with the display off)")
    return darks[0], [t for t in targets if t.kind == "white"], [t for t in targets if t.kind == "polarizer"]


def calibrate(targets: list[Target]) -> Calibration:
    """Estimate the rig's imperfection fields from calibration targets (module docs).

    Args:
        targets: one ``dark``, three ``white`` (R, G, B) and at least three ``polarizer`` targets.

    Returns:
        :class:`Calibration`: the rig (geometry and sensor of the white targets, every estimated
        field replaced) and a report per field.

    Raises:
        ValueError: one line naming what is missing or unusable, or the field whose estimate is
            not physical.
    """
    if not targets:
        raise ValueError("no calibration targets: need a dark, three white (R, G, B) and >= 3 polarizer captures")
    dark, whites, polarizers = _split(targets)
    pol = _polarizers(polarizers, dark)
    leak = pol["leak"]
    whites, second, partial = split_whites(whites)
    shown, shown_report = display_response(whites, second, partial, lambda t: _merged(t, dark, "white target"))

    # The white fit's expected radiance with the estimated profile.
    def shown_rig(rig: Rig) -> Rig:
        return dataclasses.replace(rig, display=dataclasses.replace(rig.display, **shown))

    whites = [dataclasses.replace(t, rig=shown_rig(t.rig)) for t in whites]
    white = _whites(whites, dark, leak)
    ambient, ambient_se, offset = _ambient(dark, leak, white["vignetting_focal_px"], white["vignetting_poly"])
    report: dict[str, Any] = {}
    amb = []
    for c in range(3):
        v, note = _on_bound(float(ambient[c]), 0.0, math.inf, float(ambient_se[c]), f"ambient[{CHANNELS[c]}]")
        amb.append(v)
        report[f"ambient[{CHANNELS[c]}]"] = {"value": v, "note": note}
    dop, note = _on_bound(pol["dop"], 0.0, 1.0, pol["dop_se"], "degree_of_polarization")
    report["display.degree_of_polarization"] = {"value": dop, "note": note}
    m, tol = white["crosstalk"], NOISE_SIGMAS * white["se"]
    m = np.where((m < 0) & (m >= -tol), 0.0, np.where((m > 1) & (m <= 1 + tol), 1.0, m))  # bounds within noise
    er = [math.inf if u <= 0 else 1.0 / u for u in leak]
    base = whites[0]
    fields = {
        "qwp_angle": pol["qwp_angle"],
        "qwp_retardance": tuple(float(d) for d in pol["qwp_retardance"]),
        "extinction_ratio": tuple(er),
        "ambient": tuple(amb),
        "crosstalk": m.tolist(),
        "vignetting_focal_px": white["vignetting_focal_px"],
        "vignetting_poly": tuple(float(k) for k in white["vignetting_poly"]),
    }
    report.update({k: {"value": v, "note": "estimated"} for k, v in fields.items() if k != "ambient"})
    report["vignetting_focal_px"]["note"] = "chosen (inf or the intrinsics' focal length, the better fit)"
    try:
        model = base.model.replace(**fields)
    except ValueError as e:
        hint = ""
        if np.any(m > 1):
            hint = " (a diagonal above 1: the display is brighter than rig.display.radiance and the sensor's scale say)"
        raise ValueError(f"calibration refused, the estimate is not physical: {e}{hint}") from None
    report["display.polarization_angle"] = {"value": pol["psi"], "note": "estimated"}
    report.update(shown_report)
    try:
        disp = dataclasses.replace(base.rig.display, degree_of_polarization=dop, polarization_angle=pol["psi"], **shown)
    except ValueError as e:
        raise ValueError(f"calibration refused, the estimate is not physical: {e}") from None
    for name in ("analyzer_transmittance", "sensor.electrons_per_unit", "display.radiance"):
        report[name] = {"value": None, "note": "not identifiable from these targets (a common scale); kept"}
    rig = Rig(display=disp, camera=dataclasses.replace(base.rig.camera, model=model))
    return Calibration(rig=rig, report=report, offset_dn=tuple(float(o) for o in offset))


def rig_errors(est: Rig, true: Rig, shape: tuple[int, int]) -> dict[str, float]:
    """Largest absolute error of an estimated rig per field group, in the quantities the decoder uses.

    Extinction is compared as ``1 / extinction_ratio`` (the analyzer leak: an ideal analyzer is 0, not
    inf) and vignetting as the falloff map over a ``shape`` frame (only the product of its cos^4 and
    polynomial terms is seen).

    Args:
        est: the estimate.
        true: the rig the captures came from.
        shape: ``(H, W)`` raw frame of the vignetting map.

    Returns:
        ``qwp_angle``, ``qwp_retardance``, ``leak``, ``crosstalk``, ``ambient``, ``vignetting``,
        ``degree_of_polarization``, ``polarization_angle``, ``emission_exponent``, ``tone_gamma``: each the
        largest absolute error.
    """
    e, t = est.camera.model, true.camera.model

    def leak(er) -> NDArray:
        return np.array([0.0 if math.isinf(x) else 1.0 / x for x in er])

    def vmap(m: CameraModel) -> NDArray:
        return vignetting_map(shape, m.vignetting_focal_px, m.vignetting_poly)

    return {
        "qwp_angle": abs(e.qwp_angle - t.qwp_angle),
        "qwp_retardance": float(np.max(np.abs(np.subtract(e.qwp_retardance, t.qwp_retardance)))),
        "leak": float(np.max(np.abs(leak(e.extinction_ratio) - leak(t.extinction_ratio)))),
        "crosstalk": float(np.max(np.abs(np.subtract(e.crosstalk, t.crosstalk)))),
        "ambient": float(np.max(np.abs(np.subtract(e.ambient, t.ambient)))),
        "vignetting": float(np.max(np.abs(vmap(e) - vmap(t)))),
        "degree_of_polarization": abs(est.display.degree_of_polarization - true.display.degree_of_polarization),
        "polarization_angle": abs(est.display.polarization_angle - true.display.polarization_angle),
        "emission_exponent": abs(est.display.emission_exponent - true.display.emission_exponent),
        "tone_gamma": float(np.max(np.abs(np.subtract(est.display.tone_gamma, true.display.tone_gamma)))),
    }
