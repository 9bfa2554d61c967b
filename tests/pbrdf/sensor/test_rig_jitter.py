"""pbrdf/sensor/rig_jitter.py: per-scene rig imperfections, deterministic, within the documented ranges."""

import dataclasses
import math

import numpy as np
import pytest

from pbrdf.sensor import camera, decode
from pbrdf.sensor.rig import Rig
from pbrdf.sensor.rig_jitter import MAX_SCALE, draw_rig


def test_same_seed_same_draws_other_seed_other_draws():
    a_rig, a = draw_rig(Rig(), 123, 1.0)
    b_rig, b = draw_rig(Rig(), 123, 1.0)
    _, c = draw_rig(Rig(), 124, 1.0)
    assert a == b and a_rig == b_rig
    assert a["crosstalk"] != c["crosstalk"] and a["degree_of_polarization"] != c["degree_of_polarization"]


def test_draws_stay_in_the_documented_ranges_and_reach_the_rig():
    """The ranges of docs/rig_imperfections.md ("Drawn per scene"), written out here, at scale 1."""
    for seed in range(200):
        rig, d = draw_rig(Rig(), seed, 1.0)
        m = np.asarray(d["crosstalk"])
        off = m[~np.eye(3, dtype=bool)]
        assert np.all(np.diag(m) == 1.0) and np.all((off >= 0) & (off <= 0.03))
        assert all(0.0 <= a <= 0.005 for a in d["ambient"])
        assert -0.15 <= d["vignetting_poly"][0] <= 0.0 and d["vignetting_poly"][1:] == [0.0, 0.0]
        assert all(abs(r - math.pi / 2) <= 0.1 for r in d["qwp_retardance"])
        assert abs(d["qwp_angle"]) <= math.radians(1.0)
        assert all(50.0 <= e <= 200.0 for e in d["extinction_ratio"])
        assert 0.97 <= d["degree_of_polarization"] <= 1.0
        assert abs(d["polarization_angle"] - math.pi / 2) <= math.radians(1.0)
        assert 0.0 <= d["emission_exponent"] <= 0.2 and all(2**-0.03 <= g <= 2**0.03 for g in d["tone_gamma"])
        assert (
            rig.display.emission_exponent == d["emission_exponent"] and list(rig.display.tone_gamma) == d["tone_gamma"]
        )
        model = rig.camera.model
        assert model.crosstalk == tuple(map(tuple, d["crosstalk"])) and list(model.ambient) == d["ambient"]
        assert rig.display.degree_of_polarization == d["degree_of_polarization"]
        assert rig.camera.model.exposures == Rig().camera.model.exposures and rig.display.center == Rig().display.center


def test_scale_multiplies_the_offsets_and_zero_is_the_nominal_rig_exactly():
    _, one = draw_rig(Rig(), 9, 1.0)
    _, two = draw_rig(Rig(), 9, 2.0)
    assert two["qwp_angle"] == pytest.approx(2 * one["qwp_angle"])
    assert 1 - two["degree_of_polarization"] == pytest.approx(2 * (1 - one["degree_of_polarization"]))
    assert math.log2(two["extinction_ratio"][0] / 100) == pytest.approx(2 * math.log2(one["extinction_ratio"][0] / 100))
    assert two["emission_exponent"] == pytest.approx(2 * one["emission_exponent"])
    # Around a profiled display the exponent is drawn both ways.
    around = [draw_rig(Rig.from_dict({"display": {"emission_exponent": 1.0}}), s, 1.0)[1]["emission_exponent"]
              for s in range(40)]  # fmt: skip
    assert min(around) < 0.95 and max(around) > 1.05 and all(0.8 <= p <= 1.2 for p in around)
    rig, zero = draw_rig(Rig(), 9, 0.0)
    assert rig == Rig() and rig.camera.model.nominal_rig and zero["scale"] == 0.0
    assert math.copysign(1.0, zero["vignetting_poly"][0]) == 1.0  # 0.0, not -0.0


@pytest.mark.parametrize("scale", [-0.1, MAX_SCALE + 0.1, float("nan"), "a"])
def test_bad_scale_refused_with_its_name(scale):
    with pytest.raises(ValueError, match="rig_jitter"):
        draw_rig(Rig(), 0, scale)


def _capture(model, stokes):
    return camera.simulate_capture(stokes, model, rng=np.random.default_rng(0), noise=False)


def test_drawn_rig_decoded_with_the_nominal_one_differs_and_with_itself_recovers_the_truth():
    """The engine's chain: raws through the drawn rig, decoded with the nominal one (a calibration residual)."""
    y, x = np.mgrid[0:16, 0:16] / 16.0  # smooth images: the demosaic is exact enough
    s0 = np.stack([0.3 + 0.2 * x, 0.4 - 0.1 * y, 0.25 + 0.1 * x * y], -1)
    # (H, W, 3, 4), partially polarized; s2 = 0: the decoder does not measure s2, whose leak into s3
    # through a retardance error no rig knowledge inverts.
    stokes = np.stack([s0, -0.6 * s0, 0.0 * s0, 0.1 * s0], -1)
    drawn = draw_rig(Rig(), 5, 1.0)[0].camera.model
    nominal = Rig().camera.model
    truth = decode.decode(_capture(nominal, stokes), nominal, grid="half", min_signal=-np.inf).maps
    with_nominal = decode.decode(_capture(drawn, stokes), nominal, grid="half", min_signal=-np.inf).maps
    # Decoded with the drawn model itself, everything but the ambient light is inverted (a dark frame removes it).
    no_ambient = dataclasses.replace(drawn, ambient=(0.0, 0.0, 0.0))
    with_drawn = decode.decode(_capture(no_ambient, stokes), no_ambient, grid="half", min_signal=-np.inf).maps
    err_nominal, err_drawn = np.abs(with_nominal - truth).max(), np.abs(with_drawn - truth).max()
    assert err_nominal > 0.01 and err_drawn < 0.1 * err_nominal, (err_nominal, err_drawn)
    # A zero scale is the nominal chain bit for bit.
    zero = draw_rig(Rig(), 5, 0.0)[0].camera.model
    np.testing.assert_array_equal(decode.decode(_capture(zero, stokes), nominal, grid="half").maps,
                                  decode.decode(_capture(nominal, stokes), nominal, grid="half").maps)  # fmt: skip
