"""Tests of pbrdf.brdf.microfacet: GGX terms, the Baek-2018 dielectric pBRDF and the rough conductor.

Expected values come from Mitsuba 3's own plugins (``pplastic``, ``roughconductor`` and
``MicrofacetDistribution`` in ``scalar_spectral_polarized``, float32, constant spectra so every
wavelength agrees), from closed forms (cited where used) and from physical laws: Helmholtz and
Mueller reciprocity, energy conservation (Monte Carlo), the polarization states of Fresnel
reflection and transmission.
"""

from __future__ import annotations

import numpy as np
import pytest

from pbrdf.brdf.microfacet import ALPHA_MAX, ALPHA_MIN, conductor_pbrdf, dielectric_pbrdf, ggx_d, smith_g1
from pbrdf.polar import fresnel, mueller
from tests.conftest import TOL

PI = np.pi

# Mitsuba evaluates in float32. Agreement is measured relative to m00 of the same matrix, for every entry:
# worst cases over 1000 random pairs with both z >= 0.05: pplastic 2.5e-5, roughconductor 8.2e-6 (3.2e-6 without the
# z >= 0.05 limit). Grazing pplastic pairs need more: test_against_mitsuba_near_grazing.
MI_RTOL = 1e-4
MI_ATOL = 1e-7

PLASTICS = [  # (albedo, eta, alpha)
    (0.2, 1.5, 0.05),
    (0.8, 1.5, 0.3),
    (0.2, 1.33, 0.7),
    (0.8, 1.33, 0.05),
]
# eta = n - ik: gold near 600 nm (Johnson & Christy 1972 give about 0.18 - 3.1i at 620 nm), aluminium, chrome.
CONDUCTORS = [  # (eta, alpha)
    (0.18 - 3.2j, 0.05),
    (0.18 - 3.2j, 0.3),
    (0.18 - 3.2j, 0.7),
    (1.2 - 7.0j, 0.3),
    (2.9 - 3.0j, 0.7),
]
GOLD = 0.18 - 3.2j


# --- helpers -----------------------------------------------------------------------------------------


def hemisphere(rng, n, z_min=0.0):
    """Unit vectors, uniform on the upper hemisphere restricted to z >= z_min."""
    z = rng.uniform(z_min, 1.0, n)
    phi = rng.uniform(0, 2 * PI, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def direction(theta, phi):
    """Unit vector at polar angle theta and azimuth phi (radians), local frame."""
    return np.stack(np.broadcast_arrays(np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)), -1)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def linear_stokes(e, w):
    """Stokes vector of fully linearly polarized light with field along unit ``e``, travelling along ``w``.

    Mitsuba's implicit frame: x = stokes_basis(w), y = w x x (right-handed), angles from x towards y.
    """
    x = mueller.stokes_basis(w)
    y = np.cross(w, x)
    psi = np.arctan2(np.sum(e * y, -1), np.sum(e * x, -1))
    return np.stack([np.ones_like(psi), np.cos(2 * psi), np.sin(2 * psi), np.zeros_like(psi)], -1)


def polarization_direction(s, w):
    """Unit 3-D field direction of the linear part of Stokes ``s`` travelling along ``w`` (inverse of linear_stokes)."""
    x = mueller.stokes_basis(w)
    y = np.cross(w, x)
    psi = 0.5 * np.arctan2(s[..., 2], s[..., 1])
    return np.cos(psi)[..., None] * x + np.sin(psi)[..., None] * y


def dolp(s):
    return np.hypot(s[..., 1], s[..., 2]) / s[..., 0]


def assert_close_to_mitsuba(ours, theirs, rtol=MI_RTOL, atol=MI_ATOL):
    """Every entry within rtol * m00 + atol; reports the worst pair."""
    err = np.max(np.abs(ours - theirs), axis=(-2, -1))
    bound = rtol * np.abs(theirs[..., 0, 0]) + atol
    k = int(np.argmax(err / bound))
    assert np.all(err <= bound), f"pair {k}: error {err[k]:.3g} > {bound[k]:.3g}\nours\n{ours[k]}\nmitsuba\n{theirs[k]}"


def reflect_about_normal(w):
    """Mirror direction about the normal: wi and wo with h = n."""
    return w * np.array([-1.0, -1.0, 1.0])


# --- Mitsuba helpers ---------------------------------------------------------------------------------


def _uniform(value):
    return {"type": "uniform", "value": float(value)}


def mi_pplastic(mi, albedo, eta, alpha, specular=1.0):
    return mi.load_dict(
        {
            "type": "pplastic",
            "diffuse_reflectance": _uniform(albedo),
            "specular_reflectance": _uniform(specular),
            "int_ior": float(eta),
            "ext_ior": 1.0,  # Mitsuba's default is air, 1.000277
            "alpha": float(alpha),
            "distribution": "ggx",
        }
    )


def mi_roughconductor(mi, eta, alpha, specular=1.0):
    # Mitsuba reads eta + i k with k >= 0 as n - ik (fresnel_polarized conjugates a positive imaginary part).
    return mi.load_dict(
        {
            "type": "roughconductor",
            "eta": _uniform(np.real(eta)),
            "k": _uniform(abs(np.imag(eta))),
            "specular_reflectance": _uniform(specular),
            "alpha": float(alpha),
            "distribution": "ggx",
        }
    )


