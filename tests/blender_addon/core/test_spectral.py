"""Cross-check: the per-channel mono renders agree with one spectral-polarized render of the same scene.

The default renderer (:func:`render.render_stokes`) evaluates each colour channel once, at one
wavelength, lit by that channel's share of the display pattern. :func:`spectral.render_stokes_spectral`
renders every wavelength at once, with the display emitting D65 x (upsampled RGB) spectra and the
materials evaluated per wavelength, and converts each Stokes component to linear sRGB.

* For wavelength-flat materials (grey pplastic, a grey mirror) the two agree in expectation: the
  remaining differences are Monte Carlo noise (the spectral pass adds wavelength-sampling noise).
* For a wavelength-dependent material (gold, a measured table with an albedo ramp) each spectral
  channel integrates the reflectance over the channel's whole sRGB matching function (including
  its negative lobes) and over the broad emission spectra of all display regions (e.g. the green
  region's spectrum leaks into red after a non-grey reflection). The resulting ratio spectral /
  mono is predicted here from Mitsuba's own colour matching functions, D65 and RGB upsampling and
  checked against the renders.
* Polarization (s1/s0, DoLP) does not depend on the spectral treatment for grey materials, and
  hardly for gold (its Fresnel retardance varies slowly with wavelength): checked tightly.
"""

import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")

from blender_addon.core import render, spectral  # noqa: E402
from blender_addon.core.mitsuba_scene import CHANNEL_WAVELENGTHS_NM  # noqa: E402
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from pbrdf.polar import fresnel  # noqa: E402
from pbrdf.sensor.rig import DisplaySpec, Rig  # noqa: E402

# Resolution and samples of the cross-check renders (the same for both renderers).
SETTINGS = render.RenderSettings(resolution=64, spp=256)
GOLD_ETA, GOLD_K = (0.18, 0.5, 1.3), (3.2, 2.3, 1.85)


def _translate(x, y, z, scale=1.0):
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = (x, y, z)
    return tuple(map(tuple, m))


def _spec(material, mesh="builtin:sphere", to_world=None, rig=None, seed=0):
    to_world = to_world or _translate(0, 0, -0.7, 0.2)
    return SceneSpec(
        rig=rig or Rig(),
        objects=(ObjectSpec("obj", mesh, to_world, material.name),),
        materials=(material,),
        seed=seed,
    )


def _both(spec, settings=SETTINGS):
    return render.render_stokes(spec, settings), spectral.render_stokes_spectral(spec, settings)


def _masked(mono, spec_res):
    """Stokes (N, 3, 4) of both renders over the pixels both call object."""
    m = mono.mask & spec_res.mask
    return mono.stokes[m], spec_res.stokes[m]


def _lit(s, frac=0.2):
    """Pixels (N, 3) whose S0 exceeds ``frac`` of the channel's maximum."""
    return s[..., 0] > frac * s[..., 0].max(axis=0)


def _dolp(s):
    """Degree of linear polarization of the mask-summed Stokes vectors, per channel."""
    tot = s.sum(axis=0)
    return np.hypot(tot[:, 1], tot[:, 2]) / tot[:, 0]


LAMBDA_NM = np.arange(360.0, 831.0)  # 1 nm steps over Mitsuba's colour matching range


def _spectral_rgb(reflectance, region_colours):
    """What the spectral renderer's colour channels expect from a reflection, summed over display
    regions of equal weight.

    Channel c: ``sum_q sum_lambda rgb_c(lambda) D65(lambda) up_q(lambda) R(lambda) / sum_lambda
    rgb_c D65`` with ``rgb_c`` the sRGB matching functions (CIE 1931 through Mitsuba's XYZ -> sRGB
    matrix), ``up_q`` Mitsuba's smooth upsampling of region colour q and R the reflectance
    spectrum on :data:`LAMBDA_NM`. The mono passes see ``sum_q P_c(q) R(lambda_c)`` instead.
    """
    mi = pytest.importorskip("mitsuba")
    previous = mi.variant()
    mi.set_variant("scalar_spectral_polarized")
    try:
        cmf = np.array([list(mi.cie1931_xyz(float(w))) for w in LAMBDA_NM])
        xyz_to_rgb = np.array([list(mi.xyz_to_srgb(mi.Color3f(*e))) for e in np.eye(3)]).T
        rgb_w = cmf @ xyz_to_rgb.T
        d65 = np.array([mi.cie_d65(float(w)) for w in LAMBDA_NM])
        ups = []
        for q in region_colours:
            coeff = mi.srgb_model_fetch(mi.Color3f(*q))
            ups.append([mi.srgb_model_eval(coeff, mi.UnpolarizedSpectrum(float(w)))[0] for w in LAMBDA_NM])
    finally:
        if previous is not None:
            mi.set_variant(previous)
    norm = (rgb_w * d65[:, None]).sum(axis=0)
    return sum((rgb_w * (d65 * np.asarray(u) * reflectance)[:, None]).sum(axis=0) / norm for u in ups)


