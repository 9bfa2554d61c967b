"""Physics tests of pbrdf.polar.stokes: construction, derived quantities, physicality.

Every expected value comes from a closed form, cited where it is used.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pbrdf.polar import stokes
from tests.conftest import TOL
from tests.helpers import (
    HORIZONTAL,
    LEFT_CIRCULAR,
    MINUS_45,
    PLUS_45,
    RIGHT_CIRCULAR,
    VERTICAL,
    assert_angles_close_mod_pi,
    random_stokes,
)

PI = np.pi


# --- Stokes vectors ----------------------------------------------------------------------------------


class TestStokesConstructor:
    # s = s0 [1, p cos2chi cos2psi, p cos2chi sin2psi, p sin2chi] (Born & Wolf, Principles of Optics,
    # 7th ed., sect. 1.4.2), with the project's signs: s1 > 0 horizontal, s3 > 0 right circular.
    @pytest.mark.parametrize(
        ("args", "expected"),
        [
            pytest.param((1.0, 1.0, 0.0, 0.0), HORIZONTAL, id="horizontal"),
            pytest.param((1.0, 1.0, PI / 2, 0.0), VERTICAL, id="vertical"),
            pytest.param((1.0, 1.0, PI / 4, 0.0), PLUS_45, id="plus45"),
            pytest.param((1.0, 1.0, 3 * PI / 4, 0.0), MINUS_45, id="minus45"),
            pytest.param((1.0, 1.0, 0.3, PI / 4), RIGHT_CIRCULAR, id="right-circular"),
            pytest.param((1.0, 1.0, 0.3, -PI / 4), LEFT_CIRCULAR, id="left-circular"),
            pytest.param((2.0, 0.0, 0.3, 0.1), [2.0, 0.0, 0.0, 0.0], id="unpolarized"),
            pytest.param((2.0, 0.5, PI / 4, 0.0), [2.0, 0.0, 1.0, 0.0], id="half-polarized-plus45"),
        ],
    )
    def test_closed_forms(self, args, expected):
        np.testing.assert_allclose(stokes.stokes(*args), expected, atol=TOL.f64)

    def test_display_light_convention(self):
        # Convention pin (pbrdf.polar.stokes docstring): the LCD emits vertical linear light, S1 = -S0;
        # the polarized part LP = -S1 is all of it and unpol = S0 + S1 is zero (the paper's printed
        # unpol = S0 - S1 would give 2 S0).
        s = stokes.stokes(1.0, 1.0, PI / 2, 0.0)
        np.testing.assert_allclose(s, [1.0, -1.0, 0.0, 0.0], atol=TOL.f64)
        assert -s[1] == pytest.approx(s[0], abs=TOL.f64)
        assert s[0] + s[1] == pytest.approx(0.0, abs=TOL.f64)

    def test_broadcasts(self):
        s = stokes.stokes(np.ones((5, 1)), np.linspace(0, 1, 3), 0.2, 0.1)
        assert s.shape == (5, 3, 4)

    @pytest.mark.parametrize(
        ("args", "match"),
        [((-1.0, 0.5, 0.0, 0.0), "s0"), ((1.0, 1.5, 0.0, 0.0), "dop"), ((1.0, -0.1, 0.0, 0.0), "dop")],
    )
    def test_out_of_range_raises(self, args, match):
        with pytest.raises(ValueError, match=match):
            stokes.stokes(*args)


class TestStokesDerivedQuantities:
    @settings(deadline=None, max_examples=200)
    @given(
        s0=st.floats(1e-3, 1e3),
        p=st.floats(0.0, 1.0),
        psi=st.floats(0.0, PI, exclude_max=True),
        chi=st.floats(-PI / 4, PI / 4),
    )
    def test_round_trip_with_constructor(self, s0, p, psi, chi):
        s = stokes.stokes(s0, p, psi, chi)
        # Definitions: dop = |(s1,s2,s3)|/s0, dolp = |(s1,s2)|/s0 = p cos2chi, docp = |s3|/s0 = p |sin2chi|.
        assert stokes.intensity(s) == s0
        assert stokes.dop(s) == pytest.approx(p, abs=TOL.f64)
        assert stokes.dolp(s) == pytest.approx(p * np.cos(2 * chi), abs=TOL.f64)
        assert stokes.docp(s) == pytest.approx(p * abs(np.sin(2 * chi)), abs=TOL.f64)
        psi_out, chi_out = stokes.aolp(s), stokes.ellipticity_angle(s)
        assert 0.0 <= psi_out < PI
        assert -PI / 4 <= chi_out <= PI / 4
        # The angles are undefined without a (linear) polarized part; away from that the AoLP error is
        # about eps / (p cos2chi) <= 1e-10 for p cos2chi > 1e-6.
        if p * np.cos(2 * chi) > 1e-6:
            assert_angles_close_mod_pi(psi_out, psi, atol=TOL.f64_inverse)
        if p > 1e-6:
            assert chi_out == pytest.approx(chi, abs=TOL.f64_inverse)

    def test_partially_polarized_values(self):
        # s = [2, 1, 0, 1]: |(s1,s2,s3)| = sqrt 2, |(s1,s2)| = 1, |s3| = 1; AoLP 0; chi = atan2(1, 1)/2 = pi/8.
        s = np.array([2.0, 1.0, 0.0, 1.0])
        assert stokes.dop(s) == pytest.approx(np.sqrt(2) / 2, abs=TOL.f64)
        assert stokes.dolp(s) == pytest.approx(0.5, abs=TOL.f64)
        assert stokes.docp(s) == pytest.approx(0.5, abs=TOL.f64)
        assert stokes.aolp(s) == pytest.approx(0.0, abs=TOL.f64)
        assert stokes.ellipticity_angle(s) == pytest.approx(PI / 8, abs=TOL.f64)

    @pytest.mark.filterwarnings("error")
    def test_zero_intensity_gives_zero_without_warnings(self):
        s = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 1e-30, 0.0, 0.0], [-0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
        with np.errstate(all="raise"):
            for f in (stokes.dop, stokes.dolp, stokes.docp):
                np.testing.assert_array_equal(f(s), 0.0)
            np.testing.assert_array_equal(stokes.aolp(s[:1]), 0.0)
            np.testing.assert_array_equal(stokes.ellipticity_angle(s[:1]), 0.0)

    def test_aolp_range_and_singular_point(self):
        # Documented: AoLP in [0, pi), 0 where s1 = s2 = 0. Signed zeros (arctan2(0, -0) = pi) and
        # np.mod(-1e-20, pi) == pi used to break both; all branch points in one batch.
        s = np.array(
            [
                [1.0, -0.0, 0.0, 0.0],  # s1 = -0: arctan2 gives pi -> must be 0
                [1.0, -0.0, -0.0, 1.0],
                [1.0, 1.0, -1e-20, 0.0],  # just below 0 deg: mod rounds to pi -> must wrap to 0
                [1.0, 1.0, 1e-20, 0.0],
                [1.0, -1.0, 1e-20, 0.0],  # 90 deg from both sides
                [1.0, -1.0, -1e-20, 0.0],
                [1.0, 0.0, 1.0, 0.0],
                [1.0, 0.0, -1.0, 0.0],
            ]
        )
        expected = [0.0, 0.0, 0.0, 0.0, PI / 2, PI / 2, PI / 4, 3 * PI / 4]
        out = stokes.aolp(s)
        assert np.all((out >= 0) & (out < PI))
        np.testing.assert_allclose(out, expected, atol=TOL.f64)

    @pytest.mark.parametrize(
        "fn",
        [
            stokes.intensity,
            stokes.dop,
            stokes.dolp,
            stokes.docp,
            stokes.aolp,
            stokes.ellipticity_angle,
            stokes.is_physical_stokes,
        ],
    )
    @pytest.mark.parametrize("shape", [(3,), (2, 5), ()])
    def test_wrong_shape_raises(self, fn, shape):
        with pytest.raises(ValueError, match="4"):
            fn(np.zeros(shape))


class TestIsPhysicalStokes:
    def test_accepts_float32_fully_polarized(self, rng):
        n = 1000
        s = stokes.stokes(1.0, 1.0, rng.uniform(0, PI, n), rng.uniform(-PI / 4, PI / 4, n)).astype(np.float32)
        s *= rng.uniform(0.01, 100.0, (n, 1)).astype(np.float32)
        assert s.dtype == np.float32
        assert np.all(stokes.is_physical_stokes(s))

    def test_accepts_partial_and_zero(self, rng):
        assert np.all(stokes.is_physical_stokes(random_stokes(rng, 100)))
        assert stokes.is_physical_stokes(np.zeros(4))

    @pytest.mark.parametrize(
        "s",
        [
            pytest.param([1.0, 1.0, 1.0, 0.0], id="over-polarized"),
            pytest.param([-1.0, 0.0, 0.0, 0.0], id="negative-intensity"),
            pytest.param([np.nan, 0.0, 0.0, 0.0], id="nan-s0"),
            pytest.param([1.0, np.nan, 0.0, 0.0], id="nan-s1"),
        ],
    )
    def test_rejects(self, s):
        assert not stokes.is_physical_stokes(s)


class TestExtremeMagnitudes:
    """Finite input gives finite ratios: the norms are scaled, never squared in the input's dtype."""

    @pytest.mark.parametrize(
        ("dtype", "scale"),
        [(np.float32, 1e30), (np.float32, 1e-30), (np.float64, 1e300), (np.float64, 1e-300)],
    )
    def test_ratios_are_scale_free(self, dtype, scale):
        # [1, -1, 0, 0] is fully polarized (DoP = DoLP = 1) at any scale; [2, 1, 0, 1] has
        # DoP sqrt(2)/2 and DoLP = DoCP = 1/2 (test_partially_polarized_values).
        s = (np.array([[1.0, -1.0, 0.0, 0.0], [2.0, 1.0, 0.0, 1.0]]) * scale).astype(dtype)
        with np.errstate(all="raise"):
            np.testing.assert_allclose(stokes.dop(s), [1.0, np.sqrt(2) / 2], rtol=TOL.f32)
            np.testing.assert_allclose(stokes.dolp(s), [1.0, 0.5], rtol=TOL.f32)
            np.testing.assert_allclose(stokes.docp(s), [0.0, 0.5], rtol=TOL.f32)
            assert np.all(stokes.is_physical_stokes(s))
        assert stokes.dop(s).dtype == dtype

    def test_float32_display_light_scaled_by_1e30(self):
        s = np.array([1e30, -1e30, 0.0, 0.0], dtype=np.float32)
        assert float(stokes.dop(s)) == 1.0
        assert float(stokes.dolp(s)) == 1.0

    def test_unphysical_ratio_stays_finite(self):
        # |(s1, s2, s3)| / s0 = 1e300 / 1e-300 overflows: clamped to the largest float, no warning.
        s = np.array([[1e-300, 1e300, 0.0, 1e300], [1e-300, 0.0, -1e300, -1e300]])
        with np.errstate(all="raise"):
            for f in (stokes.dop, stokes.dolp, stokes.docp):
                out = f(s)
                np.testing.assert_array_equal(out, np.finfo(np.float64).max)
