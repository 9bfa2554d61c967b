"""Physics tests for pbrdf.polar.stokes, pbrdf.polar.mueller and pbrdf.polar.fresnel.

Every expected value comes from a closed form (cited where it is used), from an independent route
(Jones calculus; Hecht's Fresnel amplitudes written out in this file) or from Mitsuba 3's C++
implementation (``mi.mueller``, ``mi.fresnel_polarized`` in ``scalar_spectral_polarized``, float32).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pbrdf.polar import fresnel, mueller, stokes

PI = np.pi

# Tolerances (STYLE.md section 4). Closed-form float64 optics agree to round-off: 1e-12.
# Mitsuba's scalar variants compute in float32: 2e-5 (measured worst case 3.7e-6, Fresnel r_p at eta 2.4).
ATOL = 1e-12
MI_ATOL = 2e-5

HORIZONTAL = [1.0, 1.0, 0.0, 0.0]
VERTICAL = [1.0, -1.0, 0.0, 0.0]
PLUS_45 = [1.0, 0.0, 1.0, 0.0]
MINUS_45 = [1.0, 0.0, -1.0, 0.0]
RIGHT_CIRCULAR = [1.0, 0.0, 0.0, 1.0]
LEFT_CIRCULAR = [1.0, 0.0, 0.0, -1.0]
UNPOLARIZED = [1.0, 0.0, 0.0, 0.0]

# Real relative IORs, seen from both sides of the interface (1/1.5 is glass-to-air).
DIELECTRIC_ETAS = [1.5, 1 / 1.5, 1.33, 2.4]
# eta = n - ik near 600 nm: gold (notes/polarimetry.md section 5), then rough silver, aluminium, chrome.
CONDUCTOR_ETAS = [0.27 - 2.78j, 0.05 - 3.9j, 1.2 - 7.0j, 2.9 - 3.0j]
# Incidence angle 0..180 deg in 1-deg steps: cos_theta_i from 1 (outside, normal) through 0 (grazing) to
# -1 (inside, normal); covers total internal reflection on the dense side.
SWEEP_COS = np.cos(np.radians(np.linspace(0.0, 180.0, 181)))
OUTSIDE_COS = SWEEP_COS[SWEEP_COS >= 0]


# --- helpers -----------------------------------------------------------------------------------------


def assert_angles_close_mod_pi(actual, expected, atol):
    """Angles of linear polarization are defined modulo pi."""
    d = np.mod(np.asarray(actual) - np.asarray(expected) + PI / 2, PI) - PI / 2
    assert np.all(np.abs(d) <= atol), f"max angle error {np.max(np.abs(d))} > {atol}"


def random_stokes(rng, n):
    """Physical Stokes vectors, valid by construction: s0 in [0.1, 2], any DoP, AoLP and ellipticity."""
    return stokes.stokes(
        rng.uniform(0.1, 2.0, n), rng.uniform(0, 1, n), rng.uniform(0, PI, n), rng.uniform(-PI / 4, PI / 4, n)
    )


def random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_perpendicular(rng, w):
    """Random unit vectors perpendicular to the unit vectors ``w`` (..., 3)."""
    v = rng.normal(size=w.shape)
    v -= np.sum(v * w, axis=-1, keepdims=True) * w
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def assert_pure_mueller(m, atol):
    """Non-depolarizing (Mueller-Jones) matrices satisfy tr(M^T M) = 4 m00^2.

    J. J. Gil and E. Bernabeu, "A depolarization criterion in Mueller matrices", Optica Acta 32(3):259, 1985.
    """
    m = np.asarray(m)
    np.testing.assert_allclose(np.einsum("...ij,...ij->...", m, m), 4 * m[..., 0, 0] ** 2, atol=atol)


def assert_maps_physical_to_physical(m, rng):
    """Stokes criterion: physical input states give physical output states."""
    s_in = random_stokes(rng, 64)
    s_out = mueller.apply(np.asarray(m)[..., None, :, :], s_in)
    assert np.all(stokes.is_physical_stokes(s_out, rtol=1e-9, atol=1e-12))


def assert_mueller_physical(m, rng):
    """Cloude and Givens-Kostinski tests of pbrdf.polar.validity, plus the Stokes criterion done here."""
    from pbrdf.polar import validity

    assert np.all(validity.is_mueller_physical(m))
    assert_maps_physical_to_physical(m, rng)


def jones_rotator(theta):
    """Jones matrix re-expressing a field in a frame rotated by theta (same sense as mueller.rotator)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, s], [-s, c]], dtype=np.complex128)


def jones_rotated(j, theta):
    """Jones matrix of element ``j`` physically rotated by theta: R(-theta) J R(theta)."""
    return jones_rotator(-theta) @ j @ jones_rotator(theta)


def mi_matrix(m):
    return np.array(m, dtype=np.float64)


def mi_vector(mi, v):
    return mi.Vector3f(*(float(x) for x in v))


def mi_complex(mi, z):
    return mi.Complex2f(float(np.real(z)), float(np.imag(z)))