def mi_eval(mi, bsdf, wi, wo):
    """``bsdf.eval`` (radiance mode: si.wi = camera side, wo = light side) as float64 ``(n, 4, 4)``."""
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    out = np.empty((len(wi), 4, 4))
    for k, (a, b) in enumerate(zip(wi, wo, strict=True)):
        si.wi = mi.Vector3f(*(float(v) for v in a))
        value = np.array(bsdf.eval(ctx, si, mi.Vector3f(*(float(v) for v in b))), dtype=np.float64)
        out[k] = value[..., 0]  # (4, 4, wavelengths): constant spectrum, all equal
    return out


# --- GGX ---------------------------------------------------------------------------------------------


class TestGgxD:
    def test_value_at_normal(self):
        alpha = np.array([0.05, 0.3, 1.0])
        np.testing.assert_allclose(ggx_d(1.0, alpha), 1 / (PI * alpha**2), rtol=1e-14)

    @pytest.mark.parametrize("alpha", [0.05, 0.3, 0.7])
    def test_projected_area_is_one(self, alpha):
        """int D(h) cos(theta_h) dh = 1 (Walter et al. 2007, eq. 4), by adaptive quadrature in theta_h."""
        from scipy.integrate import quad

        value, _ = quad(lambda t: 2 * PI * ggx_d(np.cos(t), alpha) * np.cos(t) * np.sin(t), 0, PI / 2, epsabs=1e-12)
        assert value == pytest.approx(1.0, rel=1e-8)

    def test_against_mitsuba(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        h = hemisphere(rng, 200)
        for alpha in (0.05, 0.3, 0.7):
            dist = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha)
            expected = [dist.eval(mi.Vector3f(*(float(v) for v in hk))) for hk in h]
            np.testing.assert_allclose(ggx_d(h[:, 2], alpha), expected, rtol=1e-5, atol=1e-7)

    def test_alpha_clamped_like_mitsuba(self, mitsuba_polarized):
        mi = mitsuba_polarized
        assert mi.MicrofacetDistribution(mi.MicrofacetType.GGX, 1e-6).alpha() == pytest.approx(ALPHA_MIN)
        c = np.array([1.0, 0.9999, 0.5, 1e-8, 0.0])
        np.testing.assert_array_equal(ggx_d(c, 0.0), ggx_d(c, ALPHA_MIN))
        np.testing.assert_array_equal(ggx_d(c, 1e-6), ggx_d(c, ALPHA_MIN))

    @pytest.mark.filterwarnings("error")
    def test_finite_everywhere_and_zero_below(self):
        c = np.array([-1.0, -0.5, 0.0, 1e-300, 1e-8, 0.5, 1.0])
        d = ggx_d(c[:, None], np.array([0.0, 1e-6, 0.3, 1.0, 5.0]))
        assert np.all(np.isfinite(d)) and np.all(d >= 0)
        np.testing.assert_array_equal(d[:2], 0.0)

    def test_negative_alpha_raises(self):
        with pytest.raises(ValueError, match="alpha"):
            ggx_d(1.0, -0.1)


class TestSmithG1:
    def test_limits(self):
        assert smith_g1(1.0, 0.7) == 1.0
        np.testing.assert_array_equal(smith_g1([0.0, -0.3, -1.0], 0.7), 0.0)

    @pytest.mark.filterwarnings("error")
    def test_stays_in_the_unit_interval_for_huge_alpha(self):
        # Used to return 2.0: alpha^2 + (1 - alpha^2) cos^2 cancelled to 0 at alpha = 1e150.
        # alpha is clamped to [ALPHA_MIN, 1e4]: G1 = 1 at normal incidence, 0 at grazing.
        assert smith_g1(1.0, 1e150) == 1.0
        assert smith_g1(0.0, 1e150) == 0.0
        c = np.array([-0.5, 0.0, 5e-324, 1e-8, 0.5, 1.0])[:, None]
        g = smith_g1(c, np.array([0.0, 1e-6, 0.5, 1e4, 1e150, 1e300]))
        assert np.all(np.isfinite(g)) and np.all((g >= 0) & (g <= 1))
        np.testing.assert_array_equal(g[-1], 1.0)
        d = ggx_d(c, np.array([0.0, 1e4, 1e150, 1e300]))
        assert np.all(np.isfinite(d)) and np.all(d >= 0)
        np.testing.assert_array_equal(ggx_d(c, 1e300), ggx_d(c, ALPHA_MAX))

    def test_nan_alpha_is_refused(self):
        with pytest.raises(ValueError, match="alpha"):
            smith_g1(0.5, np.nan)

    def test_closed_form(self, rng):
        """G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2)) (Walter et al. 2007, eq. 34) away from grazing."""
        c = rng.uniform(0.05, 1.0, 100)
        alpha = rng.uniform(0.01, 1.0, 100)
        tan2 = (1 - c * c) / (c * c)
        np.testing.assert_allclose(smith_g1(c, alpha), 2 / (1 + np.sqrt(1 + alpha**2 * tan2)), rtol=1e-13)

    def test_monotone_in_angle_and_roughness(self):
        c = np.linspace(1e-6, 1, 1000)
        g = smith_g1(c[None, :], np.array([[0.05], [0.3], [0.7]]))
        assert np.all(np.diff(g, axis=1) >= 0)
        assert np.all(np.diff(g, axis=0) <= 0)

    def test_against_mitsuba(self, mitsuba_polarized, rng):
        mi = mitsuba_polarized
        v = hemisphere(rng, 200)
        n = mi.Vector3f(0, 0, 1)
        for alpha in (0.05, 0.3, 0.7):
            dist = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha)
            expected = [dist.smith_g1(mi.Vector3f(*(float(x) for x in vk)), n) for vk in v]
            np.testing.assert_allclose(smith_g1(v[:, 2], alpha), expected, rtol=1e-5, atol=1e-7)

    @pytest.mark.filterwarnings("error")
    def test_finite_at_grazing_and_tiny_alpha(self):
        g = smith_g1(np.array([1e-300, 1e-8, 1e-4])[:, None], np.array([0.0, 1e-6, 0.3]))
        assert np.all(np.isfinite(g)) and np.all((g >= 0) & (g <= 1))


