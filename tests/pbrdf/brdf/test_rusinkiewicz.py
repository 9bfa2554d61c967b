"""Rusinkiewicz angles: the measured_polarized plugin's algorithm, convention examples, round trips."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from pbrdf.brdf import rusinkiewicz
from pbrdf.brdf.rusinkiewicz import directions_from_rusinkiewicz, reflection_frame_x, rusinkiewicz_from_directions
from tests.conftest import TOL
from tests.helpers import random_hemisphere

PI = np.pi


def plugin_rusinkiewicz(wi, wo):
    """Mitsuba's algorithm written out (float64): rotate so that wi has azimuth 0, then normalize/acos/atan2."""
    phi_std = np.arctan2(wi[1], wi[0])

    def rot(v, a):
        c, s = np.cos(a), np.sin(a)
        return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])

    i, o = rot(wo, -phi_std), rot(wi, -phi_std)  # i: light side, o: camera side
    h = (i + o) / np.linalg.norm(i + o)
    n = np.array([0.0, 0.0, 1.0])
    b = np.cross(n, h) / np.linalg.norm(np.cross(n, h))
    t = np.cross(b, h) / np.linalg.norm(np.cross(b, h))
    i_prj = (i - (i @ h) * h) / np.linalg.norm(i - (i @ h) * h)
    return np.arccos(n @ h), np.arccos(h @ i), np.arctan2(b @ i_prj, t @ i_prj)


unit_xy = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def upper_directions(draw):
    x, y = draw(unit_xy), draw(unit_xy)
    z = draw(st.floats(0.0, 1.0))
    v = np.array([x, y, z])
    n = np.linalg.norm(v)
    return np.array([0.0, 0.0, 1.0]) if n < 1e-6 else v / n


class TestRusinkiewicz:
    def test_matches_the_plugin_algorithm(self, rng):
        wi, wo = random_hemisphere(rng, 300), random_hemisphere(rng, 300)
        ours = np.stack(rusinkiewicz_from_directions(wi, wo), axis=-1)
        ref = np.array([plugin_rusinkiewicz(a, b) for a, b in zip(wi, wo, strict=True)])
        np.testing.assert_allclose(ours, ref, atol=1e-7)  # acos in the reference: ~1e-8 near 0

    def test_convention_examples(self):
        s, c = np.sin(PI / 6), np.cos(PI / 6)
        # Mirror configuration: h = n, phi_d = pi (light on -x, b = +y by definition).
        np.testing.assert_allclose(
            rusinkiewicz_from_directions([s, 0, c], [-s, 0, c]), [0, PI / 6, PI], atol=TOL.f64_exact
        )
        # Retro-reflection: theta_d = 0, phi_d = 0.
        np.testing.assert_allclose(
            rusinkiewicz_from_directions([s, 0, c], [s, 0, c]), [PI / 6, 0, 0], atol=TOL.f64_exact
        )
        # Camera at the normal, light at 60 degrees on +x: h at 30 degrees towards +x, b = +y,
        # t = b x h = (cos 30, 0, -sin 30) points away from the normal, and the light lies along +t.
        th, td, pd = rusinkiewicz_from_directions([0, 0, 1.0], [np.sin(PI / 3), 0, 0.5])
        np.testing.assert_allclose([th, td, pd], [PI / 6, PI / 6, 0], atol=TOL.f64)
        # Mirroring y -> -y flips the sign of phi_d.
        wi, wo = np.array([0.3, 0.2, 0.93]), np.array([-0.1, -0.5, 0.86])
        wi, wo = wi / np.linalg.norm(wi), wo / np.linalg.norm(wo)
        flip = np.array([1.0, -1.0, 1.0])
        a, b = rusinkiewicz_from_directions(wi, wo)[2], rusinkiewicz_from_directions(wi * flip, wo * flip)[2]
        assert a == pytest.approx(-b) and abs(a) > 0.1

    @settings(max_examples=300, deadline=None)
    @given(upper_directions(), upper_directions())
    def test_round_trip_directions(self, wi, wo):
        # Opposite grazing directions (wi = -wo on the horizon) have no half vector: excluded.
        assume(np.linalg.norm(wi + wo) > 1e-6)
        theta_h, theta_d, phi_d = rusinkiewicz_from_directions(wi, wo)
        h = wi + wo
        phi_h = np.arctan2(h[1], h[0])
        wi2, wo2 = directions_from_rusinkiewicz(theta_h, theta_d, phi_d, phi_h)
        np.testing.assert_allclose(wi2, wi, atol=TOL.f64_inverse)
        np.testing.assert_allclose(wo2, wo, atol=TOL.f64_inverse)

    def test_round_trip_angles(self, rng):
        th, td = rng.uniform(0.01, 0.7, 200), rng.uniform(0.01, 0.7, 200)  # both directions above the horizon
        pd, ph = rng.uniform(-PI, PI, 200), rng.uniform(-PI, PI, 200)
        wi, wo = directions_from_rusinkiewicz(th, td, pd, ph)
        assert (wi[:, 2] > 0).all() and (wo[:, 2] > 0).all()
        np.testing.assert_allclose(np.linalg.norm(wi, axis=-1), 1.0, atol=1e-14)
        np.testing.assert_allclose(np.stack(rusinkiewicz_from_directions(wi, wo)), np.stack([th, td, pd]), atol=1e-10)

    def test_rejects_non_unit(self):
        with pytest.raises(ValueError, match="wo must hold finite unit vectors"):
            rusinkiewicz_from_directions([0, 0, 1.0], [0, 0, 2.0])
        with pytest.raises(ValueError, match=r"wi must have shape \(\.\.\., 3\)"):
            rusinkiewicz_from_directions([0, 1.0], [0, 0, 1.0])


class TestReflectionFrameX:
    def test_perpendicular_to_the_plane_of_reflection(self, rng):
        wi, wo = random_hemisphere(rng, 200), random_hemisphere(rng, 200)
        x = reflection_frame_x(wi, wo)
        np.testing.assert_allclose(np.linalg.norm(x, axis=-1), 1.0, atol=TOL.f64)
        np.testing.assert_allclose(np.einsum("...i,...i->...", x, wi), 0.0, atol=TOL.f64)
        np.testing.assert_allclose(np.einsum("...i,...i->...", x, wo), 0.0, atol=TOL.f64)
        np.testing.assert_allclose(x, np.cross(wo, wi) / np.linalg.norm(np.cross(wo, wi), axis=-1, keepdims=True))

    def test_degenerate_limits(self):
        s, c = np.sin(0.5), np.cos(0.5)
        n = np.array([0.0, 0.0, 1.0])
        # wi == wo: the plane of incidence of wi, x = normalize(n x wi); normal incidence: +y.
        np.testing.assert_allclose(reflection_frame_x([s, 0, c], [s, 0, c]), [0, 1, 0], atol=TOL.f64_exact)
        np.testing.assert_allclose(reflection_frame_x(n, n), [0, 1, 0], atol=TOL.f64_exact)


def test_module_exports():
    assert set(rusinkiewicz.__all__) <= set(dir(rusinkiewicz))