def hecht_fresnel(cos_theta_i, eta):
    """Fresnel amplitudes and power transmittances written out from Hecht, Optics (ch. 4), real eta.

    Media n1 (incident side) and n2: eta = n2 / n1 from outside (cos > 0); from inside (cos < 0) the
    roles swap. r_s = (n1 ci - n2 ct)/(n1 ci + n2 ct), r_p = (n2 ci - n1 ct)/(n2 ci + n1 ct),
    t_s = 2 n1 ci/(n1 ci + n2 ct), t_p = 2 n1 ci/(n2 ci + n1 ct). The transmitted power per unit
    interface area carries the Poynting-vector factor n cos: T = (n2 ct)/(n1 ci) |t|^2.
    Returns (r_s, r_p, T_s, T_p, tir); T is 0 and |r| = 1 under total internal reflection.
    """
    n1, n2 = (1.0, eta) if cos_theta_i >= 0 else (eta, 1.0)
    ci = abs(cos_theta_i)
    sin_t = n1 / n2 * np.sqrt(1 - ci * ci)
    if sin_t > 1:
        return None, None, 0.0, 0.0, True
    ct = np.sqrt(1 - sin_t * sin_t)
    r_s = (n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)
    r_p = (n2 * ci - n1 * ct) / (n2 * ci + n1 * ct)
    t_s = 2 * n1 * ci / (n1 * ci + n2 * ct)
    t_p = 2 * n1 * ci / (n2 * ci + n1 * ct)
    factor = n2 * ct / (n1 * ci)
    return r_s, r_p, factor * t_s**2, factor * t_p**2, False


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
        np.testing.assert_allclose(stokes.stokes(*args), expected, atol=ATOL)

    def test_display_light_convention(self):
        # Convention pin (notes/polarimetry.md section 1): the LCD emits vertical linear light, S1 = -S0;
        # the polarized part LP = -S1 is all of it and unpol = S0 + S1 is zero (the paper's printed
        # unpol = S0 - S1 would give 2 S0).
        s = stokes.stokes(1.0, 1.0, PI / 2, 0.0)
        np.testing.assert_allclose(s, [1.0, -1.0, 0.0, 0.0], atol=ATOL)
        assert -s[1] == pytest.approx(s[0], abs=ATOL)
        assert s[0] + s[1] == pytest.approx(0.0, abs=ATOL)

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
        assert stokes.dop(s) == pytest.approx(p, abs=ATOL)
        assert stokes.dolp(s) == pytest.approx(p * np.cos(2 * chi), abs=ATOL)
        assert stokes.docp(s) == pytest.approx(p * abs(np.sin(2 * chi)), abs=ATOL)
        psi_out, chi_out = stokes.aolp(s), stokes.ellipticity_angle(s)
        assert 0.0 <= psi_out < PI
        assert -PI / 4 <= chi_out <= PI / 4
        # The angles are undefined without a (linear) polarized part; away from that the AoLP error is
        # about eps / (p cos2chi) <= 1e-10 for p cos2chi > 1e-6.
        if p * np.cos(2 * chi) > 1e-6:
            assert_angles_close_mod_pi(psi_out, psi, atol=1e-9)
        if p > 1e-6:
            assert chi_out == pytest.approx(chi, abs=1e-9)

    def test_partially_polarized_values(self):
        # s = [2, 1, 0, 1]: |(s1,s2,s3)| = sqrt 2, |(s1,s2)| = 1, |s3| = 1; AoLP 0; chi = atan2(1, 1)/2 = pi/8.
        s = np.array([2.0, 1.0, 0.0, 1.0])
        assert stokes.dop(s) == pytest.approx(np.sqrt(2) / 2, abs=ATOL)
        assert stokes.dolp(s) == pytest.approx(0.5, abs=ATOL)
        assert stokes.docp(s) == pytest.approx(0.5, abs=ATOL)
        assert stokes.aolp(s) == pytest.approx(0.0, abs=ATOL)
        assert stokes.ellipticity_angle(s) == pytest.approx(PI / 8, abs=ATOL)

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
        np.testing.assert_allclose(out, expected, atol=ATOL)

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


# --- Mueller algebra ---------------------------------------------------------------------------------


class TestApply:
    def test_broadcasts(self, rng):
        s = random_stokes(rng, 5)
        out = mueller.apply(mueller.qwp(0.0), s)
        assert out.shape == (5, 4)
        out = mueller.apply(mueller.rotator(np.zeros((3, 1))), s)
        assert out.shape == (3, 5, 4)

    def test_wrong_shapes_raise(self):
        with pytest.raises(ValueError, match="4, 4"):
            mueller.apply(np.eye(3), UNPOLARIZED)
        with pytest.raises(ValueError, match="4"):
            mueller.apply(np.eye(4), [1.0, 0.0, 0.0])


class TestRetarder:
    # Quarter-wave plate, fast axis horizontal: Goldstein, Polarized Light, 3rd ed., eqs. 6.46-6.47 (also
    # Mitsuba's src/bsdfs/tests/test_retarder.py; the 1st edition by Collett swapped fast and slow axes).
    @pytest.mark.parametrize(
        ("s_in", "s_out"),
        [
            pytest.param(HORIZONTAL, HORIZONTAL, id="horizontal-unchanged"),
            pytest.param(VERTICAL, VERTICAL, id="vertical-unchanged"),
            pytest.param(PLUS_45, LEFT_CIRCULAR, id="plus45-to-left-circular"),
            pytest.param(MINUS_45, RIGHT_CIRCULAR, id="minus45-to-right-circular"),
            pytest.param(RIGHT_CIRCULAR, PLUS_45, id="right-circular-to-plus45"),
            pytest.param(LEFT_CIRCULAR, MINUS_45, id="left-circular-to-minus45"),
        ],
    )
    def test_qwp_state_table(self, s_in, s_out):
        np.testing.assert_allclose(mueller.apply(mueller.qwp(0.0), s_in), s_out, atol=ATOL)

    def test_qwp_general_mapping(self, rng):
        # Convention (pbrdf.polar.mueller docstring, notes/polarimetry.md section 2): [s0,s1,s2,s3] -> [s0,s1,s3,-s2].
        s = random_stokes(rng, 50)
        expected = np.stack([s[:, 0], s[:, 1], s[:, 3], -s[:, 2]], axis=-1)
        np.testing.assert_allclose(mueller.apply(mueller.qwp(0.0), s), expected, atol=ATOL)

    @pytest.mark.parametrize(
        ("s_in", "s_out"),
        [
            pytest.param(PLUS_45, MINUS_45, id="plus45-to-minus45"),
            pytest.param(HORIZONTAL, HORIZONTAL, id="horizontal-unchanged"),
            pytest.param(RIGHT_CIRCULAR, LEFT_CIRCULAR, id="right-to-left-circular"),
        ],
    )
    def test_hwp_state_table(self, s_in, s_out):
        # Half-wave plate, fast axis horizontal: diag(1, 1, -1, -1) (Goldstein 3rd ed., ch. 6).
        np.testing.assert_allclose(mueller.apply(mueller.hwp(0.0), s_in), s_out, atol=ATOL)

    def test_hwp_mirrors_linear_polarization_about_fast_axis(self, rng):
        # A HWP with fast axis theta maps linear light at psi to 2 theta - psi (and flips handedness).
        theta, psi, chi = rng.uniform(0, PI, 20), rng.uniform(0, PI, 20), rng.uniform(-PI / 4, PI / 4, 20)
        out = mueller.apply(mueller.hwp(theta), stokes.stokes(1.0, 1.0, psi, chi))
        assert_angles_close_mod_pi(stokes.aolp(out), 2 * theta - psi, atol=1e-9)
        np.testing.assert_allclose(stokes.ellipticity_angle(out), -chi, atol=1e-9)

    def test_plates_compose(self):
        # Two QWPs make a HWP; four make the identity.
        q = mueller.qwp(0.4)
        np.testing.assert_allclose(q @ q, mueller.hwp(0.4), atol=ATOL)
        np.testing.assert_allclose(np.linalg.matrix_power(q, 4), np.eye(4), atol=ATOL)

    def test_retarder_is_orthogonal(self, rng):
        # A retarder rotates the Poincare sphere: M^T M = I and the DoP is preserved.
        m = mueller.retarder(rng.uniform(0, 2 * PI, 20), rng.uniform(0, PI, 20))
        np.testing.assert_allclose(np.swapaxes(m, -1, -2) @ m, np.broadcast_to(np.eye(4), m.shape), atol=ATOL)