# --- Against Mitsuba ---------------------------------------------------------------------------------


class TestDielectricPbrdf:
    @pytest.mark.parametrize(("albedo", "eta", "alpha"), PLASTICS)
    def test_against_mitsuba_pplastic(self, mitsuba_polarized, rng, albedo, eta, alpha):
        """All 16 entries, signs included, at 250 random pairs with z >= 0.05 (3 degrees above the horizon)."""
        wi, wo = hemisphere(rng, 250, 0.05), hemisphere(rng, 250, 0.05)
        theirs = mi_eval(mitsuba_polarized, mi_pplastic(mitsuba_polarized, albedo, eta, alpha), wi, wo)
        assert_close_to_mitsuba(dielectric_pbrdf(wi, wo, albedo=albedo, eta=eta, alpha=alpha), theirs)

    def test_against_mitsuba_specular_scale(self, mitsuba_polarized, rng):
        wi, wo = hemisphere(rng, 50, 0.05), hemisphere(rng, 50, 0.05)
        theirs = mi_eval(mitsuba_polarized, mi_pplastic(mitsuba_polarized, 0.5, 1.5, 0.2, specular=0.3), wi, wo)
        assert_close_to_mitsuba(dielectric_pbrdf(wi, wo, albedo=0.5, eta=1.5, alpha=0.2, specular=0.3), theirs)

    @pytest.mark.parametrize(("albedo", "eta", "alpha"), PLASTICS)
    def test_against_mitsuba_near_grazing(self, mitsuba_polarized, rng, albedo, eta, alpha):
        """Within 3 degrees of the horizon the specular lobe still agrees to float32; the diffuse lobe less so.

        Both differences are Mitsuba's float32 round-off in its transmittances, not a model difference:
        (1) it evaluates the exit transmittance at the refracted camera angle with 1 / eta, whose exit cosine
        sqrt(1 - eta^2 sin^2) cancels as cos_i -> 0: relative error up to 1e-7 / cos_i^2 (2.8e-2 of m00 at
        cos_i = 7e-4); this module evaluates the equal (reciprocal) transmittance at the camera angle in float64.
        (2) ``mi.mueller.specular_transmission`` itself at grazing light: m00 off by exactly its own error
        (1.3e-3 at cos_o = 1e-5), other entries up to 1.3e-6 / cos_o of m00.
        """
        mi = mitsuba_polarized
        z = np.geomspace(1e-4, 0.05, 100)
        wi = direction(np.arccos(z), rng.uniform(0, 2 * PI, 100))
        wo = hemisphere(rng, 100)
        wi, wo = np.concatenate([wi, wo]), np.concatenate([wo, wi])  # grazing camera, then grazing light
        spec_theirs = mi_eval(mi, mi_pplastic(mi, 0.0, eta, alpha), wi, wo)
        assert_close_to_mitsuba(dielectric_pbrdf(wi, wo, albedo=0.0, eta=eta, alpha=alpha), spec_theirs, rtol=2e-5)
        theirs = mi_eval(mi, mi_pplastic(mi, albedo, eta, alpha), wi, wo)
        ours = dielectric_pbrdf(wi, wo, albedo=albedo, eta=eta, alpha=alpha)
        err = np.max(np.abs(ours - theirs), axis=(-2, -1)) / theirs[:, 0, 0]
        assert np.all(err <= MI_RTOL + 2e-7 / wi[:, 2] ** 2 + 3e-6 / wo[:, 2])

    def test_no_circular_polarization(self, rng):
        """Real eta: no retardance, so row 3 and column 3 carry only m33 (in any frame)."""
        m = dielectric_pbrdf(hemisphere(rng, 500), hemisphere(rng, 500), albedo=0.5, eta=1.5, alpha=0.3)
        np.testing.assert_array_equal(m[:, 3, :3], 0.0)
        np.testing.assert_array_equal(m[:, :3, 3], 0.0)

    def test_complex_eta_raises(self):
        with pytest.raises(ValueError, match="real eta"):
            dielectric_pbrdf([0, 0, 1.0], [0, 0, 1.0], albedo=0.5, eta=1.5 - 0.1j, alpha=0.3)

    @pytest.mark.parametrize(("kwargs", "match"), [({"albedo": 1.2}, "albedo"), ({"specular": -1.0}, "specular")])
    def test_out_of_range_raises(self, kwargs, match):
        args = {"albedo": 0.5, "eta": 1.5, "alpha": 0.3} | kwargs
        with pytest.raises(ValueError, match=match):
            dielectric_pbrdf([0, 0, 1.0], [0, 0, 1.0], **args)


