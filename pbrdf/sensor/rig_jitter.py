"""Rig imperfections drawn per scene around the nominal rig (the data engine's ``rig_jitter``).

A model trained only on the nominal rig meets a real one whose calibration leaves residuals. The
engine therefore renders and simulates each scene through a *drawn* rig and decodes it with the
*nominal* one, so the residual reaches the network's input as it would on a calibrated real rig
(docs/rig_imperfections.md, "Drawn per scene", gives the ranges and why).

:data:`JITTER_RANGES` holds, per imperfection, the largest offset from nominal at ``scale = 1``;
:func:`draw_rig` draws every term uniformly within ``scale`` times it. The draws come from their
own stream (``numpy.random.default_rng([sample_seed, JITTER_STREAM])``), so the scene, its
render seeds and the camera noise are those of the same seed without jitter. ``scale = 0``
returns the nominal values exactly (bit-identical samples to no jitter).

Example:
    >>> from pbrdf.sensor.rig import Rig
    >>> rig, drawn = draw_rig(Rig(), sample_seed=7, scale=1.0)
    >>> 0.97 <= rig.display.degree_of_polarization <= 1.0, drawn == draw_rig(Rig(), 7, 1.0)[1]
    (True, True)
    >>> draw_rig(Rig(), 7, 0.0)[0] == Rig()
    True
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .rig import Rig

__all__ = ["JITTER_RANGES", "JITTER_STREAM", "MAX_SCALE", "check_scale", "draw_rig"]

#: Largest offset from the nominal value at ``scale = 1`` (a realistic residual after calibration,
#: about half the uncalibrated worst case; docs/rig_imperfections.md says why each). ``ambient``,
#: ``crosstalk`` (each off-diagonal entry) and ``vignetting_k1`` are one-sided (physical signs);
#: ``extinction_log2`` is the offset of ``log2(extinction / nominal)``, ``tone_gamma_log2`` that of
#: each channel's gamma; ``emission_exponent`` is a +- offset reflected at 0 (one-sided around a
#: flat display); the rest are +- offsets.
JITTER_RANGES = {
    "crosstalk": 0.03,  # off-diagonal fraction of a display region reaching another camera channel
    "ambient": 0.005,  # unpolarized room light per camera channel, in display radiances
    "vignetting_k1": 0.15,  # 1 - k1: falloff at the frame corner (k1 <= 0)
    "qwp_retardance": 0.1,  # rad per channel around pi/2 (about 6 degrees)
    "qwp_angle": math.radians(1.0),  # fast-axis mounting error
    "extinction_log2": 1.0,  # extinction ratio within [nominal / 2, nominal * 2]
    "degree_of_polarization": 0.03,  # display DoP in [0.97, 1]
    "polarization_angle": math.radians(1.0),  # display polarization angle around nominal
    "emission_exponent": 0.2,  # the display's cos^p profile, p around nominal (after calibration)
    "tone_gamma_log2": 0.03,  # each channel's tone gamma within 2 % of nominal (built-in patterns: no effect)
}
#: The random stream of the draws: ``default_rng([sample_seed, JITTER_STREAM])`` (the camera noise uses 1).
JITTER_STREAM = 2
#: Largest accepted ``scale`` (the worst cases at about 2; beyond, draws leave the checked ranges).
MAX_SCALE = 3.0


def check_scale(scale: float, name: str = "rig_jitter") -> float:
    """``scale`` as a float in ``[0, MAX_SCALE]``; ValueError naming ``name`` otherwise."""
    try:
        value = float(scale)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in [0, {MAX_SCALE:g}], got {scale!r}") from None
    if not 0.0 <= value <= MAX_SCALE:  # also refuses NaN
        raise ValueError(f"{name}={scale!r} must be in [0, {MAX_SCALE:g}]")
    return value


def draw_rig(rig: Rig, sample_seed: int, scale: float) -> tuple[Rig, dict]:
    """The rig of one scene: ``rig`` with its imperfections drawn around its own values.

    Args:
        rig: the nominal rig (its camera model and display are the centre of every draw).
        sample_seed: the scene's seed (:func:`blender_addon.core.scenegen.sample_seed`).
        scale: multiple of :data:`JITTER_RANGES` (0: ``rig`` unchanged; 1: the documented residual).

    Returns:
        ``(drawn rig, drawn values)``: the values as a JSON-friendly dict of the drawn fields
        (camera model: ``crosstalk``, ``ambient``, ``vignetting_poly``, ``qwp_retardance``,
        ``qwp_angle``, ``extinction_ratio``; display: ``degree_of_polarization``,
        ``polarization_angle``, ``emission_exponent``, ``tone_gamma``) plus ``scale``.
    """
    s = check_scale(scale)
    rng = np.random.default_rng([int(sample_seed) % 2**63, JITTER_STREAM])
    r = JITTER_RANGES
    model, display = rig.camera.model, rig.display
    # Every draw is made whatever the scale, so the stream (and the other terms) do not depend on it.
    u_cross = rng.random((3, 3))
    u_amb = rng.random(3)
    u_vig = rng.random()
    u_ret = rng.uniform(-1.0, 1.0, 3)
    u_qwp = rng.uniform(-1.0, 1.0)
    u_ext = rng.uniform(-1.0, 1.0, 3)
    u_dop = rng.random()
    u_pol = rng.uniform(-1.0, 1.0)
    u_exp = rng.uniform(-1.0, 1.0)  # drawn after the older terms: their draws are those of before
    u_gam = rng.uniform(-1.0, 1.0, 3)
    off = np.where(np.eye(3, dtype=bool), 0.0, s * r["crosstalk"] * u_cross)
    cam = {
        "crosstalk": tuple(tuple(float(v) for v in row) for row in np.asarray(model.crosstalk) + off),
        "ambient": tuple(float(a) for a in np.asarray(model.ambient) + s * r["ambient"] * u_amb),
        # + 0.0: a zero k1 stays 0.0, never -0.0
        "vignetting_poly": (
            float(model.vignetting_poly[0] - s * r["vignetting_k1"] * u_vig) + 0.0,
            *model.vignetting_poly[1:],
        ),
        "qwp_retardance": tuple(float(d) for d in np.asarray(model.qwp_retardance) + s * r["qwp_retardance"] * u_ret),
        "qwp_angle": float(model.qwp_angle + s * r["qwp_angle"] * u_qwp),
        "extinction_ratio": tuple(
            float(e) for e in np.asarray(model.extinction_ratio) * 2.0 ** (s * r["extinction_log2"] * u_ext)
        ),
    }
    shown = {
        "degree_of_polarization": float(
            display.degree_of_polarization * (1.0 - s * r["degree_of_polarization"] * u_dop)
        ),
        "polarization_angle": float(display.polarization_angle + s * r["polarization_angle"] * u_pol),
        "emission_exponent": abs(float(display.emission_exponent + s * r["emission_exponent"] * u_exp)),
        "tone_gamma": tuple(
            float(g) for g in np.asarray(display.tone_gamma) * 2.0 ** (s * r["tone_gamma_log2"] * u_gam)
        ),
    }
    new_rig = replace(rig, camera=replace(rig.camera, model=replace(model, **cam)), display=replace(display, **shown))
    drawn = {k: [list(row) for row in v] if k == "crosstalk" else list(v) if isinstance(v, tuple) else v
             for k, v in {**cam, **shown}.items()}  # fmt: skip
    return new_rig, {**drawn, "scale": s}