class TestLinearPolarizer:
    ANALYZER_ANGLES = np.linspace(0.0, PI, 37)

    @pytest.mark.parametrize("theta", [0.0, 0.3, PI / 4, PI / 2, 2.0])
    def test_malus_law_ideal(self, theta):
        # Malus' law: a unit fully linearly polarized beam at angle a transmits cos^2(a - theta).
        a = self.ANALYZER_ANGLES
        out = mueller.apply(mueller.linear_polarizer(theta), stokes.stokes(1.0, 1.0, a, 0.0))
        np.testing.assert_allclose(out[:, 0], np.cos(a - theta) ** 2, atol=ATOL)

    @pytest.mark.parametrize("extinction_ratio", [1.0, 2.0, 10.0, 300.0])
    @pytest.mark.parametrize("theta", [0.0, 0.7])
    @pytest.mark.parametrize("q", [1.0, 0.8])
    def test_malus_law_with_extinction_ratio(self, extinction_ratio, theta, q):
        # Diattenuator with transmittances q (along the axis) and r = q / ER (across):
        # I(a) = (q + r)/2 + (q - r)/2 cos 2(a - theta) for unit polarized light at angle a.
        a = self.ANALYZER_ANGLES
        r = q / extinction_ratio
        m = mueller.linear_polarizer(theta, extinction_ratio=extinction_ratio, transmittance=q)
        out = mueller.apply(m, stokes.stokes(1.0, 1.0, a, 0.0))
        np.testing.assert_allclose(out[:, 0], 0.5 * (q + r) + 0.5 * (q - r) * np.cos(2 * (a - theta)), atol=ATOL)

    def test_rotated_closed_form(self):
        # Ideal polarizer at theta: 1/2 [[1,c,s,0],[c,c^2,cs,0],[s,cs,s^2,0],[0,0,0,0]], c = cos 2theta,
        # s = sin 2theta (Goldstein, Polarized Light, 3rd ed., ch. 6; notes/polarimetry.md section 2).
        theta = np.linspace(-PI, PI, 25)
        c, s, z = np.cos(2 * theta), np.sin(2 * theta), np.zeros_like(theta)
        expected = 0.5 * np.stack(
            [np.stack(row, axis=-1) for row in ([1 + z, c, s, z], [c, c * c, c * s, z], [s, c * s, s * s, z], [z] * 4)],
            axis=-2,
        )
        np.testing.assert_allclose(mueller.linear_polarizer(theta), expected, atol=ATOL)

    def test_equals_rotated_element(self):
        theta = np.linspace(-PI, PI, 25)
        np.testing.assert_allclose(
            mueller.linear_polarizer(theta), mueller.rotate_element(mueller.linear_polarizer(0.0), theta), atol=ATOL
        )

    def test_output_is_linear_along_axis(self, rng):
        theta = rng.uniform(0, PI, 50)
        out = mueller.apply(mueller.linear_polarizer(theta), random_stokes(rng, 50))
        np.testing.assert_allclose(stokes.dolp(out), 1.0, atol=1e-9)
        assert_angles_close_mod_pi(stokes.aolp(out), theta, atol=1e-9)

    def test_unpolarized_input(self):
        # Unpolarized light: transmitted intensity (q + r)/2, DoLP = diattenuation (q - r)/(q + r).
        out = mueller.apply(mueller.linear_polarizer(0.3, extinction_ratio=9.0), UNPOLARIZED)
        assert out[0] == pytest.approx(0.5 * (1 + 1 / 9), abs=ATOL)
        assert stokes.dolp(out) == pytest.approx(0.8, abs=ATOL)

    def test_extinction_ratio_below_one_raises(self):
        with pytest.raises(ValueError, match="extinction_ratio"):
            mueller.linear_polarizer(0.0, extinction_ratio=0.5)


class TestLinearDiattenuator:
    @pytest.mark.parametrize("q", [0.0, 0.3, 1.0])
    def test_equal_transmittances_is_neutral_density(self, q):
        np.testing.assert_allclose(mueller.linear_diattenuator(q, q, 0.7), q * np.eye(4), atol=ATOL)

    def test_ideal_polarizer_limit(self):
        np.testing.assert_allclose(mueller.linear_diattenuator(1.0, 0.0, 0.4), mueller.linear_polarizer(0.4), atol=ATOL)

    def test_is_pure(self, rng):
        m = mueller.linear_diattenuator(rng.uniform(0, 1, 20), rng.uniform(0, 1, 20), rng.uniform(0, PI, 20))
        assert_pure_mueller(m, atol=ATOL)

    def test_negative_transmittance_raises(self):
        with pytest.raises(ValueError, match="q and r"):
            mueller.linear_diattenuator(-0.1, 0.5)


class TestRotator:
    def test_composition(self, rng):
        a, b = rng.uniform(-PI, PI, (2, 30))
        np.testing.assert_allclose(mueller.rotator(a) @ mueller.rotator(b), mueller.rotator(a + b), atol=ATOL)

    def test_half_turn_is_identity(self):
        # Stokes parameters depend on 2 theta: a frame turned by pi is the same frame.
        np.testing.assert_allclose(mueller.rotator(PI), np.eye(4), atol=ATOL)
        np.testing.assert_allclose(mueller.rotator(-PI), np.eye(4), atol=ATOL)

    def test_frame_rotation_example(self):
        # Mitsuba's rotator docstring: horizontal light read in a frame rotated by +45 deg is -45 deg light.
        np.testing.assert_allclose(mueller.apply(mueller.rotator(PI / 4), HORIZONTAL), MINUS_45, atol=ATOL)

    def test_shifts_aolp_keeps_ellipticity(self, rng):
        # A frame turned by t sees AoLP psi - t; intensity, DoP and ellipticity are frame invariant.
        t, psi, chi = rng.uniform(-PI, PI, 30), rng.uniform(0, PI, 30), rng.uniform(-PI / 4, PI / 4, 30)
        s = stokes.stokes(1.0, 0.8, psi, chi)
        out = mueller.apply(mueller.rotator(t), s)
        assert_angles_close_mod_pi(stokes.aolp(out), psi - t, atol=1e-9)
        np.testing.assert_allclose(stokes.ellipticity_angle(out), chi, atol=1e-9)
        np.testing.assert_allclose(stokes.dop(out), 0.8, atol=1e-9)

    def test_rotate_element_by_half_turn_is_unchanged(self, rng):
        m = rng.normal(size=(4, 4))
        np.testing.assert_allclose(mueller.rotate_element(m, PI), m, atol=ATOL)


