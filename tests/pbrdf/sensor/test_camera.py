"""Tests of the display-camera forward model (pbrdf.sensor.camera): mosaic layout, measurement matrix, noise, model.

Expected values come from physics and closed forms, never from earlier runs of the code:

- the IMX250MYR layout is written out literally in tests/helpers.py (checked against polanalyser 3.0.0);
- pixel intensities follow Malus' law behind a quarter-wave plate whose fast axis is horizontal,
  ``[S0, S1, S2, S3] -> [S0, S1, S3, -S2]`` (Goldstein, Polarized Light, 3rd ed., eqs. 6.46-6.47), so the
  analyzer at theta records ``1/2 (S0 + S1 cos 2 theta + S3 sin 2 theta)``;
- a micro-polarizer with extinction ratio ER and transmittance q is a diattenuator with transmittances q and
  q / ER: ``I = a S0 + b (S1 cos 2 theta + S2' sin 2 theta)``, ``a = q (1 + 1/ER) / 2``,
  ``b = q (1 - 1/ER) / 2``;
- the raw noise is Poisson-Gaussian, ``Var(DN) = K (mean - black) + K^2 sigma_r^2 + 1/12`` (Foi et al., IEEE TIP
  2008; EMVA 1288).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from pbrdf.sensor import camera
from pbrdf.sensor.camera import CameraModel, SensorParams
from tests.helpers import IDEAL_OPTICS, IMX250MYR_LAYOUT, elliptical_states, parse_layout_entry

# ----------------------------------------------------------------------------------------------------------
# 1. Layout
# ----------------------------------------------------------------------------------------------------------


def test_layout_table_matches_documented_imx250myr():
    assert camera.ANGLES_DEG == (0, 45, 90, 135)
    for i in range(4):
        for j in range(4):
            colour, angle = parse_layout_entry(IMX250MYR_LAYOUT[i][j])
            assert camera.MOSAIC_COLOR[i, j] == colour, (i, j, IMX250MYR_LAYOUT[i][j])
            assert camera.ANGLES_DEG[camera.MOSAIC_ANGLE[i, j]] == angle, (i, j, IMX250MYR_LAYOUT[i][j])


@pytest.mark.parametrize("offset", [(0, 0), (0, 1), (1, 0), (3, 2)])
def test_mosaic_index_offset_shifts_the_table(offset):
    # A sensor ROI starting at (r, c) of the full sensor puts table entry ((i + r) % 4, (j + c) % 4) at raw (i, j).
    color, angle = camera.mosaic_indices(offset)
    for i in range(4):
        for j in range(4):
            c, a = parse_layout_entry(IMX250MYR_LAYOUT[(i + offset[0]) % 4][(j + offset[1]) % 4])
            assert (color[i, j], camera.ANGLES_DEG[angle[i, j]]) == (c, a)


def test_mosaic_end_to_end_follows_malus_law_on_the_literal_table():
    # Each colour carries a distinct fully polarized state (elliptical: with the QWP the 45/135 pixels see the
    # incoming s3, so linear states alone could not tell 45 from 135), and s0 varies over the image so that a
    # misplaced pixel cannot match by accident.
    h, w = 12, 16
    y, x = np.mgrid[0:h, 0:w]
    s0 = 1.0 + 0.05 * y + 0.013 * x
    img = s0[..., None, None] * elliptical_states()
    raw = camera.mosaic(img, CameraModel(**IDEAL_OPTICS))
    for yy in range(h):
        for xx in range(w):
            entry = IMX250MYR_LAYOUT[yy % 4][xx % 4]
            c, theta = parse_layout_entry(entry)
            s = img[yy, xx, c]
            t = np.deg2rad(theta)
            # QWP (fast axis horizontal): the analyzer's "s2" is the incoming s3; the incoming s2 is lost.
            expected = 0.5 * (s[0] + s[1] * np.cos(2 * t) + s[3] * np.sin(2 * t))
            assert raw[yy, xx] == pytest.approx(expected, rel=1e-12, abs=1e-12), (yy, xx, entry)
    # The 12 (colour, angle) intensities at one point are pairwise distinct, so the check above discriminates.
    t = np.deg2rad(np.array(camera.ANGLES_DEG))
    s = elliptical_states()
    vals = 0.5 * (s[:, :1] + s[:, 1:2] * np.cos(2 * t) + s[:, 3:4] * np.sin(2 * t))
    assert np.min(np.diff(np.sort(vals.ravel()))) > 0.02


@pytest.mark.parametrize("er", [np.inf, 100.0, 20.0])
@pytest.mark.parametrize("delta", [np.pi / 2, np.pi / 2 + 0.07])
def test_measurement_matrix_closed_form(er, delta):
    # Diattenuator (q, q/ER) at theta behind a retarder delta with horizontal fast axis:
    # I = a s0 + b (s1 cos 2t + (s2 cos d + s3 sin d) sin 2t).
    q = 0.8
    m = camera.measurement_matrix(CameraModel(extinction_ratio=er, qwp_retardance=delta, analyzer_transmittance=q))
    a, b = 0.5 * q * (1 + 1 / er), 0.5 * q * (1 - 1 / er)
    t = np.deg2rad(np.array(camera.ANGLES_DEG))
    rows = np.stack(
        [a + 0 * t, b * np.cos(2 * t), b * np.sin(2 * t) * np.cos(delta), b * np.sin(2 * t) * np.sin(delta)], axis=-1
    )
    np.testing.assert_allclose(m, np.broadcast_to(rows, (3, 4, 4)), rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------------------------------
# 2. Noise statistics
# ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("electrons", [100.0, 1000.0, 5000.0, 9000.0])
def test_raw_noise_is_poisson_gaussian(electrons):
    rng = np.random.default_rng(1234)
    sensor = SensorParams()
    t = 0.01
    irr = np.full((512, 512), electrons / (sensor.electrons_per_unit * t))
    raw = camera.expose(irr, t, sensor, rng=rng).astype(np.float64)
    k = sensor.gain
    mean_pred = sensor.black_level + k * electrons
    var_pred = k * (mean_pred - sensor.black_level) + k**2 * sensor.read_noise**2 + 1 / 12
    assert raw.mean() == pytest.approx(mean_pred, abs=5 * np.sqrt(var_pred / raw.size) + 0.02)
    # Relative standard error of a variance from N = 262144 samples: sqrt(2 / N) = 0.3 %.
    assert raw.var() == pytest.approx(var_pred, rel=0.05)


def test_raw_saturation_clips_and_is_flagged():
    rng = np.random.default_rng(1234)
    sensor = SensorParams()
    irr = np.full((64, 64), 10.0)  # 8e4 electrons at 10 ms: far beyond the 10.7 ke- well
    raw = camera.expose(irr, 0.01, sensor, rng=rng)
    # The full well in DN (K FW + black = 4082) lies above the saturation threshold (0.95 * 4095 = 3890), so a
    # full pixel is always flagged as saturated by the merge, and never exceeds the white level.
    assert sensor.gain * sensor.full_well + sensor.black_level > sensor.saturation * sensor.white_level
    assert raw.min() >= sensor.saturation * sensor.white_level and raw.max() <= sensor.white_level
    # With a gain that maps the well beyond the ADC range the output clips exactly at the white level.
    hot = SensorParams(gain=1.0)
    assert np.all(camera.expose(irr, 0.01, hot, rng=rng) == hot.white_level)
    assert np.all(camera.expose(irr, 0.01, hot, noise=False) == hot.white_level)
    with pytest.raises(ValueError, match="rng"):
        camera.expose(irr, 0.01, sensor, noise=True)


# ----------------------------------------------------------------------------------------------------------
# 3. CameraModel serialisation and validation
# ----------------------------------------------------------------------------------------------------------


def test_camera_model_dict_round_trip_through_json():
    model = CameraModel(
        qwp_angle=0.01,
        qwp_retardance=(1.5, np.pi / 2, 1.62),
        extinction_ratio=(np.inf, 150.0, 80.5),
        analyzer_transmittance=0.9,
        exposures=(0.005, 0.05),
        sensor=SensorParams(gain=0.4, read_noise=3.1, black_level=12.0, electrons_per_unit=1.0e5),
        pattern_offset=(1, 3),
    )
    text = json.dumps(model.to_dict())
    back = CameraModel.from_dict(json.loads(text))
    assert back == model
    assert back.extinction_ratio[0] == np.inf
    assert CameraModel.from_dict(CameraModel().to_dict()) == CameraModel()


def test_camera_model_unknown_keys_are_named():
    d = CameraModel().to_dict()
    d["exposure_times"] = [0.1]
    with pytest.raises(ValueError, match="exposure_times"):
        CameraModel.from_dict(d)
    d = CameraModel().to_dict()
    d["sensor"]["well"] = 1.0
    with pytest.raises(ValueError, match="well"):
        CameraModel.from_dict(d)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"exposures": (0.01, -0.02)}, "exposures"),
        ({"exposures": ()}, "exposures"),
        ({"extinction_ratio": 0.5}, "extinction_ratio"),
        ({"extinction_ratio": (100.0, np.nan, 100.0)}, "extinction_ratio"),
        ({"qwp_retardance": 0.0}, "qwp_retardance"),
        ({"analyzer_transmittance": 0.0}, "analyzer_transmittance"),
        # Out of the documented ranges (found by fuzzing: these decoded to all-zero or meaningless maps, or failed
        # with "SVD did not converge" naming no field).
        ({"extinction_ratio": (1.0, 1.0, 1.0)}, r"extinction_ratio\[R\] must be in \[2, inf\]; got 1$"),
        ({"extinction_ratio": (100.0, 100.0, 1.5)}, r"extinction_ratio\[B\] must be in \[2, inf\]"),
        ({"analyzer_transmittance": 1e300}, r"analyzer_transmittance must be in \[0.001, 1\]; got 1e\+300"),
        ({"analyzer_transmittance": 1e-300}, r"analyzer_transmittance must be in \[0.001, 1\]"),
        ({"qwp_angle": np.inf}, r"qwp_angle \(radians\) must be in \[-6.28319, 6.28319\]; got inf"),
        ({"qwp_angle": 1e300}, "qwp_angle"),
        ({"qwp_angle": "0.1"}, "qwp_angle .* must be a number"),
        ({"qwp_retardance": np.inf}, r"qwp_retardance \(radians\)\[R\] must be in \[0, 6.28319\]"),
        ({"qwp_retardance": (1.5, 1.5)}, "qwp_retardance .* one number or three"),
        ({"exposures": (1e-300,)}, r"exposures \(seconds\) must be in \[1e-07, 10000\]; got 1e-300"),
        ({"exposures": (0.01, 1e300)}, r"exposures \(seconds\) must be in \[1e-07, 10000\]"),
        ({"exposures": (0.01, np.inf)}, "exposures"),
        ({"exposures": (0.01,) * 65}, "exposures must be a list of 1 to 64 times"),
        ({"pattern_offset": (0.5, 0)}, "pattern_offset must be two integers"),
        ({"pattern_offset": (1, 2, 3)}, "pattern_offset must be two integers"),
        ({"sensor": {"gain": 1.0}}, "sensor must be a SensorParams"),
    ],
)
def test_camera_model_rejects_invalid_values(changes, match):
    with pytest.raises(ValueError, match=match):
        CameraModel(**changes)


def test_camera_model_accepts_range_ends_and_normalises_types():
    lo = {k: v[0] for k, v in camera.CAMERA_RANGES.items()}
    hi = {k: v[1] for k, v in camera.CAMERA_RANGES.items()}
    for ends in (lo, hi):
        exposures = (ends.pop("exposures"),)
        retardance = ends.pop("qwp_retardance")
        retardance = retardance + (np.pi / 2 if retardance == 0 else -np.pi / 2)  # keep |sin| >= 0.1
        CameraModel(exposures=exposures, qwp_retardance=retardance, **ends)
    model = CameraModel(pattern_offset=(np.int64(5), 6.0), exposures=np.array([0.01, 0.02]))
    assert model.pattern_offset == (1, 2) and model.exposures == (0.01, 0.02)
    assert all(type(v) is int for v in model.pattern_offset)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"gain": 0.0}, "gain"),
        ({"read_noise": -1.0}, "read_noise"),
        ({"bits": 17}, "bits"),
        ({"saturation": 0}, "saturation"),
        # Out of the documented ranges (found by fuzzing: gain 1e-320 raised ZeroDivisionError, 1e308 and inf gave
        # "sigma must be positive and finite" naming no field, and so on).
        ({"gain": 1e-320}, r"SensorParams.gain must be in \[0.0001, 10000\]; got 9.99989e-321"),
        ({"gain": 1e308}, r"SensorParams.gain must be in \[0.0001, 10000\]; got 1e\+308"),
        ({"gain": np.inf}, r"SensorParams.gain must be in \[0.0001, 10000\]; got inf"),
        ({"gain": np.nan}, r"SensorParams.gain must be in .*; got nan"),
        ({"gain": "0.38"}, r"SensorParams.gain must be a number in \[0.0001, 10000\]; got '0.38'"),
        ({"gain": None}, "SensorParams.gain must be a number"),
        ({"gain": True}, "SensorParams.gain must be a number"),
        ({"electrons_per_unit": 1e308}, r"SensorParams.electrons_per_unit must be in \[0.001, 1e\+12\]"),
        ({"full_well": 1e-320}, r"SensorParams.full_well must be in \[1, 1e\+09\]"),
        ({"read_noise": np.inf}, r"SensorParams.read_noise must be in \[0, 1e\+06\]"),
        ({"saturation": 1e-320}, r"SensorParams.saturation must be in \[0.5, 1\]"),
        ({"black_level": np.inf}, r"SensorParams.black_level must be in \[0, 65535\]"),
        ({"bits": 12.5}, r"SensorParams.bits must be an integer in \[1, 16\]; got 12.5"),
        ({"bits": "12"}, "SensorParams.bits must be an integer"),
        ({"bits": 4}, "SensorParams.black_level 16 must be below the saturation threshold 14.25 DN"),
        ({"black_level": 3900.0}, "SensorParams.black_level 3900 must be below the saturation threshold 3890.25 DN"),
    ],
)
def test_sensor_params_reject_invalid_values(changes, match):
    with pytest.raises(ValueError, match=match):
        SensorParams(**changes)


def test_sensor_params_integral_float_bits_become_int():
    assert SensorParams(bits=12.0).bits == 12 and type(SensorParams(bits=np.int64(10)).bits) is int


@pytest.mark.parametrize(
    ("path", "match"),
    [
        (("sensor", "gain"), "SensorParams.gain must be in"),
        (("qwp_angle",), "qwp_angle .* must be in"),
        (("exposures",), "exposures .* must be in"),
    ],
)
def test_from_dict_int_too_large_for_a_float_is_a_value_error(path, match):
    # JSON integers have no size limit; float(10**400) raises OverflowError, which used to escape as a traceback.
    d = CameraModel().to_dict()
    target = d
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = 10**400 if path[-1] != "exposures" else [10**400]
    with pytest.raises(ValueError, match=match):
        CameraModel.from_dict(d)


def test_from_dict_extinction_inf_string_and_bare_exposure():
    d = CameraModel().to_dict()
    d["extinction_ratio"] = ["inf", "INF", 50]
    d["exposures"] = 0.05
    model = CameraModel.from_dict(d)
    assert model.extinction_ratio == (np.inf, np.inf, 50.0) and model.exposures == (0.05,)
    d["sensor"] = [1]
    with pytest.raises(ValueError, match="sensor must be an object"):
        CameraModel.from_dict(d)
