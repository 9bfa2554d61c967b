"""Self-calibration: known rigs recovered from noisy synthetic target captures; bad targets refused.

The targets are formed in closed form and passed through the project's forward model
(``simulate_capture``); the estimates are compared with the rigs they came from. Tolerances (the
reasons: docs/calibration.md) are 1 % of each field's realistic range, in the quantity the decoder
depends on: ``1 / extinction_ratio`` (the analyzers' leak), and the falloff map ``V`` rather than
the polynomial's correlated coefficients.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pbrdf.polar import mueller
from pbrdf.sensor.calibration import Target, calibrate, rig_errors
from pbrdf.sensor.calibration_targets import lab_rig, simulate_targets, target_stokes
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.decode import decode
from pbrdf.sensor.projection import pinhole_intrinsics
from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig

SIZE = 128
FOCAL = 0.94 * SIZE  # the real camera's field of view
K = pinhole_intrinsics(FOCAL, SIZE, SIZE)

#: Realistic range of each field and the tolerance (1 % of it): ``(span, tolerance)``.
TOLERANCE = {
    "qwp_angle": (0.2, 0.002),  # +-0.1 rad of mounting error
    "qwp_retardance": (0.6, 0.006),  # pi/2 +- 0.3 rad over the visible band
    "leak": (0.1, 0.001),  # 1 / extinction_ratio, ER >= 10
    "crosstalk": (0.5, 0.005),  # each entry; diagonal 0.7 - 1, off-diagonal 0 - 0.2
    "ambient": (0.05, 5e-4),  # radiance units (the display is 1)
    "vignetting": (0.7, 0.007),  # the falloff map V over the frame, 0.3 - 1
    "degree_of_polarization": (0.2, 0.002),  # 0.8 - 1
    "polarization_angle": (0.2, 0.002),  # pi/2 +- 0.1 rad
    "emission_exponent": (4.0, 0.04),  # cos^p: flat to halved at 36 degrees
    "tone_gamma": (2.0, 0.02),  # each channel, linear (1) to beyond sRGB-like (3)
}


def _rig(model: dict, dop: float, angle: float, exponent: float = 0.0, gamma=(1.0, 1.0, 1.0)) -> Rig:
    display = DisplaySpec(
        degree_of_polarization=dop, polarization_angle=angle, emission_exponent=exponent, tone_gamma=gamma
    )
    return Rig(display, CameraSpec(model=CameraModel(**model)))


RIGS = {
    "mild": _rig(
        {"qwp_angle": 0.03, "qwp_retardance": (1.50, 1.62, 1.66), "extinction_ratio": (80, 120, 200),
         "ambient": (0.004, 0.006, 0.003), "crosstalk": [[0.92, 0.06, 0.01], [0.08, 0.95, 0.05], [0.02, 0.07, 0.9]],
         "vignetting_focal_px": FOCAL, "vignetting_poly": (-0.1, 0.03, 0.0)},
        0.97, math.pi / 2 + 0.04, 0.8, (2.2, 2.0, 2.4),
    ),
    "strong": _rig(
        {"qwp_angle": -0.08, "qwp_retardance": (1.32, 1.45, 1.80), "extinction_ratio": (12, 30, 50),
         "ambient": (0.03, 0.02, 0.04), "crosstalk": [[0.8, 0.15, 0.05], [0.18, 0.85, 0.12], [0.04, 0.2, 0.75]],
         "vignetting_focal_px": FOCAL, "vignetting_poly": (-0.3, 0.1, -0.05)},
        0.85, math.pi / 2 - 0.09, 1.8, (1.6, 2.6, 1.9),
    ),
    "nominal": _rig({}, 1.0, math.pi / 2),  # no imperfection: nothing may be invented
}  # fmt: skip


def _leak(er) -> np.ndarray:
    return np.array([0.0 if math.isinf(e) else 1.0 / e for e in er])


def assert_recovered(est: Rig, true: Rig) -> None:
    """Every field within its tolerance; the message lists the ones that are not."""
    errors = rig_errors(est, true, (SIZE, SIZE))
    bad = {k: v for k, v in errors.items() if not v <= TOLERANCE[k][1]}
    assert not bad, f"not recovered within tolerance: {bad}"


@pytest.fixture(scope="module")
def calibrations() -> dict[str, tuple[Rig, list[Target], Rig]]:
    """Per rig: the true rig, its noisy targets and the calibrated rig."""
    out = {}
    for seed, (name, rig) in enumerate(RIGS.items()):
        targets = simulate_targets(rig, (SIZE, SIZE), rng=np.random.default_rng(seed), intrinsics=K)
        out[name] = (rig, targets, calibrate(targets).rig)
    return out


@pytest.mark.parametrize("name", list(RIGS))
def test_known_rigs_are_recovered_within_tolerance(calibrations, name):
    true, _, est = calibrations[name]
    assert_recovered(est, true)


def _planted(rig: Rig, field: str) -> Rig:
    """``rig`` with one field moved by three tolerances (a wrong parameter in the forward model)."""
    m, d = rig.camera.model, rig.display
    step = 3 * TOLERANCE[field][1]
    changes = {
        "qwp_angle": lambda: {"qwp_angle": m.qwp_angle + step},
        "qwp_retardance": lambda: {"qwp_retardance": (m.qwp_retardance[0], m.qwp_retardance[1] + step,
                                                      m.qwp_retardance[2])},
        "leak": lambda: {"extinction_ratio": tuple(1.0 / (u + step) for u in _leak(m.extinction_ratio))},
        "crosstalk": lambda: {"crosstalk": np.add(m.crosstalk, np.diag([0.0, 0.0, step])).tolist()},
        "ambient": lambda: {"ambient": tuple(a + step for a in m.ambient)},
        "vignetting": lambda: {"vignetting_poly": (m.vignetting_poly[0] - 3 * step, *m.vignetting_poly[1:])},
    }  # fmt: skip
    if field in changes:
        return dataclasses.replace(rig, camera=dataclasses.replace(rig.camera, model=m.replace(**changes[field]())))
    if field == "tone_gamma":
        return dataclasses.replace(
            rig, display=dataclasses.replace(d, tone_gamma=(d.tone_gamma[0] + step, *d.tone_gamma[1:]))
        )
    value = getattr(d, field) + (step if field in ("polarization_angle", "emission_exponent") else -step)
    return dataclasses.replace(rig, display=dataclasses.replace(d, **{field: value}))


@pytest.mark.parametrize("field", list(TOLERANCE))
def test_a_planted_wrong_parameter_fails_the_recovery_check(calibrations, field):
    true, _, est = calibrations["mild"]
    with pytest.raises(AssertionError, match=field):
        assert_recovered(est, _planted(true, field))


def _object_stokes(h: int, w: int) -> np.ndarray:
    """A smooth object: per-region s0, linear (display-like) and a little circular polarization."""
    yy, xx = np.mgrid[0:h, 0:w] / h
    s = np.zeros((h, w, 3, 4))
    s[..., 0] = (0.15 + 0.25 * yy + 0.1 * xx)[..., None] * np.array([1.0, 0.8, 0.6])
    s[..., 1] = -(0.3 + 0.4 * xx)[..., None] * s[..., 0]
    s[..., 3] = (0.1 - 0.2 * yy)[..., None] * s[..., 0]
    return s


@pytest.mark.parametrize("name", ["mild", "strong"])
def test_decoding_with_the_estimate_matches_decoding_with_the_truth(calibrations, name):
    true, targets, est = calibrations[name]
    s = _object_stokes(64, 64)
    rng = np.random.default_rng(5)
    model = true.camera.model
    raws = simulate_capture(s, model, rng=rng)
    dark = simulate_capture(np.zeros_like(s), model, rng=rng)

    def maps(m: CameraModel) -> np.ndarray:
        return decode(raws, m, dark=dark).maps[2:-2, 2:-2]  # away from the demosaic's repeated edge

    want = maps(model)
    scale = np.abs(want).max(axis=(0, 1))
    calibrated = np.abs(maps(est.camera.model) - want).max(axis=(0, 1)) / scale
    nominal = np.abs(maps(lab_rig(true).camera.model) - want).max(axis=(0, 1)) / scale
    assert calibrated.max() < 0.02, calibrated
    assert nominal.max() > 5 * calibrated.max()  # the check can fail: the nominal rig is far off


def _replace(targets: list[Target], name: str, **changes) -> list[Target]:
    return [dataclasses.replace(t, **changes) if t.name == name else t for t in targets]


def test_missing_or_unusable_targets_are_named(calibrations):
    _, targets, _ = calibrations["mild"]
    cases = {
        "missing dark frame": [t for t in targets if t.kind != "dark"],
        "missing white target for display channel G": [t for t in targets if t.name != "white_g"],
        "3 distinct angles": [t for t in targets if t.kind != "polarizer" or t.name < "polarizer_060"],
        "missing polarizer targets": [t for t in targets if t.kind != "polarizer"],
        "white_r: white target not visible": _replace(targets, "white_r", raws=targets[0].raws),
        "two white targets for display channel R": _replace(targets, "white_g", display_channel=0),
        "white_g_050: a white target below full level": _replace(targets, "white_g_050", distance_m=0.4),
    }
    for message, subset in cases.items():
        with pytest.raises(ValueError, match=message):
            calibrate(subset)
    with pytest.raises(ValueError, match="no calibration targets"):
        calibrate([])


def test_saturated_target_and_invisible_display_are_refused(calibrations):
    true, targets, _ = calibrations["mild"]
    white = next(t for t in targets if t.name == "white_b")
    bright = white.model.replace(sensor=dataclasses.replace(white.model.sensor, electrons_per_unit=1e8))
    s = target_stokes("white", true, (SIZE, SIZE), display_channel=2, intrinsics=K)
    saturated = simulate_capture(s, true.camera.model.replace(sensor=bright.sensor), noise=False)
    with pytest.raises(ValueError, match="white_b: white target saturated in every exposure at 100 % of the B pixels"):
        calibrate(_replace(targets, "white_b", raws=saturated))
    dark_pol = targets
    for t in targets:
        if t.kind == "polarizer":
            dark_pol = _replace(dark_pol, t.name, raws=t.dark)
    with pytest.raises(ValueError, match=r"display \(through the polarizer\) not visible"):
        calibrate(dark_pol)


def test_non_physical_estimates_are_refused_naming_the_field(calibrations):
    true, targets, _ = calibrations["mild"]
    # Two white captures of the same primary labelled as two channels: the mixing matrix is singular.
    white_r = next(t for t in targets if t.name == "white_r")
    with pytest.raises(ValueError, match="not physical: crosstalk is singular"):
        calibrate(_replace(targets, "white_g", raws=white_r.raws, dark=white_r.dark))
    # A retarder far from a quarter wave (built past CameraModel's own check, as a real plate could be).
    thin = true.camera.model.replace()
    object.__setattr__(thin, "qwp_retardance", (0.05, 0.05, 0.05))
    rng = np.random.default_rng(3)
    swapped = targets
    for t in targets:
        if t.kind == "polarizer":
            s = target_stokes("polarizer", true, (SIZE, SIZE), polarizer_angle=t.polarizer_angle)
            swapped = _replace(swapped, t.name, raws=simulate_capture(s, thin, rng=rng))
    with pytest.raises(ValueError, match="not physical: qwp_retardance"):
        calibrate(swapped)
    # Brightness behind the polarizer modulated beyond what a DoP of 1 allows (say the display drifted):
    # Stokes of a "display" with DoP 1.3 (clipped at 0 where the intensity would be negative).
    psi = true.display.polarization_angle
    over = np.array([1.0, 1.3 * math.cos(2 * psi), 1.3 * math.sin(2 * psi), 0.0])
    drifted = targets
    for t in targets:
        if t.kind == "polarizer":
            s = np.broadcast_to(mueller.linear_polarizer(t.polarizer_angle) @ over, (SIZE, SIZE, 3, 4))
            drifted = _replace(drifted, t.name, raws=simulate_capture(s, true.camera.model, rng=rng))
    with pytest.raises(ValueError, match="not physical: display.degree_of_polarization must be in"):
        calibrate(drifted)


def test_calibration_is_fast(calibrations):
    import time

    _, targets, _ = calibrations["mild"]
    start = time.perf_counter()
    calibrate(targets)
    assert time.perf_counter() - start < 10.0  # seconds, on a shared 2-core machine


def test_profile_and_tone_response_need_their_targets_and_are_kept_without_them(calibrations):
    """Without the second distance or the partial levels the fields keep the capture rig's values, said so."""
    true, targets, _ = calibrations["mild"]
    plain = [t for t in targets if not (t.kind == "white" and (t.level < 1.0 or t.distance_m != 0.7))]
    assert len(plain) == len(targets) - 9
    cal = calibrate(plain)
    assert cal.rig.display.emission_exponent == 0.0 and cal.rig.display.tone_gamma == (1.0, 1.0, 1.0)
    assert "not measured" in cal.report["display.emission_exponent"]["note"]
    assert "not measured" in cal.report["display.tone_gamma[G]"]["note"]
    # One primary at one partial level is enough for its own gamma; the others are kept.
    one = plain + [t for t in targets if t.name == "white_g_050"]
    gamma = calibrate(one).rig.display.tone_gamma
    assert gamma[0] == gamma[2] == 1.0 and abs(gamma[1] - true.display.tone_gamma[1]) < TOLERANCE["tone_gamma"][1]