class TestConductorPbrdf:
    @pytest.mark.parametrize(("eta", "alpha"), CONDUCTORS)
    def test_against_mitsuba_roughconductor(self, mitsuba_polarized, rng, eta, alpha):
        """All 16 entries at 250 random pairs on the whole upper hemisphere (grazing included)."""
        wi, wo = hemisphere(rng, 250), hemisphere(rng, 250)
        theirs = mi_eval(mitsuba_polarized, mi_roughconductor(mitsuba_polarized, eta, alpha), wi, wo)
        assert_close_to_mitsuba(conductor_pbrdf(wi, wo, eta=eta, alpha=alpha), theirs, rtol=2e-5)

    def test_against_mitsuba_specular_scale(self, mitsuba_polarized, rng):
        wi, wo = hemisphere(rng, 50), hemisphere(rng, 50)
        theirs = mi_eval(mitsuba_polarized, mi_roughconductor(mitsuba_polarized, GOLD, 0.2, specular=0.6), wi, wo)
        assert_close_to_mitsuba(conductor_pbrdf(wi, wo, eta=GOLD, alpha=0.2, specular=0.6), theirs, rtol=2e-5)

    def test_eta_sign_of_k_is_ignored(self, rng):
        """n + ik is read as n - ik, as in Mitsuba (pbrdf.polar.fresnel)."""
        wi, wo = hemisphere(rng, 50), hemisphere(rng, 50)
        np.testing.assert_array_equal(
            conductor_pbrdf(wi, wo, eta=GOLD, alpha=0.3), conductor_pbrdf(wi, wo, eta=GOLD.conjugate(), alpha=0.3)
        )

    def test_unpolarized_light_gets_no_circular_part(self, rng):
        m = conductor_pbrdf(hemisphere(rng, 500), hemisphere(rng, 500), eta=GOLD, alpha=0.3)
        np.testing.assert_array_equal(m[:, 3, 0], 0.0)
        assert np.max(np.abs(m[:, 3, 1:3])) > 0.1 * np.max(m[:, 0, 0])

    def test_circular_only_from_light_oblique_to_the_plane(self, rng):
        """Specular-direction gold: linear light along s or p stays linear, +-45 degrees to s gets |s3| large.

        Gold (eta = 0.18 - 3.2i) at 60 degrees retards p against s by about 100 degrees (pbrdf.polar.fresnel), so
        45-degree light leaves strongly elliptical (s3/s0 = 0.8 at 0.27 - 2.78i).
        Fields are built as 3-D vectors and converted with Mitsuba's frames, so the test does not assume them.
        """
        phi = rng.uniform(0, 2 * PI, 64)
        wo = direction(np.radians(60), phi)
        wi = reflect_about_normal(wo)
        m = conductor_pbrdf(wi, wo, eta=GOLD, alpha=0.05)
        s = unit(np.cross(wo, wi))  # perpendicular to the plane of incidence
        p_in = np.cross(s, -wo)  # in the plane, perpendicular to the incident ray
        for e, circular in [(s, False), (p_in, False), (unit(s + p_in), True), (unit(s - p_in), True)]:
            out = np.einsum("nij,nj->ni", m, linear_stokes(e, -wo))
            ellipticity = np.abs(out[:, 3]) / out[:, 0]
            if circular:
                assert np.all(ellipticity > 0.5)
            else:
                np.testing.assert_allclose(ellipticity, 0.0, atol=TOL.f64)

    def test_vertical_light_gets_circular_part_only_on_oblique_planes(self):
        """The project's case: display light polarized along the Stokes x-axis (s1 = +-1).

        Both Stokes bases of a plane of incidence containing the x-axis (azimuth 0) lie in that plane, so
        s1-polarized light is p or s and stays linear (m31 = 0); turn the plane to azimuth 30 degrees and the
        same basis is oblique to it: m31 != 0.
        """
        theta = np.radians(50)
        for phi, oblique in [(0.0, False), (PI, False), (PI / 6, True)]:
            wo = direction(theta, phi)
            m = conductor_pbrdf(reflect_about_normal(wo), wo, eta=GOLD, alpha=0.05)
            if oblique:
                assert abs(m[3, 1]) > 0.1 * m[0, 0]
            else:
                assert abs(m[3, 1]) < TOL.f64 * m[0, 0]
                assert abs(m[3, 2]) > 0.3 * m[0, 0]


# --- Frame convention ---------------------------------------------------------------------------------