class TestBatchedShapes:
    THETA = np.linspace(0.0, PI, 15).reshape(5, 3)

    @pytest.mark.parametrize(
        "build",
        [
            pytest.param(mueller.rotator, id="rotator"),
            pytest.param(mueller.linear_polarizer, id="linear_polarizer"),
            pytest.param(lambda t: mueller.linear_polarizer(t, extinction_ratio=100.0), id="polarizer-er"),
            pytest.param(lambda t: mueller.linear_diattenuator(0.9, 0.2, t), id="diattenuator"),
            pytest.param(lambda t: mueller.retarder(0.3, t), id="retarder"),
            pytest.param(mueller.qwp, id="qwp"),
            pytest.param(mueller.hwp, id="hwp"),
            pytest.param(lambda t: mueller.rotate_element(mueller.qwp(0.0), t), id="rotate_element"),
        ],
    )
    def test_shape_and_float32(self, build):
        m64 = build(self.THETA)
        assert m64.shape == (5, 3, 4, 4)
        m32 = build(self.THETA.astype(np.float32))
        assert m32.shape == (5, 3, 4, 4)
        assert np.all(np.isfinite(m32))
        np.testing.assert_allclose(m32, m64, atol=1e-6)  # float32 round-off


class TestDepolarizer:
    def test_full_depolarizer_outputs_unpolarized(self, rng):
        s = random_stokes(rng, 50)
        out = mueller.apply(mueller.depolarizer(0.0), s)
        np.testing.assert_array_equal(out[:, 1:], 0.0)
        np.testing.assert_array_equal(out[:, 0], s[:, 0])

    def test_partial_scales_dop(self, rng):
        s = random_stokes(rng, 50)
        out = mueller.apply(mueller.depolarizer(0.3), s)
        np.testing.assert_allclose(stokes.dop(out), 0.3 * stokes.dop(s), atol=ATOL)

    def test_per_component_factors(self):
        np.testing.assert_allclose(mueller.diagonal_depolarizer(0.1, 0.2, 0.3), np.diag([1.0, 0.1, 0.2, 0.3]), atol=0)

    def test_batched(self):
        a = np.linspace(0, 1, 10).reshape(5, 2)
        m = mueller.depolarizer(a)
        assert m.shape == (5, 2, 4, 4)
        np.testing.assert_allclose(m[..., 1, 1], a, atol=0)
        assert mueller.depolarizer(np.full((5, 3), 0.5)).shape == (5, 3, 4, 4)
        m32 = mueller.depolarizer(a.astype(np.float32))
        assert np.all(np.isfinite(m32))
        np.testing.assert_allclose(m32, m, atol=1e-6)

    def test_out_of_range_raises(self):
        with pytest.raises(ValueError, match="depolarizer"):
            mueller.depolarizer(1.5)


class TestJonesToMueller:
    # Independent route: build the element as a 2x2 Jones matrix and convert (no depolarization).

    @pytest.mark.parametrize("theta", [0.0, 0.4, PI / 4, 2.5, -1.0])
    def test_rotation(self, theta):
        np.testing.assert_allclose(mueller.jones_to_mueller(jones_rotator(theta)), mueller.rotator(theta), atol=ATOL)

    @pytest.mark.parametrize("delta", [0.0, PI / 2, PI, 1.1, 4.0])
    @pytest.mark.parametrize("theta", [0.0, 0.4, PI / 4, 2.5])
    def test_retarder(self, delta, theta):
        # Jones retarder, fast axis horizontal: diag(1, exp(-i delta)) with the module's Jones convention
        # (E = (1, i)/sqrt 2 is right circular).
        j = jones_rotated(np.diag([1.0, np.exp(-1j * delta)]), theta)
        np.testing.assert_allclose(mueller.jones_to_mueller(j), mueller.retarder(delta, theta), atol=ATOL)

    @pytest.mark.parametrize("theta", [0.0, 0.4, 2.5])
    def test_diattenuator_and_polarizer(self, theta):
        q, r = 0.81, 0.09  # amplitudes 0.9 and 0.3
        j = jones_rotated(np.diag([np.sqrt(q), np.sqrt(r)]).astype(complex), theta)
        np.testing.assert_allclose(mueller.jones_to_mueller(j), mueller.linear_diattenuator(q, r, theta), atol=ATOL)
        j = jones_rotated(np.diag([1.0, 0.0]).astype(complex), theta)
        np.testing.assert_allclose(mueller.jones_to_mueller(j), mueller.linear_polarizer(theta), atol=ATOL)

    def test_right_circular_polarizer_convention(self):
        # Projector onto E = (1, i)/sqrt 2: the right circular polarizer 1/2 [[1,0,0,1],0,0,[1,0,0,1]]
        # (Chipman, Lam, Young, Polarized Light and Optical Systems, Table 6.2; Mitsuba's
        # right_circular_polarizer). Pins s3 = -2 Im(Ex Ey*) > 0 for right circular.
        e = np.array([1.0, 1j]) / np.sqrt(2)
        m = mueller.jones_to_mueller(np.outer(e, e.conj()))
        expected = 0.5 * np.array([[1, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 1]], dtype=float)
        np.testing.assert_allclose(m, expected, atol=ATOL)

    def test_multiplicative(self, rng):
        j1, j2 = rng.normal(size=(2, 10, 2, 2)) + 1j * rng.normal(size=(2, 10, 2, 2))
        m12 = mueller.jones_to_mueller(j1 @ j2)
        assert m12.shape == (10, 4, 4)
        np.testing.assert_allclose(m12, mueller.jones_to_mueller(j1) @ mueller.jones_to_mueller(j2), atol=1e-11)

    def test_random_jones_are_pure_and_physical(self, rng):
        j = rng.normal(size=(20, 2, 2)) + 1j * rng.normal(size=(20, 2, 2))
        m = mueller.jones_to_mueller(j)
        assert_pure_mueller(m, atol=1e-10)
        assert_mueller_physical(m, rng)

    def test_wrong_shape_raises(self):
        with pytest.raises(ValueError, match="2, 2"):
            mueller.jones_to_mueller(np.eye(3))