def _predicted_gold_ratio(quadrant_colours):
    """Predicted (spectral / mono) S0 per channel for gold: normal-incidence reflectance of the
    piecewise-linear eta, k spectra the spectral renderer uses, display regions of equal weight."""
    wl_r, wl_g, wl_b = CHANNEL_WAVELENGTHS_NM

    def spectrum(rgb):
        r, g, b = rgb
        return np.interp(LAMBDA_NM, [360, wl_b, wl_g, wl_r, 830], [b, b, g, r, r])

    eta, k = spectrum(GOLD_ETA), spectrum(GOLD_K)
    f_lam = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
    f_mono = np.array([((n - 1) ** 2 + kk**2) / ((n + 1) ** 2 + kk**2) for n, kk in zip(GOLD_ETA, GOLD_K, strict=True)])
    mono_sum = sum(np.asarray(q, float) for q in quadrant_colours) * f_mono
    return _spectral_rgb(f_lam, quadrant_colours) / mono_sum


# --------------------------------------------------------------------------- the display's spectra


@pytest.mark.parametrize("pattern", ["white", "image"])
def test_display_colour_seen_in_a_grey_mirror(slab_path, tmp_path, pattern):
    """A grey mirror shows the display colour times R0 in both renderers: the D65-weighted emitter
    spectra render as their RGB values (white as (1, 1, 1), not (1.205, 0.95, 0.89))."""
    from PIL import Image

    colour = np.ones(3)
    if pattern == "image":
        colour = np.array([51, 153, 230]) / 255.0  # linear pattern values 0.2, 0.6, 0.9
        pattern = str(tmp_path / "pattern.png")
        Image.fromarray(np.full((9, 16, 3), (51, 153, 230), np.uint8)).save(pattern)
    mirror = MaterialSpec.metal("mirror", eta=(0.05, 0.05, 0.05), k=(9.0, 9.0, 9.0), roughness=0.0)
    rig = Rig(display=DisplaySpec(pattern=pattern))
    spec = _spec(mirror, slab_path, _translate(0, 0, -0.7), rig=rig)
    mono, spec_res = _both(spec, render.RenderSettings(resolution=32, spp=32))
    r0 = float(fresnel.fresnel_reflectance(1.0, 0.05 - 9.0j))
    for res in (mono, spec_res):
        s = res.stokes[6:-6, 6:-6].reshape(-1, 3, 4)
        # (measured over 4 seeds: spectral within 0.25 % per channel, mono within 0.06 %)
        np.testing.assert_allclose(s[..., 0].mean(axis=0), r0 * colour, rtol=0.01)
        # Normal incidence keeps the vertical polarization (s1/s0 = -1 up to the off-axis
        # pixels' slightly oblique reflection, as in test_render).
        np.testing.assert_allclose(s[..., 1] / s[..., 0], -1.0, atol=5e-3)


# --------------------------------------------------------------------------- cross-checks


@pytest.fixture(scope="module")
def lambertian():
    # ior 1.001: no specular lobe (R0 = 2.5e-7); grey albedo 0.5 under the default rgb_halves display.
    mat = MaterialSpec.plastic("lambert", (0.5, 0.5, 0.5), roughness=0.5, ior=1.001)
    return _both(_spec(mat))


@pytest.fixture(scope="module")
def glossy_plastic():
    # Grey, dark base: the polarized specular reflection of the display dominates the highlight.
    mat = MaterialSpec.plastic("plastic", (0.1, 0.1, 0.1), roughness=0.15, ior=1.5)
    return _both(_spec(mat))


