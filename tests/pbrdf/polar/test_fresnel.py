"""Physics tests of pbrdf.polar.fresnel: amplitudes and Mueller matrices of reflection and transmission.

Every expected value comes from a closed form (cited where it is used), from an independent route
(Hecht's Fresnel amplitudes written out in this file) or from Mitsuba 3's C++ implementation
(``mi.fresnel_polarized``, ``mi.mueller`` in ``scalar_spectral_polarized``, float32).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pbrdf.polar import fresnel, mueller, stokes
from tests.conftest import TOL
from tests.helpers import (
    HORIZONTAL,
    PLUS_45,
    UNPOLARIZED,
    VERTICAL,
    assert_mueller_physical,
    assert_pure_mueller,
    mi_matrix,
)

PI = np.pi

# Real relative IORs, seen from both sides of the interface (1/1.5 is glass-to-air).
DIELECTRIC_ETAS = [1.5, 1 / 1.5, 1.33, 2.4]
# eta = n - ik near 600 nm: gold, then rough silver, aluminium, chrome.
CONDUCTOR_ETAS = [0.27 - 2.78j, 0.05 - 3.9j, 1.2 - 7.0j, 2.9 - 3.0j]
# Incidence angle 0..180 deg in 1-deg steps: cos_theta_i from 1 (outside, normal) through 0 (grazing) to
# -1 (inside, normal); covers total internal reflection on the dense side.
SWEEP_COS = np.cos(np.radians(np.linspace(0.0, 180.0, 181)))
OUTSIDE_COS = SWEEP_COS[SWEEP_COS >= 0]


# --- helpers (shared ones, and the named Stokes states, are in tests/helpers.py) ---------------------


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


# --- Fresnel -----------------------------------------------------------------------------------------


class TestFresnelAmplitudes:
    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS + CONDUCTOR_ETAS)
    def test_normal_incidence(self, eta):
        # R0 = |(eta - 1)/(eta + 1)|^2 (= ((n-1)/(n+1))^2 for a dielectric); Verdet signs: r_p = -r_s.
        r_s, r_p, cos_t = fresnel.fresnel_amplitudes(1.0, eta)
        r0 = abs((eta - 1) / (eta + 1)) ** 2
        assert abs(r_s) ** 2 == pytest.approx(r0, abs=TOL.f64)
        assert r_p == pytest.approx(-r_s, abs=TOL.f64)
        assert cos_t == pytest.approx(1.0, abs=TOL.f64)
        assert fresnel.fresnel_reflectance(1.0, eta) == pytest.approx(r0, abs=TOL.f64)

    @pytest.mark.parametrize("eta", [1.5, 1.33, 2.4])
    def test_normal_incidence_from_inside(self, eta):
        # The same R0 from both sides: ((1/n - 1)/(1/n + 1))^2 = ((n - 1)/(n + 1))^2.
        assert fresnel.fresnel_reflectance(-1.0, eta) == pytest.approx(((eta - 1) / (eta + 1)) ** 2, abs=TOL.f64)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_matches_hecht_and_snell(self, eta):
        # Same amplitudes as Hecht's (helper above; Hecht's r_parallel sign is the Verdet one), and the
        # transmitted cosine obeys Snell's law sin_t = sin_i / eta_eff; |r| = 1 under TIR.
        r_s, r_p, cos_t = fresnel.fresnel_amplitudes(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            h_s, h_p, _, _, tir = hecht_fresnel(c, eta)
            if tir:
                assert abs(r_s[k]) == pytest.approx(1.0, abs=TOL.f64)
                assert abs(r_p[k]) == pytest.approx(1.0, abs=TOL.f64)
                assert cos_t[k].imag < 0  # decaying evanescent wave, Mitsuba's branch
                continue
            assert r_s[k] == pytest.approx(h_s, abs=TOL.f64)
            assert r_p[k] == pytest.approx(h_p, abs=TOL.f64)
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
            assert complex(a_s.real, a_s.imag) == pytest.approx(r_s[k], abs=TOL.mitsuba_f32)
            assert complex(a_p.real, a_p.imag) == pytest.approx(r_p[k], abs=TOL.mitsuba_f32)
            # Mitsuba returns the real cosine of the refracted direction (sign opposite to cos_i, 0 under TIR).
            assert abs(mi_cos_t) == pytest.approx(cos_t[k].real, abs=TOL.mitsuba_f32)

    @pytest.mark.parametrize("eta", CONDUCTOR_ETAS)
    def test_against_mitsuba_conductor(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        r_s, r_p, _ = fresnel.fresnel_amplitudes(OUTSIDE_COS, eta)
        for k, c in enumerate(OUTSIDE_COS):
            a_s, a_p, _, _, _ = mi.fresnel_polarized(float(c), mi_complex(mi, eta))
            assert complex(a_s.real, a_s.imag) == pytest.approx(r_s[k], abs=TOL.mitsuba_f32)
            assert complex(a_p.real, a_p.imag) == pytest.approx(r_p[k], abs=TOL.mitsuba_f32)


class TestReflectionMueller:
    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS + CONDUCTOR_ETAS)
    def test_mirror_at_normal_incidence(self, eta):
        # r_p = -r_s at normal incidence: R0 diag(1, 1, -1, -1), the mirror flips S2 and S3.
        r0 = abs((eta - 1) / (eta + 1)) ** 2
        np.testing.assert_allclose(fresnel.reflection_mueller(1.0, eta), r0 * np.diag([1.0, 1, -1, -1]), atol=TOL.f64)

    @pytest.mark.parametrize("n", [1.33, 1.5, 2.4])
    @pytest.mark.parametrize("side", ["outside", "inside"])
    def test_brewster_angle(self, n, side):
        # Brewster: tan theta_B = eta_eff, R_p = 0; theta_i + theta_t = 90 deg gives
        # R_s = sin^2(theta_i - theta_t) = cos^2(2 theta_B) = ((eta^2 - 1)/(eta^2 + 1))^2.
        eta_eff = n if side == "outside" else 1 / n
        cos_b = np.cos(np.arctan(eta_eff)) * (1 if side == "outside" else -1)
        m = fresnel.reflection_mueller(cos_b, n)
        r_s = ((eta_eff**2 - 1) / (eta_eff**2 + 1)) ** 2
        assert m[0, 0] == pytest.approx(m[0, 1], abs=TOL.f64)  # m00 - m01 = R_p = 0
        assert m[0, 0] == pytest.approx(r_s / 2, abs=TOL.f64)
        out = mueller.apply(m, UNPOLARIZED)
        assert stokes.dolp(out) == pytest.approx(1.0, abs=TOL.f64_inverse)
        assert out[1] > 0  # s-polarized: the Stokes x-axis is perpendicular to the plane of incidence

    def test_gold_makes_circular_polarization(self):
        # Gold eta = 0.27 - 2.78i at 60 deg, +45 deg linear in: S = (.880, .063, -.513, .712), S3 > 0 (right
        # circular), verified against Mitsuba's specular_reflection (3 decimals).
        out = mueller.apply(fresnel.reflection_mueller(np.cos(np.radians(60)), 0.27 - 2.78j), PLUS_45)
        np.testing.assert_allclose(out, [0.880, 0.063, -0.513, 0.712], atol=1e-3)
        assert out[3] > 0
        # The same metal written n + ik gives the same light (conjugation convention).
        np.testing.assert_array_equal(
            mueller.apply(fresnel.reflection_mueller(np.cos(np.radians(60)), 0.27 + 2.78j), PLUS_45), out
        )

    def test_gold_keeps_s_and_p_linear(self):
        # s- and p-polarized light are eigenstates of reflection: they stay linear.
        m = fresnel.reflection_mueller(np.cos(np.radians(60)), 0.27 - 2.78j)
        for s_in in (HORIZONTAL, VERTICAL):
            out = mueller.apply(m, s_in)
            np.testing.assert_allclose(out[2:], 0.0, atol=TOL.f64)
            assert stokes.dolp(out) == pytest.approx(1.0, abs=TOL.f64_inverse)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_dielectric_makes_no_circular_polarization(self, eta):
        # Real eta without TIR: r_s and r_p are real, Im(r_s r_p*) = 0, so linear light stays linear.
        c = SWEEP_COS[[not hecht_fresnel(c, eta)[4] for c in SWEEP_COS]]
        out = mueller.apply(fresnel.reflection_mueller(c, eta), PLUS_45)
        np.testing.assert_allclose(out[:, 3], 0.0, atol=TOL.f64)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_total_internal_reflection_is_a_retarder(self, eta):
        # Under TIR all light is reflected (|r_s| = |r_p| = 1), only the s-p phase changes.
        tir = np.array([hecht_fresnel(c, eta)[4] for c in SWEEP_COS])
        assert tir.any()  # every eta != 1 has a dense side
        m = fresnel.reflection_mueller(SWEEP_COS[tir], eta)
        np.testing.assert_allclose(m[:, 0, 0], 1.0, atol=TOL.f64)
        np.testing.assert_allclose(m[:, 0, 1], 0.0, atol=TOL.f64)
        assert_pure_mueller(m, atol=TOL.f64)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS + CONDUCTOR_ETAS)
    def test_unpolarized_reflectance(self, eta):
        # Unpolarized light reflects the scalar Fresnel reflectance (R_s + R_p)/2.
        c = SWEEP_COS if np.isreal(eta) else OUTSIDE_COS
        out = mueller.apply(fresnel.reflection_mueller(c, eta), UNPOLARIZED)
        np.testing.assert_allclose(out[:, 0], fresnel.fresnel_reflectance(c, eta), atol=TOL.f64)

    def test_physical(self, rng):
        ms = [fresnel.reflection_mueller(SWEEP_COS, eta) for eta in DIELECTRIC_ETAS]
        ms += [fresnel.reflection_mueller(OUTSIDE_COS, eta) for eta in CONDUCTOR_ETAS]
        m = np.concatenate(ms)
        assert np.all(m[:, 0, 0] > 0)
        assert_pure_mueller(m, atol=TOL.f64)
        assert_mueller_physical(m, rng)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_against_mitsuba_dielectric(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        ours = fresnel.reflection_mueller(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            expected = mi_matrix(mi.mueller.specular_reflection(float(c), mi_complex(mi, eta)))
            np.testing.assert_allclose(ours[k], expected, atol=TOL.mitsuba_f32)

    @pytest.mark.parametrize("eta", CONDUCTOR_ETAS)
    def test_against_mitsuba_conductor(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        ours = fresnel.reflection_mueller(OUTSIDE_COS, eta)
        for k, c in enumerate(OUTSIDE_COS):
            expected = mi_matrix(mi.mueller.specular_reflection(float(c), mi_complex(mi, eta)))
            np.testing.assert_allclose(ours[k], expected, atol=TOL.mitsuba_f32)


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
                assert refl[k, 0, 0] == pytest.approx(1.0, abs=TOL.f64)
                continue
            assert h_s**2 + t_s == pytest.approx(1.0, abs=TOL.f64)  # the derivation itself
            assert h_p**2 + t_p == pytest.approx(1.0, abs=TOL.f64)
            assert trans[k, 0, 0] == pytest.approx(0.5 * (t_s + t_p), abs=TOL.f64)
            assert trans[k, 0, 1] == pytest.approx(0.5 * (t_s - t_p), abs=TOL.f64)
            assert trans[k, 2, 2] == pytest.approx(np.sqrt(t_s * t_p), abs=TOL.f64)
        # Any input state: the reflected plus the transmitted intensity is the incident intensity.
        np.testing.assert_allclose(
            refl[:, 0, :] + trans[:, 0, :], np.broadcast_to(UNPOLARIZED, (len(c), 4)), atol=TOL.f64
        )

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_is_a_pure_diattenuator(self, eta, rng):
        m = fresnel.transmission_mueller(SWEEP_COS, eta)
        np.testing.assert_allclose(m[:, 2:, :2], 0.0, atol=0)  # no retardance
        np.testing.assert_allclose(m[:, :2, 2:], 0.0, atol=0)
        assert_pure_mueller(m, atol=TOL.f64)
        m = m[m[:, 0, 0] > 1e-6]  # drop TIR and grazing (zero matrices are not Cloude-physical)
        assert_mueller_physical(m, rng)

    @pytest.mark.parametrize("eta", DIELECTRIC_ETAS)
    def test_against_mitsuba(self, mitsuba_polarized, eta):
        mi = mitsuba_polarized
        ours = fresnel.transmission_mueller(SWEEP_COS, eta)
        for k, c in enumerate(SWEEP_COS):
            expected = mi_matrix(mi.mueller.specular_transmission(float(c), float(eta)))
            np.testing.assert_allclose(ours[k], expected, atol=TOL.mitsuba_f32)

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


class TestFresnelRange:
    """The documented range: |eta| in [1e-6, 1e6] and finite cosines; outside it, a clear ValueError."""

    EDGE_ETAS = [1e-6, 1e6, 1e-6 - 9e5j, 9e5 - 1e-6j, 1e-6 - 1e-6j]
    COS = np.array([0.0, 5e-324, 1e-300, 1e-12, 0.5, 1.0 - 1e-16, 1.0])

    @pytest.mark.filterwarnings("error")
    @pytest.mark.parametrize("eta", EDGE_ETAS)
    def test_edges_of_the_range_are_finite_and_bounded(self, eta):
        r = fresnel.fresnel_reflectance(self.COS, eta)
        assert np.all(np.isfinite(r)) and np.all((r >= 0) & (r <= 1))
        # Hand limits: R = 1 at grazing incidence; at normal incidence R0 = |(eta - 1)/(eta + 1)|^2,
        # which tends to 1 for eta -> 0 and eta -> inf.
        assert r[0] == pytest.approx(1.0, abs=1e-15)
        assert r[-1] == pytest.approx(abs((eta - 1) / (eta + 1)) ** 2, rel=1e-12)
        assert np.all(np.isfinite(fresnel.reflection_mueller(self.COS, eta)))
        if np.imag(eta) == 0:
            assert np.all(np.isfinite(fresnel.transmission_mueller(self.COS, eta)))

    @pytest.mark.parametrize("eta", [1e-300, 1e-7, 1e7, 1e300, 1e-7 - 1e-7j, 1 - 2e6j, np.nan, np.inf, 1 + np.nan * 1j])
    @pytest.mark.parametrize(
        "fn",
        [fresnel.fresnel_amplitudes, fresnel.fresnel_reflectance, fresnel.reflection_mueller],
    )
    def test_eta_outside_the_range_is_refused(self, fn, eta):
        # fresnel_reflectance(1.0, 1e-300) used to be NaN: 1e-300**2 underflows and 0/0 followed.
        with pytest.raises(ValueError, match=r"eta must be finite with \|eta\| in \[1e-06, 1e\+06\]"):
            fn(1.0, eta)

    @pytest.mark.parametrize("eta", [1e-300, 1e300, np.nan])
    def test_eta_outside_the_range_is_refused_transmission(self, eta):
        with pytest.raises(ValueError, match="eta"):
            fresnel.transmission_mueller(1.0, eta)

    @pytest.mark.parametrize("c", [np.nan, np.inf, -np.inf])
    def test_non_finite_cosine_is_refused(self, c):
        for fn in (fresnel.fresnel_reflectance, fresnel.reflection_mueller, fresnel.transmission_mueller):
            with pytest.raises(ValueError, match="cos_theta_i must be finite"):
                fn(np.array([0.5, c]), 1.5)

    def test_reflectance_is_clamped_to_the_unit_interval(self, rng):
        # Rounding of |r_s|^2 + |r_p|^2 never leaves [0, 1] (hand bound: |r| <= 1 for Re(eta) > 0).
        c = rng.uniform(0, 1, 20000)
        eta = 10.0 ** rng.uniform(-5.8, 5.8, 20000) - 1j * 10.0 ** rng.uniform(-6, 5.8, 20000)
        r = fresnel.fresnel_reflectance(c, eta)
        assert np.all((r >= 0) & (r <= 1))


@pytest.mark.parametrize("n", [1.0, 0.16, 2.5])
def test_conductor_extinction_gives_that_normal_incidence_reflectance(n):
    r_min = ((n - 1) / (n + 1)) ** 2
    for r0 in np.linspace(r_min + 1e-3, 0.99, 7):
        k, r = fresnel.conductor_extinction(r0, n)
        assert float(r) == pytest.approx(r0)
        # the complex Fresnel reflectance of n - ik at normal incidence
        assert float(fresnel.fresnel_reflectance(1.0, complex(n, -float(k)))) == pytest.approx(r0, rel=1e-6)
    k, r = fresnel.conductor_extinction(0.0, 2.5)  # below what n = 2.5 reaches: clipped, k = 0
    assert float(k) == 0.0 and float(r) == pytest.approx((1.5 / 3.5) ** 2)


@pytest.mark.parametrize("eta", [1.33, 1.5, 2.4])
def test_dielectric_transmittance_is_one_minus_the_complex_amplitude_reflectance(eta):
    cos = np.linspace(0.0, 1.0, 101)
    want = 1.0 - fresnel.fresnel_reflectance(cos, eta)  # the complex-amplitude path, an independent form
    np.testing.assert_allclose(fresnel.dielectric_transmittance(cos, eta), want, atol=1e-12)
    torch = pytest.importorskip("torch")
    c = torch.tensor(cos, requires_grad=True)
    t = fresnel.dielectric_transmittance(c, eta)
    np.testing.assert_allclose(t.detach().numpy(), want, atol=1e-12)
    t.sum().backward()
    assert torch.isfinite(c.grad).all()  # grazing included
    # Normal incidence: 4 eta / (1 + eta)^2; light from below clips to grazing (no transmission).
    assert fresnel.dielectric_transmittance(np.array([1.0, -0.5]), eta) == pytest.approx(
        [4 * eta / (1 + eta) ** 2, 0.0]
    )