class TestStokesBasisGeometry:
    def test_basis_is_unit_and_perpendicular(self, rng):
        w = np.concatenate([random_unit(rng, 200), np.eye(3), -np.eye(3)])
        x = mueller.stokes_basis(w)
        np.testing.assert_allclose(np.linalg.norm(x, axis=-1), 1.0, atol=ATOL)
        np.testing.assert_allclose(np.sum(x * w, axis=-1), 0.0, atol=ATOL)

    def test_rotate_stokes_basis_docstring_example(self):
        # Mitsuba's rotate_stokes_basis docstring: horizontal light [1,1,0,0] in basis x = (1,0,0)
        # (travelling along +z) is +45 deg light in the target basis (0.707, -0.707, 0).
        m = mueller.rotate_stokes_basis([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [np.sqrt(0.5), -np.sqrt(0.5), 0.0])
        np.testing.assert_allclose(mueller.apply(m, HORIZONTAL), PLUS_45, atol=ATOL)

    def test_rotate_stokes_basis_matches_field_geometry(self, rng):
        # Independent route: a linearly polarized field along p (perpendicular to the direction f) has, in a
        # frame with x-axis b and y = f x b, the angle psi = atan2(p.y, p.x), hence [1, cos2psi, sin2psi, 0].
        n = 100
        f = random_unit(rng, n)
        cur, tgt, p = (random_perpendicular(rng, f) for _ in range(3))

        def linear_stokes(x_axis):
            y_axis = np.cross(f, x_axis)
            psi = np.arctan2(np.sum(p * y_axis, -1), np.sum(p * x_axis, -1))
            return stokes.stokes(1.0, 1.0, psi, 0.0)

        m = mueller.rotate_stokes_basis(f, cur, tgt)
        # arccos loses accuracy near 0 and pi (about sqrt(eps) ~ 1e-8 there); 1e-7 covers random frames.
        np.testing.assert_allclose(mueller.apply(m, linear_stokes(cur)), linear_stokes(tgt), atol=1e-7)

    def test_rotate_mueller_basis_identity_frames(self, rng):
        f_in, f_out = random_unit(rng, 2)
        b_in, b_out = random_perpendicular(rng, f_in), random_perpendicular(rng, f_out)
        m = rng.normal(size=(4, 4))
        np.testing.assert_allclose(mueller.rotate_mueller_basis(m, f_in, b_in, b_in, f_out, b_out, b_out), m, atol=ATOL)


class TestMuellerAgainstMitsuba:
    # Mitsuba 3.9.1's mi.mueller takes radians. Its linear_retarder(phase) has only the retardance
    # (fast axis horizontal, checked with help()); rotated_element(theta, M) rotates it. Only the
    # mitsuba *plugins* (polarizer, retarder) take degrees.

    def test_rotator(self, mitsuba_polarized):
        mi = mitsuba_polarized
        for theta in np.linspace(-PI, PI, 37):
            np.testing.assert_allclose(
                mueller.rotator(theta), mi_matrix(mi.mueller.rotator(float(theta))), atol=MI_ATOL
            )

    @pytest.mark.parametrize("value", [1.0, 0.8, 0.3])
    def test_linear_polarizer(self, mitsuba_polarized, value):
        mi = mitsuba_polarized
        expected = mi_matrix(mi.mueller.linear_polarizer(value))
        np.testing.assert_allclose(mueller.linear_polarizer(0.0, transmittance=value), expected, atol=MI_ATOL)

    def test_linear_retarder(self, mitsuba_polarized):
        mi = mitsuba_polarized
        for delta in np.linspace(0.0, 2 * PI, 25):
            expected = mi_matrix(mi.mueller.linear_retarder(float(delta)))
            np.testing.assert_allclose(mueller.retarder(delta), expected, atol=MI_ATOL)
            for theta in (0.3, PI / 4, 2.0):
                expected = mi_matrix(mi.mueller.rotated_element(float(theta), mi.mueller.linear_retarder(float(delta))))
                np.testing.assert_allclose(mueller.retarder(delta, theta), expected, atol=MI_ATOL)

    def test_rotated_element(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        for theta in rng.uniform(-PI, PI, 10):
            m = rng.uniform(-1, 1, (4, 4))
            expected = mi_matrix(mi.mueller.rotated_element(float(theta), mi.Matrix4f(m)))
            np.testing.assert_allclose(mueller.rotate_element(m, theta), expected, atol=MI_ATOL)

    def test_right_circular_polarizer(self, mitsuba_polarized):
        mi = mitsuba_polarized
        e = np.array([1.0, 1j]) / np.sqrt(2)
        expected = mi_matrix(mi.mueller.right_circular_polarizer())
        np.testing.assert_allclose(mueller.jones_to_mueller(np.outer(e, e.conj())), expected, atol=MI_ATOL)

    def test_stokes_basis(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        # Directions in the z = 0 plane with z = +0.0 and -0.0: Mitsuba takes -0.0 as the z < 0 branch
        # (its basis is then -x of the z = +0.0 one; the same Stokes frame, but a different vector).
        flat = random_unit(rng, 20) * [1.0, 1.0, 0.0]
        flat /= np.linalg.norm(flat, axis=-1, keepdims=True)
        w = np.concatenate([random_unit(rng, 100), np.eye(3), -np.eye(3), flat, flat * [1.0, 1.0, -1.0]])
        assert np.signbit(w[-1, 2])
        ours = mueller.stokes_basis(w)
        for wi, xi in zip(w, ours, strict=True):
            np.testing.assert_allclose(xi, np.array(mi.mueller.stokes_basis(mi_vector(mi, wi))), atol=MI_ATOL)

    def test_rotate_stokes_basis(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        f = random_unit(rng, 100)
        cur = mueller.stokes_basis(f)
        tgt = random_perpendicular(rng, f)
        ours = mueller.rotate_stokes_basis(f, cur, tgt)
        for k in range(len(f)):
            expected = mi.mueller.rotate_stokes_basis(mi_vector(mi, f[k]), mi_vector(mi, cur[k]), mi_vector(mi, tgt[k]))
            np.testing.assert_allclose(ours[k], mi_matrix(expected), atol=MI_ATOL)

    def test_rotate_mueller_basis(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        n = 50
        m = rng.uniform(-1, 1, (n, 4, 4))
        f_in, f_out = random_unit(rng, n), random_unit(rng, n)
        args = (f_in, mueller.stokes_basis(f_in), random_perpendicular(rng, f_in))
        args += (f_out, mueller.stokes_basis(f_out), random_perpendicular(rng, f_out))
        ours = mueller.rotate_mueller_basis(m, *args)
        for k in range(n):
            expected = mi.mueller.rotate_mueller_basis(mi.Matrix4f(m[k]), *(mi_vector(mi, a[k]) for a in args))
            np.testing.assert_allclose(ours[k], mi_matrix(expected), atol=MI_ATOL)


# --- Fresnel -----------------------------------------------------------------------------------------


class TestFresnelAmplitudes:
    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS + CONDUCTOR_ETAS)
    def test_normal_incidence(self, eta):
        # R0 = |(eta - 1)/(eta + 1)|^2 (= ((n-1)/(n+1))^2 for a dielectric); Verdet signs: r_p = -r_s.
        r_s, r_p, cos_t = fresnel.fresnel_amplitudes(1.0, eta)
        r0 = abs((eta - 1) / (eta + 1)) ** 2
        assert abs(r_s) ** 2 == pytest.approx(r0, abs=ATOL)
        assert r_p == pytest.approx(-r_s, abs=ATOL)
        assert cos_t == pytest.approx(1.0, abs=ATOL)
        assert fresnel.fresnel_reflectance(1.0, eta) == pytest.approx(r0, abs=ATOL)

    @pytest.mark.parametrize("eta", [1.5, 1.33, 2.4])
    def test_normal_incidence_from_inside(self, eta):
        # The same R0 from both sides: ((1/n - 1)/(1/n + 1))^2 = ((n - 1)/(n + 1))^2.
        assert fresnel.fresnel_reflectance(-1.0, eta) == pytest.approx(((eta - 1) / (eta + 1)) ** 2, abs=ATOL)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_matches_hecht_and_snell(self, eta):
        # Same amplitudes as Hecht's (helper above; Hecht's r_parallel sign is the Verdet one), and the
        # transmitted cosine obeys Snell's law sin_t = sin_i / eta_eff; |r| = 1 under TIR.
        r_s, r_p, cos_t = fresnel.fresnel_amplitudes(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            h_s, h_p, _, _, tir = hecht_fresnel(c, eta)
            if tir:
                assert abs(r_s[k]) == pytest.approx(1.0, abs=ATOL)
                assert abs(r_p[k]) == pytest.approx(1.0, abs=ATOL)
                assert cos_t[k].imag < 0  # decaying evanescent wave, Mitsuba's branch
                continue
            assert r_s[k] == pytest.approx(h_s, abs=ATOL)
            assert r_p[k] == pytest.approx(h_p, abs=ATOL)
            eta_eff = eta if c >= 0 else 1 / eta
            assert np.sqrt(1 - cos_t[k].real ** 2) == pytest.approx(np.sqrt(1 - c * c) / eta_eff, abs=1e-9)

    @pytest.mark.parametrize("eta", CONDUCTOR_ETAS)
    def test_conjugate_eta_convention(self, eta):
        # eta = n + ik is read as n - ik (tables with either sign work).
        ours = fresnel.fresnel_amplitudes(OUTSIDE_COS, eta)
        conj = fresnel.fresnel_amplitudes(OUTSIDE_COS, np.conj(eta))
        for a, b in zip(ours, conj, strict=True):
            np.testing.assert_array_equal(a, b)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_against_mitsuba_dielectric(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        r_s, r_p, cos_t = fresnel.fresnel_amplitudes(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            a_s, a_p, mi_cos_t, _, _ = mi.fresnel_polarized(float(c), mi_complex(mi, eta))
            assert complex(a_s.real, a_s.imag) == pytest.approx(r_s[k], abs=MI_ATOL)
            assert complex(a_p.real, a_p.imag) == pytest.approx(r_p[k], abs=MI_ATOL)
            # Mitsuba returns the real cosine of the refracted direction (sign opposite to cos_i, 0 under TIR).
            assert abs(mi_cos_t) == pytest.approx(cos_t[k].real, abs=MI_ATOL)

    @pytest.mark.parametrize("eta", CONDUCTOR_ETAS)
    def test_against_mitsuba_conductor(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        r_s, r_p, _ = fresnel.fresnel_amplitudes(OUTSIDE_COS, eta)
        for k, c in enumerate(OUTSIDE_COS):
            a_s, a_p, _, _, _ = mi.fresnel_polarized(float(c), mi_complex(mi, eta))
            assert complex(a_s.real, a_s.imag) == pytest.approx(r_s[k], abs=MI_ATOL)
            assert complex(a_p.real, a_p.imag) == pytest.approx(r_p[k], abs=MI_ATOL)


class TestReflectionMueller:
    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS + CONDUCTOR_ETAS)
    def test_mirror_at_normal_incidence(self, eta):
        # r_p = -r_s at normal incidence: R0 diag(1, 1, -1, -1), the mirror flips S2 and S3 (notes section 5).
        r0 = abs((eta - 1) / (eta + 1)) ** 2
        np.testing.assert_allclose(fresnel.reflection_mueller(1.0, eta), r0 * np.diag([1.0, 1, -1, -1]), atol=ATOL)

    @pytest.mark.parametrize("n", [1.33, 1.5, 2.4])
    @pytest.mark.parametrize("side", ["outside", "inside"])
    def test_brewster_angle(self, n, side):
        # Brewster: tan theta_B = eta_eff, R_p = 0; theta_i + theta_t = 90 deg gives
        # R_s = sin^2(theta_i - theta_t) = cos^2(2 theta_B) = ((eta^2 - 1)/(eta^2 + 1))^2.
        eta_eff = n if side == "outside" else 1 / n
        cos_b = np.cos(np.arctan(eta_eff)) * (1 if side == "outside" else -1)
        m = fresnel.reflection_mueller(cos_b, n)
        r_s = ((eta_eff**2 - 1) / (eta_eff**2 + 1)) ** 2
        assert m[0, 0] == pytest.approx(m[0, 1], abs=ATOL)  # m00 - m01 = R_p = 0
        assert m[0, 0] == pytest.approx(r_s / 2, abs=ATOL)
        out = mueller.apply(m, UNPOLARIZED)
        assert stokes.dolp(out) == pytest.approx(1.0, abs=1e-9)
        assert out[1] > 0  # s-polarized: the Stokes x-axis is perpendicular to the plane of incidence

    def test_gold_makes_circular_polarization(self):
        # Gold eta = 0.27 - 2.78i at 60 deg, +45 deg linear in: S = (.880, .063, -.513, .712), S3 > 0 (right
        # circular); notes/polarimetry.md section 5, verified against Mitsuba's specular_reflection (3 decimals).
        out = mueller.apply(fresnel.reflection_mueller(np.cos(np.radians(60)), 0.27 - 2.78j), PLUS_45)
        np.testing.assert_allclose(out, [0.880, 0.063, -0.513, 0.712], atol=1e-3)
        assert out[3] > 0
        # The same metal written n + ik gives the same light (conjugation convention).
        np.testing.assert_array_equal(
            mueller.apply(fresnel.reflection_mueller(np.cos(np.radians(60)), 0.27 + 2.78j), PLUS_45), out
        )

    def test_gold_keeps_s_and_p_linear(self):
        # s- and p-polarized light are eigenstates of reflection: they stay linear (notes section 5).
        m = fresnel.reflection_mueller(np.cos(np.radians(60)), 0.27 - 2.78j)
        for s_in in (HORIZONTAL, VERTICAL):
            out = mueller.apply(m, s_in)
            np.testing.assert_allclose(out[2:], 0.0, atol=ATOL)
            assert stokes.dolp(out) == pytest.approx(1.0, abs=1e-9)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_dielectric_makes_no_circular_polarization(self, eta):
        # Real eta without TIR: r_s and r_p are real, Im(r_s r_p*) = 0, so linear light stays linear.
        c = SWEEP_COS[[not hecht_fresnel(c, eta)[4] for c in SWEEP_COS]]
        out = mueller.apply(fresnel.reflection_mueller(c, eta), PLUS_45)
        np.testing.assert_allclose(out[:, 3], 0.0, atol=ATOL)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_total_internal_reflection_is_a_retarder(self, eta):
        # Under TIR all light is reflected (|r_s| = |r_p| = 1), only the s-p phase changes.
        tir = np.array([hecht_fresnel(c, eta)[4] for c in SWEEP_COS])
        assert tir.any()  # every eta != 1 has a dense side
        m = fresnel.reflection_mueller(SWEEP_COS[tir], eta)
        np.testing.assert_allclose(m[:, 0, 0], 1.0, atol=ATOL)
        np.testing.assert_allclose(m[:, 0, 1], 0.0, atol=ATOL)
        assert_pure_mueller(m, atol=1e-12)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS + CONDUCTOR_ETAS)
    def test_unpolarized_reflectance(self, eta):
        # Unpolarized light reflects the scalar Fresnel reflectance (R_s + R_p)/2.
        c = SWEEP_COS if np.isreal(eta) else OUTSIDE_COS
        out = mueller.apply(fresnel.reflection_mueller(c, eta), UNPOLARIZED)
        np.testing.assert_allclose(out[:, 0], fresnel.fresnel_reflectance(c, eta), atol=ATOL)

    def test_physical(self, rng):
        ms = [fresnel.reflection_mueller(SWEEP_COS, eta) for eta in DIELECTRIC_ETAS]
        ms += [fresnel.reflection_mueller(OUTSIDE_COS, eta) for eta in CONDUCTOR_ETAS]
        m = np.concatenate(ms)
        assert np.all(m[:, 0, 0] > 0)
        assert_pure_mueller(m, atol=1e-12)
        assert_mueller_physical(m, rng)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_against_mitsuba_dielectric(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        ours = fresnel.reflection_mueller(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            expected = mi_matrix(mi.mueller.specular_reflection(float(c), mi_complex(mi, eta)))
            np.testing.assert_allclose(ours[k], expected, atol=MI_ATOL)

    @pytest.mark.parametrize("eta", CONDUCTOR_ETAS)
    def test_against_mitsuba_conductor(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        ours = fresnel.reflection_mueller(OUTSIDE_COS, eta)
        for k, c in enumerate(OUTSIDE_COS):
            expected = mi_matrix(mi.mueller.specular_reflection(float(c), mi_complex(mi, eta)))
            np.testing.assert_allclose(ours[k], expected, atol=MI_ATOL)


class TestTransmissionMueller:
    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_energy_conservation(self, eta):
        # Independent route (hecht_fresnel): T_s,p = (n2 cos_t)/(n1 cos_i) |t_s,p|^2 (power through the
        # interface; Poynting vector normal component), R_s,p = |r_s,p|^2, R + T = 1 per polarization.
        # Mueller form: m00 = (T_s + T_p)/2, m01 = (T_s - T_p)/2, m22 = m33 = sqrt(T_s T_p) (real t's).
        # Both sides of the interface, TIR included; exact grazing (cos = 0) is left to the stress tests.
        c = SWEEP_COS[np.abs(SWEEP_COS) > 1e-3]
        refl, trans = fresnel.reflection_mueller(c, eta), fresnel.transmission_mueller(c, eta)
        for k, ck in enumerate(c):
            h_s, h_p, t_s, t_p, tir = hecht_fresnel(ck, eta)
            if tir:
                np.testing.assert_allclose(trans[k], 0.0, atol=0)
                assert refl[k, 0, 0] == pytest.approx(1.0, abs=ATOL)
                continue
            assert h_s**2 + t_s == pytest.approx(1.0, abs=ATOL)  # the derivation itself
            assert h_p**2 + t_p == pytest.approx(1.0, abs=ATOL)
            assert trans[k, 0, 0] == pytest.approx(0.5 * (t_s + t_p), abs=ATOL)
            assert trans[k, 0, 1] == pytest.approx(0.5 * (t_s - t_p), abs=ATOL)
            assert trans[k, 2, 2] == pytest.approx(np.sqrt(t_s * t_p), abs=ATOL)
        # Any input state: the reflected plus the transmitted intensity is the incident intensity.
        np.testing.assert_allclose(refl[:, 0, :] + trans[:, 0, :], np.broadcast_to(UNPOLARIZED, (len(c), 4)), atol=ATOL)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_is_a_pure_diattenuator(self, eta, rng):
        m = fresnel.transmission_mueller(SWEEP_COS, eta)
        np.testing.assert_allclose(m[:, 2:, :2], 0.0, atol=0)  # no retardance
        np.testing.assert_allclose(m[:, :2, 2:], 0.0, atol=0)
        assert_pure_mueller(m, atol=1e-12)
        m = m[m[:, 0, 0] > 1e-6]  # drop TIR and grazing (zero matrices are not Cloude-physical)
        assert_mueller_physical(m, rng)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_against_mitsuba(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        ours = fresnel.transmission_mueller(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            expected = mi_matrix(mi.mueller.specular_transmission(float(c), float(eta)))
            np.testing.assert_allclose(ours[k], expected, atol=MI_ATOL)

    @pytest.mark.parametrize("eta", [0.27 - 2.78j, 1.5 + 0.01j, 1.5 - 1e-9j])
    def test_complex_eta_raises(self, eta):
        with pytest.raises(ValueError, match="real eta"):
            fresnel.transmission_mueller(0.5, eta)


class TestFresnelNumericalStress:
    # Grazing down to the smallest subnormal: transmission must not divide round-off by cos_i.
    COS = [0.0, 1e-12, -1e-12, 1.0, -1.0, 1e-30, -1e-30, 1e-300, 5e-324, -5e-324]
    REAL_ETAS = [1.0, 1.0000001, 1e3, 1e-3]
    COMPLEX_ETAS = [1e3 - 1e3j, 1e-3 - 1e3j, 1e-3 - 1e-3j, 1.5 - 1e-9j]
    BOUND_TOL = 1e-9

    def _check_reflection(self, c, eta):
        r_s, r_p, cos_t = fresnel.fresnel_amplitudes(c, eta)
        assert np.all(np.isfinite(r_s)) and np.all(np.isfinite(r_p)) and np.all(np.isfinite(cos_t))
        m = fresnel.reflection_mueller(c, eta)
        assert np.all(np.isfinite(m))
        assert np.all((m[..., 0, 0] >= -self.BOUND_TOL) & (m[..., 0, 0] <= 1 + self.BOUND_TOL))
        # s and p reflectances m00 +- m01 individually in [0, 1]
        for r in (m[..., 0, 0] + m[..., 0, 1], m[..., 0, 0] - m[..., 0, 1]):
            assert np.all((r >= -self.BOUND_TOL) & (r <= 1 + self.BOUND_TOL))
        assert_pure_mueller(m, atol=self.BOUND_TOL)
        return m

    def _check_transmission(self, c, eta, refl):
        t = fresnel.transmission_mueller(c, eta)
        assert np.all(np.isfinite(t))
        for tt in (t[..., 0, 0], t[..., 0, 0] + t[..., 0, 1], t[..., 0, 0] - t[..., 0, 1]):
            assert np.all((tt >= -self.BOUND_TOL) & (tt <= 1 + self.BOUND_TOL))
        # Energy: R + T = 1 for every input state, grazing incidence included (R = 1, T = 0 there).
        np.testing.assert_allclose(
            refl[..., 0, :2] + t[..., 0, :2], np.broadcast_to([1.0, 0.0], t.shape[:-2] + (2,)), atol=self.BOUND_TOL
        )

    @pytest.mark.filterwarnings("error")
    @pytest.mark.parametrize("eta", REAL_ETAS)
    @pytest.mark.parametrize("c", COS)
    def test_extreme_dielectric(self, c, eta):
        self._check_transmission(c, eta, self._check_reflection(c, eta))

    @pytest.mark.filterwarnings("error")
    @pytest.mark.parametrize("eta", COMPLEX_ETAS)
    @pytest.mark.parametrize("c", [cc for cc in COS if cc >= 0])
    def test_extreme_conductor(self, c, eta):
        self._check_reflection(c, eta)

    @pytest.mark.filterwarnings("error")
    def test_index_matched_interface(self):
        # eta = 1 is no interface: nothing reflects and everything passes, at every angle (Mitsuba also
        # returns zero amplitudes). This used to give 0/0 at grazing and R = 1 for |cos| < 1e-8.
        c = np.array([0.0, 1e-300, 1e-12, -1e-12, 1e-9, 0.5, -0.5, 1.0, -1.0])
        np.testing.assert_array_equal(fresnel.reflection_mueller(c, 1.0), 0.0)
        np.testing.assert_array_equal(fresnel.transmission_mueller(c, 1.0), np.broadcast_to(np.eye(4), (len(c), 4, 4)))

    @pytest.mark.filterwarnings("error")
    @settings(deadline=None, max_examples=300)
    @given(c=st.floats(-1.0, 1.0), log_eta=st.floats(-3.0, 3.0))
    def test_random_dielectric(self, c, log_eta):
        eta = 10.0**log_eta
        self._check_transmission(c, eta, self._check_reflection(c, eta))

    @pytest.mark.filterwarnings("error")
    @settings(deadline=None, max_examples=300)
    @given(c=st.floats(0.0, 1.0), log_n=st.floats(-3.0, 3.0), log_k=st.floats(-6.0, 3.0))
    def test_random_conductor(self, c, log_n, log_k):
        self._check_reflection(c, 10.0**log_n - 1j * 10.0**log_k)

    def test_batched_broadcast(self):
        c = np.linspace(-1, 1, 7)[:, None]
        eta = np.array([1.5, 2.4, 1.0])
        assert fresnel.reflection_mueller(c, eta).shape == (7, 3, 4, 4)
        assert fresnel.transmission_mueller(c, eta).shape == (7, 3, 4, 4)
        assert fresnel.fresnel_reflectance(c.astype(np.float32), eta).shape == (7, 3)

    @pytest.mark.parametrize("eta", [0.0, -1.5, -0.5 - 2j, 0.0 - 2j, [1.5, -1.0]])
    @pytest.mark.parametrize(
        "fn", [fresnel.fresnel_amplitudes, fresnel.fresnel_reflectance, fresnel.reflection_mueller]
    )
    def test_invalid_eta_raises(self, fn, eta):
        with pytest.raises(ValueError, match="eta"):
            fn(0.5, eta)

    @pytest.mark.parametrize("eta", [0.0, -1.5, [1.5, -1.0]])
    def test_invalid_eta_raises_transmission(self, eta):
        with pytest.raises(ValueError, match="eta"):
            fresnel.transmission_mueller(0.5, eta)