@pytest.fixture(scope="module")
def gold():
    mat = MaterialSpec.metal("gold", eta=GOLD_ETA, k=GOLD_K, roughness=0.1)
    return _both(_spec(mat))


def test_lambertian_sphere_agrees(lambertian):
    sm, ss = _masked(*lambertian)
    # Mean S0 over the object, per channel: over 8 seeds at 64 px / 256 spp (multijitter) the
    # ratio's mean is 1 within 0.03 % and its spread 0.08 % (1 sigma), worst 0.17 %.
    np.testing.assert_allclose(ss[..., 0].mean(axis=0) / sm[..., 0].mean(axis=0), 1.0, atol=0.005)
    # A Lambertian reflection of polarized light is unpolarized in both (|s1|, |s2| < 1e-6 s0 measured).
    for s in (sm, ss):
        lit = _lit(s)
        assert np.abs(s[..., 1][lit] / s[..., 0][lit]).max() < 1e-3
        assert np.abs(s[..., 2][lit] / s[..., 0][lit]).max() < 1e-3


def test_grey_plastic_polarization_agrees(glossy_plastic):
    sm, ss = _masked(*glossy_plastic)
    # Over 8 seeds: S0 ratio within 0.13 %, LP ratio within 0.4 %, DoLP within 6e-4, the mean
    # per-pixel s1/s0 difference within 8e-4 and its mean magnitude (noise) below 0.005.
    np.testing.assert_allclose(ss[..., 0].mean(axis=0) / sm[..., 0].mean(axis=0), 1.0, atol=0.005)
    # LP = -s1 summed over the object (the specular highlight's vertical polarization).
    lp_m, lp_s = -sm[..., 1].sum(axis=0), -ss[..., 1].sum(axis=0)
    assert np.all(lp_m > 0.1 * sm[..., 0].sum(axis=0))
    np.testing.assert_allclose(lp_s / lp_m, 1.0, atol=0.015)
    # DoLP of the summed Stokes vectors: 0.171 in both.
    np.testing.assert_allclose(_dolp(ss), _dolp(sm), atol=0.002)
    # Per-pixel polarization state over lit pixels: the same geometry and Fresnel terms at every
    # wavelength, so s1/s0 agrees up to noise.
    lit = _lit(sm) & _lit(ss)
    d = ss[..., 1] / ss[..., 0] - sm[..., 1] / sm[..., 0]
    for c in range(3):
        assert abs(d[lit[:, c], c].mean()) < 0.002
        assert np.abs(d[lit[:, c], c]).mean() < 0.01


def test_gold_sphere_agrees_with_the_predicted_spectral_integration(gold):
    sm, ss = _masked(*gold)
    # The sphere is centred on the display's axis: the four quadrants of rgb_halves (upper-left
    # cyan, upper-right magenta, lower-left green, lower-right red) light equal shares of it.
    predicted = _predicted_gold_ratio([(0, 1, 1), (1, 0, 1), (0, 1, 0), (1, 0, 0)])
    # Prediction (1.059, 1.015, 0.928): the red channel's matching function is negative in the
    # blue-green, where gold reflects less, so red comes out brighter than F(630 nm); blue
    # averages over the dim green side. Over 8 seeds at 256 spp the renders sit (0.0, 0.0, +0.1) %
    # from the prediction on average (it takes normal incidence and exactly equal quadrant
    # shares), spread 0.2 % (1 sigma), worst 0.33 %.
    np.testing.assert_allclose(predicted, (1.059, 1.015, 0.928), atol=2e-3)
    ratio = ss[..., 0].mean(axis=0) / sm[..., 0].mean(axis=0)
    np.testing.assert_allclose(ratio, predicted, atol=0.008)
    # The spectral render differs from the mono one by several percent: the difference is real.
    assert abs(ratio[0] - 1) > 0.03 and abs(ratio[2] - 1) > 0.04
    # LP follows S0: a near-normal reflection off gold keeps the display's vertical polarization.
    lp_ratio = ss[..., 1].mean(axis=0) / sm[..., 1].mean(axis=0)
    np.testing.assert_allclose(lp_ratio, predicted, atol=0.008)
    # DoLP 0.994 (R, G), 0.996 (B) in both; measured differences below 4e-4 over 8 seeds.
    np.testing.assert_allclose(_dolp(ss), _dolp(sm), atol=1e-3)
    lit = _lit(sm) & _lit(ss)
    d = ss[..., 1] / ss[..., 0] - sm[..., 1] / sm[..., 0]
    for c in range(3):
        assert np.abs(d[lit[:, c], c]).mean() < 1e-3  # measured below 1.4e-4