class TestFrameConvention:
    """Pins the rule of the module Convention on Mitsuba itself, then on this module.

    Light arrives along -wo (Stokes x-axis stokes_basis(-wo), y = (-wo) x x) and leaves along wi
    (x-axis stokes_basis(wi), y = wi x x): s-polarized light (field along wo x wi) reflects
    s-polarized, and the p state stays p.
    """

    @staticmethod
    def _check_eigenstates(m, wi, wo):
        s = unit(np.cross(wo, wi))
        for e_in, e_out in [(s, s), (np.cross(s, -wo), np.cross(s, wi))]:
            out = np.einsum("nij,nj->ni", m, linear_stokes(e_in, -wo))
            # Near Brewster's angle the p state is hardly reflected and Mitsuba's float32 output is mostly noise.
            ok = out[:, 0] > 0.05 * m[:, 0, 0]
            assert np.mean(ok) > 0.8
            np.testing.assert_allclose(dolp(out[ok]), 1.0, atol=1e-4)
            # field direction up to sign
            np.testing.assert_allclose(np.abs(np.sum(polarization_direction(out, wi) * e_out, -1))[ok], 1.0, atol=1e-4)

    @staticmethod
    def _specular_pairs(rng, n=100):
        """Random pairs; the half vector is the microfacet normal, so the eigenstates hold for any (wi, wo)."""
        return hemisphere(rng, n, 0.05), hemisphere(rng, n, 0.05)

    def test_mitsuba_roughconductor(self, mitsuba_polarized, rng):
        wi, wo = self._specular_pairs(rng)
        # 2.9 - 3.0i: s and p both well above zero reflectance, so both directions are measurable.
        self._check_eigenstates(
            mi_eval(mitsuba_polarized, mi_roughconductor(mitsuba_polarized, 2.9 - 3j, 0.3), wi, wo), wi, wo
        )

    def test_mitsuba_pplastic_specular(self, mitsuba_polarized, rng):
        wi, wo = self._specular_pairs(rng)
        m = mi_eval(mitsuba_polarized, mi_pplastic(mitsuba_polarized, 0.0, 2.4, 0.3), wi, wo)
        self._check_eigenstates(m, wi, wo)

    def test_this_module(self, rng):
        wi, wo = self._specular_pairs(rng)
        self._check_eigenstates(conductor_pbrdf(wi, wo, eta=2.9 - 3j, alpha=0.3), wi, wo)
        self._check_eigenstates(dielectric_pbrdf(wi, wo, albedo=0.0, eta=2.4, alpha=0.3), wi, wo)

    def test_other_conventions_disagree_with_mitsuba(self, mitsuba_polarized, rng):
        """The comparison is sensitive to the frames: a mirrored y-axis on either side, or camera and light
        swapped, misses Mitsuba by more than 10 % of m00 on most pairs.

        Note: reversing the ray does not change its x-axis, stokes_basis(-w) == stokes_basis(w) for w_z != 0 (the
        Duff et al. basis), so "the basis of wo" and "of -wo" differ only in y = w x x, i.e. in the signs of s2, s3.
        """
        wi, wo = hemisphere(rng, 100, 0.05), hemisphere(rng, 100, 0.05)
        np.testing.assert_array_equal(mueller.stokes_basis(-wo), mueller.stokes_basis(wo))
        theirs = mi_eval(mitsuba_polarized, mi_roughconductor(mitsuba_polarized, GOLD, 0.3), wi, wo)
        ours = conductor_pbrdf(wi, wo, eta=GOLD, alpha=0.3)
        mirror = np.diag([1.0, 1.0, -1.0, -1.0])
        swapped = conductor_pbrdf(wo, wi, eta=GOLD, alpha=0.3) * (wo[:, 2] / wi[:, 2])[:, None, None]
        for other in (ours @ mirror, mirror @ ours, swapped):
            err = np.max(np.abs(other - theirs), axis=(-2, -1)) / theirs[:, 0, 0]
            assert np.median(err) > 0.1


# --- Physics -----------------------------------------------------------------------------------------


def _both_models():
    return [
        pytest.param(lambda wi, wo, a: dielectric_pbrdf(wi, wo, albedo=0.8, eta=1.5, alpha=a), id="dielectric"),
        pytest.param(lambda wi, wo, a: conductor_pbrdf(wi, wo, eta=GOLD, alpha=a), id="conductor"),
    ]


class TestReciprocity:
    @pytest.mark.parametrize("model", _both_models())
    @pytest.mark.parametrize("alpha", [0.05, 0.3, 0.7])
    def test_m00_helmholtz(self, rng, model, alpha):
        """f(wi, wo) = f(wo, wi) for the BRDF without the cos factor."""
        wi, wo = hemisphere(rng, 300), hemisphere(rng, 300)
        f = model(wi, wo, alpha)[:, 0, 0] / wo[:, 2]
        f_swapped = model(wo, wi, alpha)[:, 0, 0] / wi[:, 2]
        np.testing.assert_allclose(f_swapped, f, rtol=1e-12)

    @pytest.mark.parametrize("model", _both_models())
    def test_mueller_reciprocity(self, rng, model):
        """Reversed path: M_rev = Q M^T Q, Q = diag(1, 1, -1, 1), with each ray's x-axis kept for the reversed ray.

        Mueller form of the Jones reciprocity theorem (Z. Sekera, J. Opt. Soc. Am. 56:1732, 1966). A frame check
        independent of Mitsuba: the forward matrix uses stokes_basis(-wo) in and stokes_basis(wi) out, so the
        reversed one uses stokes_basis(wi) for the ray along -wi and stokes_basis(-wo) for the ray along wo (the
        right-handed y = w x x flips with w, as the theorem requires), then is rotated into the reversed
        ray's own bases.
        """
        wi, wo = hemisphere(rng, 300), hemisphere(rng, 300)
        q = np.diag([1.0, 1.0, -1.0, 1.0])
        forward = model(wi, wo, 0.3) / wo[:, 2, None, None]
        reverse = model(wo, wi, 0.3) / wi[:, 2, None, None]
        sb = mueller.stokes_basis
        predicted = mueller.rotate_mueller_basis(
            q @ np.swapaxes(forward, -1, -2) @ q, -wi, sb(wi), sb(-wi), wo, sb(-wo), sb(wo)
        )
        np.testing.assert_allclose(predicted, reverse, atol=1e-12 * np.max(np.abs(reverse)))


