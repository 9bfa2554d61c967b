"""Physics tests of pbrdf.polar.mueller: optical elements and Stokes-frame rotations.

Every expected value comes from a closed form (cited where it is used), from an independent route
(Jones calculus) or from Mitsuba 3's C++ implementation (``mi.mueller`` in
``scalar_spectral_polarized``, float32).
"""

from __future__ import annotations

import numpy as np
import pytest

from pbrdf.polar import mueller, stokes
from tests.conftest import TOL
from tests.helpers import (
    HORIZONTAL,
    LEFT_CIRCULAR,
    MINUS_45,
    PLUS_45,
    RIGHT_CIRCULAR,
    UNPOLARIZED,
    VERTICAL,
    assert_angles_close_mod_pi,
    assert_mueller_physical,
    assert_pure_mueller,
    mi_matrix,
    random_stokes,
)

PI = np.pi


# --- helpers (shared ones, and the named Stokes states, are in tests/helpers.py) ---------------------


def random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_perpendicular(rng, w):
    """Random unit vectors perpendicular to the unit vectors ``w`` (..., 3)."""
    v = rng.normal(size=w.shape)
    v -= np.sum(v * w, axis=-1, keepdims=True) * w
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def jones_rotator(theta):
    """Jones matrix re-expressing a field in a frame rotated by theta (same sense as mueller.rotator)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, s], [-s, c]], dtype=np.complex128)


def jones_rotated(j, theta):
    """Jones matrix of element ``j`` physically rotated by theta: R(-theta) J R(theta)."""
    return jones_rotator(-theta) @ j @ jones_rotator(theta)


def mi_vector(mi, v):
    return mi.Vector3f(*(float(x) for x in v))


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
        np.testing.assert_allclose(mueller.apply(mueller.qwp(0.0), s_in), s_out, atol=TOL.f64)

    def test_qwp_general_mapping(self, rng):
        # Convention (pbrdf.polar.mueller docstring): [s0,s1,s2,s3] -> [s0,s1,s3,-s2].
        s = random_stokes(rng, 50)
        expected = np.stack([s[:, 0], s[:, 1], s[:, 3], -s[:, 2]], axis=-1)
        np.testing.assert_allclose(mueller.apply(mueller.qwp(0.0), s), expected, atol=TOL.f64)

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
        np.testing.assert_allclose(mueller.apply(mueller.hwp(0.0), s_in), s_out, atol=TOL.f64)

    def test_hwp_mirrors_linear_polarization_about_fast_axis(self, rng):
        # A HWP with fast axis theta maps linear light at psi to 2 theta - psi (and flips handedness).
        theta, psi, chi = rng.uniform(0, PI, 20), rng.uniform(0, PI, 20), rng.uniform(-PI / 4, PI / 4, 20)
        out = mueller.apply(mueller.hwp(theta), stokes.stokes(1.0, 1.0, psi, chi))
        assert_angles_close_mod_pi(stokes.aolp(out), 2 * theta - psi, atol=TOL.f64_inverse)
        np.testing.assert_allclose(stokes.ellipticity_angle(out), -chi, atol=TOL.f64_inverse)

    def test_plates_compose(self):
        # Two QWPs make a HWP; four make the identity.
        q = mueller.qwp(0.4)
        np.testing.assert_allclose(q @ q, mueller.hwp(0.4), atol=TOL.f64)
        np.testing.assert_allclose(np.linalg.matrix_power(q, 4), np.eye(4), atol=TOL.f64)

    def test_retarder_is_orthogonal(self, rng):
        # A retarder rotates the Poincare sphere: M^T M = I and the DoP is preserved.
        m = mueller.retarder(rng.uniform(0, 2 * PI, 20), rng.uniform(0, PI, 20))
        np.testing.assert_allclose(np.swapaxes(m, -1, -2) @ m, np.broadcast_to(np.eye(4), m.shape), atol=TOL.f64)


class TestLinearPolarizer:
    ANALYZER_ANGLES = np.linspace(0.0, PI, 37)

    @pytest.mark.parametrize("theta", [0.0, 0.3, PI / 4, PI / 2, 2.0])
    def test_malus_law_ideal(self, theta):
        # Malus' law: a unit fully linearly polarized beam at angle a transmits cos^2(a - theta).
        a = self.ANALYZER_ANGLES
        out = mueller.apply(mueller.linear_polarizer(theta), stokes.stokes(1.0, 1.0, a, 0.0))
        np.testing.assert_allclose(out[:, 0], np.cos(a - theta) ** 2, atol=TOL.f64)

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
        np.testing.assert_allclose(out[:, 0], 0.5 * (q + r) + 0.5 * (q - r) * np.cos(2 * (a - theta)), atol=TOL.f64)

    def test_rotated_closed_form(self):
        # Ideal polarizer at theta: 1/2 [[1,c,s,0],[c,c^2,cs,0],[s,cs,s^2,0],[0,0,0,0]], c = cos 2theta,
        # s = sin 2theta (Goldstein, Polarized Light, 3rd ed., ch. 6).
        theta = np.linspace(-PI, PI, 25)
        c, s, z = np.cos(2 * theta), np.sin(2 * theta), np.zeros_like(theta)
        expected = 0.5 * np.stack(
            [np.stack(row, axis=-1) for row in ([1 + z, c, s, z], [c, c * c, c * s, z], [s, c * s, s * s, z], [z] * 4)],
            axis=-2,
        )
        np.testing.assert_allclose(mueller.linear_polarizer(theta), expected, atol=TOL.f64)

    def test_equals_rotated_element(self):
        theta = np.linspace(-PI, PI, 25)
        np.testing.assert_allclose(
            mueller.linear_polarizer(theta), mueller.rotate_element(mueller.linear_polarizer(0.0), theta), atol=TOL.f64
        )

    def test_output_is_linear_along_axis(self, rng):
        theta = rng.uniform(0, PI, 50)
        out = mueller.apply(mueller.linear_polarizer(theta), random_stokes(rng, 50))
        np.testing.assert_allclose(stokes.dolp(out), 1.0, atol=TOL.f64_inverse)
        assert_angles_close_mod_pi(stokes.aolp(out), theta, atol=TOL.f64_inverse)

    def test_unpolarized_input(self):
        # Unpolarized light: transmitted intensity (q + r)/2, DoLP = diattenuation (q - r)/(q + r).
        out = mueller.apply(mueller.linear_polarizer(0.3, extinction_ratio=9.0), UNPOLARIZED)
        assert out[0] == pytest.approx(0.5 * (1 + 1 / 9), abs=TOL.f64)
        assert stokes.dolp(out) == pytest.approx(0.8, abs=TOL.f64)

    def test_extinction_ratio_below_one_raises(self):
        with pytest.raises(ValueError, match="extinction_ratio"):
            mueller.linear_polarizer(0.0, extinction_ratio=0.5)


class TestLinearDiattenuator:
    @pytest.mark.parametrize("q", [0.0, 0.3, 1.0])
    def test_equal_transmittances_is_neutral_density(self, q):
        np.testing.assert_allclose(mueller.linear_diattenuator(q, q, 0.7), q * np.eye(4), atol=TOL.f64)

    def test_ideal_polarizer_limit(self):
        np.testing.assert_allclose(
            mueller.linear_diattenuator(1.0, 0.0, 0.4), mueller.linear_polarizer(0.4), atol=TOL.f64
        )

    def test_is_pure(self, rng):
        m = mueller.linear_diattenuator(rng.uniform(0, 1, 20), rng.uniform(0, 1, 20), rng.uniform(0, PI, 20))
        assert_pure_mueller(m, atol=TOL.f64)

    def test_negative_transmittance_raises(self):
        with pytest.raises(ValueError, match="q and r"):
            mueller.linear_diattenuator(-0.1, 0.5)


class TestRotator:
    def test_composition(self, rng):
        a, b = rng.uniform(-PI, PI, (2, 30))
        np.testing.assert_allclose(mueller.rotator(a) @ mueller.rotator(b), mueller.rotator(a + b), atol=TOL.f64)

    def test_half_turn_is_identity(self):
        # Stokes parameters depend on 2 theta: a frame turned by pi is the same frame.
        np.testing.assert_allclose(mueller.rotator(PI), np.eye(4), atol=TOL.f64)
        np.testing.assert_allclose(mueller.rotator(-PI), np.eye(4), atol=TOL.f64)

    def test_frame_rotation_example(self):
        # Mitsuba's rotator docstring: horizontal light read in a frame rotated by +45 deg is -45 deg light.
        np.testing.assert_allclose(mueller.apply(mueller.rotator(PI / 4), HORIZONTAL), MINUS_45, atol=TOL.f64)

    def test_shifts_aolp_keeps_ellipticity(self, rng):
        # A frame turned by t sees AoLP psi - t; intensity, DoP and ellipticity are frame invariant.
        t, psi, chi = rng.uniform(-PI, PI, 30), rng.uniform(0, PI, 30), rng.uniform(-PI / 4, PI / 4, 30)
        s = stokes.stokes(1.0, 0.8, psi, chi)
        out = mueller.apply(mueller.rotator(t), s)
        assert_angles_close_mod_pi(stokes.aolp(out), psi - t, atol=TOL.f64_inverse)
        np.testing.assert_allclose(stokes.ellipticity_angle(out), chi, atol=TOL.f64_inverse)
        np.testing.assert_allclose(stokes.dop(out), 0.8, atol=TOL.f64_inverse)

    def test_rotate_element_by_half_turn_is_unchanged(self, rng):
        m = rng.normal(size=(4, 4))
        np.testing.assert_allclose(mueller.rotate_element(m, PI), m, atol=TOL.f64)


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
        np.testing.assert_allclose(m32, m64, atol=TOL.f32)


class TestDepolarizer:
    def test_full_depolarizer_outputs_unpolarized(self, rng):
        s = random_stokes(rng, 50)
        out = mueller.apply(mueller.depolarizer(0.0), s)
        np.testing.assert_array_equal(out[:, 1:], 0.0)
        np.testing.assert_array_equal(out[:, 0], s[:, 0])

    def test_partial_scales_dop(self, rng):
        s = random_stokes(rng, 50)
        out = mueller.apply(mueller.depolarizer(0.3), s)
        np.testing.assert_allclose(stokes.dop(out), 0.3 * stokes.dop(s), atol=TOL.f64)

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
        np.testing.assert_allclose(m32, m, atol=TOL.f32)

    def test_out_of_range_raises(self):
        with pytest.raises(ValueError, match="depolarizer"):
            mueller.depolarizer(1.5)


class TestJonesToMueller:
    # Independent route: build the element as a 2x2 Jones matrix and convert (no depolarization).

    @pytest.mark.parametrize("theta", [0.0, 0.4, PI / 4, 2.5, -1.0])
    def test_rotation(self, theta):
        np.testing.assert_allclose(mueller.jones_to_mueller(jones_rotator(theta)), mueller.rotator(theta), atol=TOL.f64)

    @pytest.mark.parametrize("delta", [0.0, PI / 2, PI, 1.1, 4.0])
    @pytest.mark.parametrize("theta", [0.0, 0.4, PI / 4, 2.5])
    def test_retarder(self, delta, theta):
        # Jones retarder, fast axis horizontal: diag(1, exp(-i delta)) with the module's Jones convention
        # (E = (1, i)/sqrt 2 is right circular).
        j = jones_rotated(np.diag([1.0, np.exp(-1j * delta)]), theta)
        np.testing.assert_allclose(mueller.jones_to_mueller(j), mueller.retarder(delta, theta), atol=TOL.f64)

    @pytest.mark.parametrize("theta", [0.0, 0.4, 2.5])
    def test_diattenuator_and_polarizer(self, theta):
        q, r = 0.81, 0.09  # amplitudes 0.9 and 0.3
        j = jones_rotated(np.diag([np.sqrt(q), np.sqrt(r)]).astype(complex), theta)
        np.testing.assert_allclose(mueller.jones_to_mueller(j), mueller.linear_diattenuator(q, r, theta), atol=TOL.f64)
        j = jones_rotated(np.diag([1.0, 0.0]).astype(complex), theta)
        np.testing.assert_allclose(mueller.jones_to_mueller(j), mueller.linear_polarizer(theta), atol=TOL.f64)

    def test_right_circular_polarizer_convention(self):
        # Projector onto E = (1, i)/sqrt 2: the right circular polarizer 1/2 [[1,0,0,1],0,0,[1,0,0,1]]
        # (Chipman, Lam, Young, Polarized Light and Optical Systems, Table 6.2; Mitsuba's
        # right_circular_polarizer). Pins s3 = -2 Im(Ex Ey*) > 0 for right circular.
        e = np.array([1.0, 1j]) / np.sqrt(2)
        m = mueller.jones_to_mueller(np.outer(e, e.conj()))
        expected = 0.5 * np.array([[1, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 1]], dtype=float)
        np.testing.assert_allclose(m, expected, atol=TOL.f64)

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
        np.testing.assert_allclose(np.linalg.norm(x, axis=-1), 1.0, atol=TOL.f64)
        np.testing.assert_allclose(np.sum(x * w, axis=-1), 0.0, atol=TOL.f64)

    def test_rotate_stokes_basis_docstring_example(self):
        # Mitsuba's rotate_stokes_basis docstring: horizontal light [1,1,0,0] in basis x = (1,0,0)
        # (travelling along +z) is +45 deg light in the target basis (0.707, -0.707, 0).
        m = mueller.rotate_stokes_basis([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [np.sqrt(0.5), -np.sqrt(0.5), 0.0])
        np.testing.assert_allclose(mueller.apply(m, HORIZONTAL), PLUS_45, atol=TOL.f64)

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
        np.testing.assert_allclose(
            mueller.rotate_mueller_basis(m, f_in, b_in, b_in, f_out, b_out, b_out), m, atol=TOL.f64
        )


class TestMuellerAgainstMitsuba:
    # Mitsuba 3.9.1's mi.mueller takes radians. Its linear_retarder(phase) has only the retardance
    # (fast axis horizontal, checked with help()); rotated_element(theta, M) rotates it. Only the
    # mitsuba *plugins* (polarizer, retarder) take degrees.

    def test_rotator(self, mitsuba_polarized):
        mi = mitsuba_polarized
        for theta in np.linspace(-PI, PI, 37):
            np.testing.assert_allclose(
                mueller.rotator(theta), mi_matrix(mi.mueller.rotator(float(theta))), atol=TOL.mitsuba_f32
            )

    @pytest.mark.parametrize("value", [1.0, 0.8, 0.3])
    def test_linear_polarizer(self, mitsuba_polarized, value):
        mi = mitsuba_polarized
        expected = mi_matrix(mi.mueller.linear_polarizer(value))
        np.testing.assert_allclose(mueller.linear_polarizer(0.0, transmittance=value), expected, atol=TOL.mitsuba_f32)

    def test_linear_retarder(self, mitsuba_polarized):
        mi = mitsuba_polarized
        for delta in np.linspace(0.0, 2 * PI, 25):
            expected = mi_matrix(mi.mueller.linear_retarder(float(delta)))
            np.testing.assert_allclose(mueller.retarder(delta), expected, atol=TOL.mitsuba_f32)
            for theta in (0.3, PI / 4, 2.0):
                expected = mi_matrix(mi.mueller.rotated_element(float(theta), mi.mueller.linear_retarder(float(delta))))
                np.testing.assert_allclose(mueller.retarder(delta, theta), expected, atol=TOL.mitsuba_f32)

    def test_rotated_element(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        for theta in rng.uniform(-PI, PI, 10):
            m = rng.uniform(-1, 1, (4, 4))
            expected = mi_matrix(mi.mueller.rotated_element(float(theta), mi.Matrix4f(m)))
            np.testing.assert_allclose(mueller.rotate_element(m, theta), expected, atol=TOL.mitsuba_f32)

    def test_right_circular_polarizer(self, mitsuba_polarized):
        mi = mitsuba_polarized
        e = np.array([1.0, 1j]) / np.sqrt(2)
        expected = mi_matrix(mi.mueller.right_circular_polarizer())
        np.testing.assert_allclose(mueller.jones_to_mueller(np.outer(e, e.conj())), expected, atol=TOL.mitsuba_f32)

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
            np.testing.assert_allclose(xi, np.array(mi.mueller.stokes_basis(mi_vector(mi, wi))), atol=TOL.mitsuba_f32)

    def test_rotate_stokes_basis(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        f = random_unit(rng, 100)
        cur = mueller.stokes_basis(f)
        tgt = random_perpendicular(rng, f)
        ours = mueller.rotate_stokes_basis(f, cur, tgt)
        for k in range(len(f)):
            expected = mi.mueller.rotate_stokes_basis(mi_vector(mi, f[k]), mi_vector(mi, cur[k]), mi_vector(mi, tgt[k]))
            np.testing.assert_allclose(ours[k], mi_matrix(expected), atol=TOL.mitsuba_f32)

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
            np.testing.assert_allclose(ours[k], mi_matrix(expected), atol=TOL.mitsuba_f32)