def test_aovs_agree(lambertian):
    mono, spec_res = lambertian
    assert spec_res.stokes.shape == mono.stokes.shape == (64, 64, 3, 4)
    assert spec_res.window == mono.window
    assert spec_res.variant.endswith("spectral_polarized") and "pass_spectral" in spec_res.seconds
    both = mono.mask & spec_res.mask
    # Coverage is a per-pixel sample fraction: only silhouette pixels can differ.
    assert np.mean(mono.mask != spec_res.mask) < 0.01
    np.testing.assert_array_equal(spec_res.object_index[both], mono.object_index[both])
    assert np.all(spec_res.object_index[~spec_res.mask] == -1)
    inner = both & (mono.coverage == 1) & (spec_res.coverage == 1)
    # Normals and depth are averages over each pixel's samples. Measured: identical, since the
    # spectral pass draws the same sample positions as the mono first pass (same sampler and
    # seed); the tolerances allow for different positions (independent sampler: normals within
    # 0.007, depth within 7e-4 m).
    np.testing.assert_allclose(spec_res.normal[inner], mono.normal[inner], atol=0.02)
    np.testing.assert_allclose(spec_res.depth[inner], mono.depth[inner], atol=2e-3)


# --------------------------------------------------------------------------- set-up details


def test_conductor_spectra_pass_through_the_channel_values():
    mi = pytest.importorskip("mitsuba")
    mat = MaterialSpec.metal("gold", eta=GOLD_ETA, k=GOLD_K, roughness=0.1)
    d = spectral.bsdf_dict(mat)
    previous = mi.variant()
    mi.set_variant("scalar_spectral_polarized")
    try:
        si = mi.SurfaceInteraction3f()
        for key, values in (("eta", GOLD_ETA), ("k", GOLD_K)):
            tex = mi.load_dict(d[key])
            for wl, want in [*zip(CHANNEL_WAVELENGTHS_NM, values, strict=True), (360.0, values[2]), (830.0, values[0])]:
                si.wavelengths = mi.UnpolarizedSpectrum(wl)
                assert tex.eval(si)[0] == pytest.approx(want, rel=1e-5), (key, wl)
    finally:
        if previous is not None:
            mi.set_variant(previous)
    # Equal channel values give a plain number (an all-zero k has no irregular spectrum).
    assert spectral.bsdf_dict(MaterialSpec.metal("m", (0.2,) * 3, (0.0,) * 3, 0.1))["k"] == 0.0


def test_scalar_variant_and_curved_display():
    mats = [MaterialSpec.plastic("a", (0.5, 0.5, 0.5), 0.5, ior=1.001)]
    objs = (
        ObjectSpec("right", "builtin:sphere", _translate(0.08, 0, -0.7, 0.12), "a"),
        ObjectSpec("left", "builtin:sphere", _translate(-0.08, 0, -0.7, 0.12), "a"),
    )
    rig = Rig(display=DisplaySpec(curvature_radius=1.0))
    spec = SceneSpec(rig=rig, objects=objs, materials=tuple(mats))
    settings = render.RenderSettings(resolution=24, spp=16)
    scalar = spectral.render_stokes_spectral(spec, settings, variant="scalar_spectral_polarized")
    llvm = spectral.render_stokes_spectral(spec, settings)
    mono = render.render_stokes(spec, settings)
    assert scalar.variant == "scalar_spectral_polarized"
    # Object indices from the scalar variant's shape-index AOV (no Dr.Jit registry there; the
    # curved display's meshes come first in scene.shapes() here).
    cols = np.arange(24)[None, :].repeat(24, 0)
    for res in (scalar, llvm):
        assert cols[res.object_index == 0].mean() > 12 > cols[res.object_index == 1].mean()
    both = scalar.mask & llvm.mask
    np.testing.assert_array_equal(scalar.object_index[both], llvm.object_index[both])
    both = scalar.mask & mono.mask
    # Same light from the curved display (16 spp: the means agree within noise, about 2 %).
    for res in (scalar, llvm):
        np.testing.assert_allclose(res.stokes[both][:, :, 0].mean(0) / mono.stokes[both][:, :, 0].mean(0), 1, atol=0.08)