def _albedo_mc(model, wi, alpha, rng, n=100_000):
    """Directional albedo int m00 dwo (m00 already includes cos_o): one-sample mixture of GGX and cosine sampling.

    Returns (estimate, standard error). GGX half vectors h with pdf D(h) cos(theta_h) (Walter et al. 2007, eq. 35),
    wo = reflect(wi, h), pdf(wo) = D cos_h / (4 wo.h); cosine-weighted wo with pdf cos_o / pi.
    """
    u, v, pick = rng.random(n), rng.random(n), rng.random(n) < 0.5
    a = max(alpha, ALPHA_MIN)
    h = direction(np.arctan(a * np.sqrt(u / (1 - u))), 2 * PI * v)
    wo_spec = 2 * np.sum(wi * h, -1, keepdims=True) * h - wi
    wo_cos = direction(np.arcsin(np.sqrt(u)), 2 * PI * v)
    wo = np.where(pick[:, None], wo_spec, wo_cos)
    above = wo[:, 2] > 0
    hh = unit(wi + wo)
    pdf = (
        0.5 * ggx_d(hh[:, 2], alpha) * hh[:, 2] / (4 * np.abs(np.sum(wo * hh, -1))) + 0.5 * np.maximum(wo[:, 2], 0) / PI
    )
    f = model(np.broadcast_to(wi, wo.shape), wo, alpha)[:, 0, 0]
    x = np.where(above, f / np.where(above, pdf, 1.0), 0.0)
    return x.mean(), x.std() / np.sqrt(n)


class TestEnergy:
    @pytest.mark.parametrize("alpha", [0.05, 0.3, 0.7])
    @pytest.mark.parametrize("theta_deg", [0.0, 45.0, 80.0])
    def test_dielectric_albedo_at_most_one(self, rng, alpha, theta_deg):
        wi = direction(np.radians(theta_deg), 0.3)
        est, se = _albedo_mc(lambda a, b, al: dielectric_pbrdf(a, b, albedo=1.0, eta=1.5, alpha=al), wi, alpha, rng)
        assert est <= 1.0 + 4 * se
        # diffuse part alone: rho T(theta_i) int T(theta_o) cos_o / pi < T(theta_i)
        est_d, se_d = _albedo_mc(
            lambda a, b, al: dielectric_pbrdf(a, b, albedo=1.0, eta=1.5, alpha=al, specular=0.0), wi, alpha, rng
        )
        assert est_d <= fresnel.transmission_mueller(wi[2], 1.5)[0, 0] + 4 * se_d

    @pytest.mark.parametrize("alpha", [0.05, 0.3, 0.7])
    @pytest.mark.parametrize("theta_deg", [0.0, 45.0, 80.0])
    def test_conductor_albedo_at_most_one(self, rng, alpha, theta_deg):
        wi = direction(np.radians(theta_deg), 1.1)
        est, se = _albedo_mc(lambda a, b, al: conductor_pbrdf(a, b, eta=GOLD, alpha=al), wi, alpha, rng)
        assert est <= 1.0 + 4 * se

    @pytest.mark.parametrize(("alpha", "expected"), [(0.05, 0.9968), (0.3, 0.8636)])
    def test_white_furnace_near_mirror(self, rng, alpha, expected):
        """A near-perfect reflector (|eta| = 1000) at 30 degrees: the GGX-Smith lobe integrates to almost 1.

        The separable Smith term loses energy (shadowing and reflections below the horizon; none is gained): a
        dense (theta, phi) grid quadrature of D G1 G1 / (4 cos_i) gives 0.9968 (alpha 0.05) and 0.8636 (alpha 0.3).
        """
        wi = direction(np.radians(30.0), 0.0)
        est, se = _albedo_mc(lambda a, b, al: conductor_pbrdf(a, b, eta=1 - 1000j, alpha=al), wi, alpha, rng)
        assert est == pytest.approx(expected, abs=4 * se + 1e-3)