def test_variant_must_be_spectral_polarized():
    spec = _spec(MaterialSpec.plastic("a", (0.5, 0.5, 0.5), 0.5))
    with pytest.raises(ValueError, match="spectral_polarized"):
        spectral.render_stokes_spectral(spec, variant="llvm_ad_mono_polarized")


def test_polarization_angle_45_through_a_mirror(slab_path):
    """The sheet is the mono helper's (theta = -degrees(polarization_angle)) and the output layout
    puts S2 where the mono renderer does: +45 degrees seen in a mirror gives s2 = -s0 (test_render)."""
    mirror = MaterialSpec.metal("mirror", eta=(0.05, 0.05, 0.05), k=(9.0, 9.0, 9.0), roughness=0.0)
    rig = Rig(display=DisplaySpec(polarization_angle=math.pi / 4, pattern="white"))
    spec = _spec(mirror, slab_path, _translate(0, 0, -0.7), rig=rig)
    res = spectral.render_stokes_spectral(spec, render.RenderSettings(resolution=16, spp=8))
    s = res.stokes[4:-4, 4:-4].reshape(-1, 3, 4)
    np.testing.assert_allclose(s[..., 2] / s[..., 0], -1.0, atol=5e-3)
    # Off-axis rays turn the field slightly (|s1|/s0 up to 0.015 at the corners here).
    assert np.abs(s[..., 1] / s[..., 0]).max() < 0.03 and np.abs(s[..., 3] / s[..., 0]).max() < 0.03


def test_measured_table_uses_all_bands(tmp_path):
    """A Lambertian measured_polarized table whose albedo rises from 0.3 (450 nm) to 0.7 (650 nm):
    the spectral render integrates it over each channel's band (the plugin interpolates linearly
    between bands and holds the end values), the mono passes read it at 630, 532 and 465 nm."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    from mitsuba import tensor_io

    wvls = np.array([450, 500, 550, 600, 650], np.uint16)
    albedo = np.array([0.3, 0.4, 0.5, 0.6, 0.7])
    m = np.zeros((9, 7, 7, len(wvls), 4, 4), np.float32)
    m[..., 0, 0] = albedo / np.pi
    table = tmp_path / "ramp.pbsdf"
    tensor_io.write(
        str(table),
        phi_d=np.linspace(-np.pi, np.pi, 9, dtype=np.float32)[None],
        theta_d=np.linspace(0, np.pi / 2, 7, dtype=np.float32)[None],
        theta_h=np.linspace(0, np.pi / 2, 7, dtype=np.float32)[None],
        wvls=wvls,
        M=m,
    )
    mat = MaterialSpec.measured("ramp", str(table), (0.5, 0.5, 0.5), roughness=1.0, metallic=0.0)
    spec = _spec(mat, rig=Rig(display=DisplaySpec(pattern="white")))
    sm, ss = _masked(*_both(spec, render.RenderSettings(resolution=32, spp=128)))
    ratio = ss[..., 0].mean(axis=0) / sm[..., 0].mean(axis=0)
    rho = np.interp(LAMBDA_NM, wvls.astype(float), albedo)
    rho_mono = np.interp(CHANNEL_WAVELENGTHS_NM, wvls.astype(float), albedo)
    predicted = _spectral_rgb(rho, [(1, 1, 1)]) / rho_mono
    # Prediction (1.037, 1.044, 0.899); measured (1.038, 1.043, 0.898). A grey table agrees
    # within 0.1 % (so wavelengths outside 450-650 nm see the end bands, not 0).
    np.testing.assert_allclose(predicted, (1.037, 1.044, 0.899), atol=2e-3)
    np.testing.assert_allclose(ratio, predicted, atol=0.01)
    assert np.abs(ss[..., 1:]).max() < 1e-3 * ss[..., 0].max()  # M has no polarizing entries