class TestPolarizationStates:
    def test_mirror_signs_at_normal_incidence(self):
        """wi = wo = n: R0 diag(1, 1, -1, -1) times D G / 4 (the mirror flips s2 and s3)."""
        n = [0.0, 0.0, 1.0]
        spec = dielectric_pbrdf(n, n, albedo=0.0, eta=1.5, alpha=0.1)
        expected = 0.04 / (PI * 0.1**2) / 4  # R0 = ((1.5 - 1) / (1.5 + 1))^2, D(n) = 1 / (pi alpha^2), G = 1
        np.testing.assert_allclose(spec, expected * np.diag([1.0, 1.0, -1.0, -1.0]), rtol=1e-13, atol=TOL.f64)
        gold = conductor_pbrdf(n, n, eta=GOLD, alpha=0.1)
        r0 = fresnel.fresnel_reflectance(1.0, GOLD) / (PI * 0.1**2) / 4
        np.testing.assert_allclose(gold, r0 * np.diag([1.0, 1.0, -1.0, -1.0]), rtol=1e-13, atol=TOL.f64 * r0)

    def test_mirror_signs_in_specular_direction(self, rng):
        """Near-normal specular geometry (10 degrees), any azimuth: m33 < 0 (handedness flips) and the linear block
        m[1:3, 1:3] has a negative determinant (an improper map, like diag(1, -1)); both are independent of the
        Stokes bases, which rotate the linear block only. The xz-plane case is exact: m11 > 0 and m22, m33 < 0."""
        wo = direction(np.radians(10.0), rng.uniform(0, 2 * PI, 32))
        wi = reflect_about_normal(wo)
        for m in (
            dielectric_pbrdf(wi, wo, albedo=0.0, eta=1.5, alpha=0.1),
            conductor_pbrdf(wi, wo, eta=GOLD, alpha=0.1),
        ):
            assert np.all(m[:, 3, 3] < 0)
            assert np.all(np.linalg.det(m[:, 1:3, 1:3]) < 0)
        wo = direction(np.radians(10.0), 0.0)
        for m in (
            dielectric_pbrdf(reflect_about_normal(wo), wo, albedo=0.0, eta=1.5, alpha=0.1),
            conductor_pbrdf(reflect_about_normal(wo), wo, eta=GOLD, alpha=0.1),
        ):
            assert m[1, 1] > 0 and m[2, 2] < 0 and m[3, 3] < 0

    def test_specular_polarized_perpendicular_diffuse_radial(self, rng):
        """Unpolarized light: the specular lobe leaves polarized along s = wo x wi (perpendicular to the plane of
        reflection), the diffuse lobe along the plane through the normal and wi (radially)."""
        wi, wo = hemisphere(rng, 300, 0.1), hemisphere(rng, 300, 0.1)
        spec = dielectric_pbrdf(wi, wo, albedo=0.0, eta=1.5, alpha=0.3)[:, :, 0]
        diff = dielectric_pbrdf(wi, wo, albedo=0.8, eta=1.5, alpha=0.3, specular=0.0)[:, :, 0]
        s_spec = unit(np.cross(wo, wi))
        s_diff = unit(np.cross([0.0, 0.0, 1.0], wi))
        np.testing.assert_allclose(
            np.abs(np.sum(polarization_direction(spec, wi) * s_spec, -1)), 1.0, atol=TOL.f64_inverse
        )
        np.testing.assert_allclose(np.sum(polarization_direction(diff, wi) * s_diff, -1), 0.0, atol=TOL.f64_inverse)

    def test_diffuse_weaker_than_specular(self, rng):
        """Mirror geometry (theta_d = theta_i): the diffuse DoLP (T_p - T_s) / (T_p + T_s) is below the specular
        (R_s - R_p) / (R_s + R_p), since R_s - R_p = T_p - T_s and R < T (eta 1.5: up to 82.8 degrees)."""
        wo = direction(rng.uniform(0.05, np.radians(80), 200), rng.uniform(0, 2 * PI, 200))
        wi = reflect_about_normal(wo)
        spec = dielectric_pbrdf(wi, wo, albedo=0.0, eta=1.5, alpha=0.3)[:, :, 0]
        diff = dielectric_pbrdf(wi, wo, albedo=0.8, eta=1.5, alpha=0.3, specular=0.0)[:, :, 0]
        assert np.all(dolp(diff) < dolp(spec))
        assert np.all(dolp(diff) < 0.247)  # (T_p - T_s) / (T_p + T_s) = 0.2464 at 80 deg, eta 1.5

    def test_in_plane_angles_are_90_degrees_apart(self, rng):
        """wi and wo in one vertical plane: the two lobes' AoLPs differ by exactly 90 degrees."""
        phi = rng.uniform(0, 2 * PI, 50)
        wi = direction(rng.uniform(0.1, 1.4, 50), phi)
        wo = direction(rng.uniform(0.1, 1.4, 50), phi + PI)
        spec = dielectric_pbrdf(wi, wo, albedo=0.0, eta=1.5, alpha=0.3)[:, :, 0]
        diff = dielectric_pbrdf(wi, wo, albedo=0.8, eta=1.5, alpha=0.3, specular=0.0)[:, :, 0]
        aolp = lambda s: 0.5 * np.arctan2(s[:, 2], s[:, 1])  # noqa: E731
        d = np.mod(aolp(spec) - aolp(diff), PI)
        np.testing.assert_allclose(d, PI / 2, atol=TOL.f64_inverse)


# --- Shapes and numerical stress ------------------------------------------------------------------------


class TestShapes:
    def test_broadcasting(self, rng):
        wi = hemisphere(rng, 5)[:, None, :]  # (5, 1, 3)
        wo = hemisphere(rng, 3)  # (3, 3)
        alpha = np.array([[0.1], [0.2], [0.3], [0.4], [0.5]])  # (5, 1)
        m = dielectric_pbrdf(wi, wo, albedo=0.5, eta=1.5, alpha=alpha)
        assert m.shape == (5, 3, 4, 4) and m.dtype == np.float64
        np.testing.assert_allclose(m[2, 1], dielectric_pbrdf(wi[2, 0], wo[1], albedo=0.5, eta=1.5, alpha=0.3))
        assert conductor_pbrdf(wi, wo, eta=np.array([GOLD, 1.2 - 7j, 2.9 - 3j]), alpha=0.3).shape == (5, 3, 4, 4)
        assert conductor_pbrdf([0, 0, 1.0], [0, 0, 1.0], eta=GOLD, alpha=np.full((2, 7), 0.3)).shape == (2, 7, 4, 4)

    def test_below_horizon_is_zero(self, rng):
        up = hemisphere(rng, 20)
        down = up * np.array([1.0, 1.0, -1.0])
        flat = unit(up * np.array([1.0, 1.0, 0.0]))  # z = 0 exactly: on the horizon
        for wi, wo in [(up, down), (down, up), (down, down), (flat, up), (up, flat)]:
            np.testing.assert_array_equal(dielectric_pbrdf(wi, wo, albedo=0.5, eta=1.5, alpha=0.3), 0.0)
            np.testing.assert_array_equal(conductor_pbrdf(wi, wo, eta=GOLD, alpha=0.3), 0.0)

    @pytest.mark.parametrize("shape", [(3,), (2, 4)])
    def test_wrong_direction_shape_raises(self, shape):
        with pytest.raises(ValueError, match="shape"):
            conductor_pbrdf(np.zeros((*shape[:-1], 2)), [0, 0, 1.0], eta=GOLD, alpha=0.3)


def _stress_pairs():
    """Degenerate and extreme geometry, one batch: grazing (z = 1e-8), wi == wo, h = n, normal."""
    g = 1e-8
    rt = np.sqrt(1 - g * g)
    graze = np.array([[rt, 0.0, g], [0.0, -rt, g], [-rt * 0.6, rt * 0.8, g]])
    n = np.array([[0.0, 0.0, 1.0]])
    tilted = direction(np.radians([30.0, 60.0, 89.0]), np.radians([10.0, 200.0, -70.0]))
    wi = np.concatenate([graze, graze, n, graze, tilted, tilted, graze, n])
    wo = np.concatenate(
        [
            graze,  # wi == wo at grazing
            reflect_about_normal(graze),  # h = n at grazing
            n,  # wi == wo == n
            tilted,  # grazing camera, oblique light
            tilted,  # wi == wo
            reflect_about_normal(tilted),  # h = n
            graze[::-1],  # both grazing, unrelated
            graze[:1],  # normal camera, grazing light
        ]
    )
    return wi, wo


class TestNumericalStress:
    @pytest.mark.filterwarnings("error")
    @pytest.mark.parametrize("alpha", [0.0, 1e-6, ALPHA_MIN, 0.3, 1.0])
    def test_finite_without_warnings(self, alpha):
        wi, wo = _stress_pairs()
        for a, b in [(wi, wo), (wo, wi)]:
            for m in (
                dielectric_pbrdf(a, b, albedo=0.8, eta=1.33, alpha=alpha),
                conductor_pbrdf(a, b, eta=GOLD, alpha=alpha),
            ):
                assert np.all(np.isfinite(m))
                assert np.all(m[:, 0, 0] >= 0)
                # intensity bound of a physical Mueller matrix: m00 >= |(m01, m02, m03)|, and likewise for column 0
                assert np.all(m[:, 0, 0] * (1 + 1e-9) >= np.linalg.norm(m[:, 0, 1:], axis=-1))
                assert np.all(m[:, 0, 0] * (1 + 1e-9) >= np.linalg.norm(m[:, 1:, 0], axis=-1))

    @pytest.mark.filterwarnings("error")
    def test_degenerate_pairs_are_limits_of_nearby_pairs(self):
        """wi == wo (retro-reflection: the plane of reflection is undefined) and wi == wo == n match the
        matrices of pairs 1e-7 rad away, so the fallback frame is the continuous choice."""
        wo = direction(np.radians([0.0, 35.0, 70.0]), np.radians([0.0, 120.0, -40.0]))
        for eps_dir in ([1.0, 0, 0], [0, 1.0, 0]):
            near = unit(wo + 1e-7 * np.cross(wo + [0.1, 0.2, 0.0], eps_dir))
            for f in (
                lambda a, b: dielectric_pbrdf(a, b, albedo=0.5, eta=1.5, alpha=0.3),
                lambda a, b: conductor_pbrdf(a, b, eta=GOLD, alpha=0.3),
            ):
                exact, close = f(wo, wo), f(near, wo)
                np.testing.assert_allclose(exact, close, atol=1e-5 * np.max(np.abs(exact)))

    @pytest.mark.filterwarnings("error")
    def test_tiny_alpha_is_a_peak_at_the_mirror_direction(self):
        wo = direction(np.radians(40.0), 0.5)
        wi = reflect_about_normal(wo)
        off = direction(np.radians(41.0), 0.5 + PI)
        peak = conductor_pbrdf(wi, wo, eta=GOLD, alpha=1e-6)[0, 0]
        assert np.isfinite(peak) and peak > 1e6
        assert conductor_pbrdf(off, wo, eta=GOLD, alpha=1e-6)[0, 0] < 1e-6 * peak
