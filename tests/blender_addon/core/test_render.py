"""Physics of the polarized renderer: real Mitsuba renders checked against closed forms.

Conventions under test (docs/ARCHITECTURE.md): the display's light is vertically polarized
(s1 < 0 in the camera frame), the pattern's red half is on the display's right as seen from the
object (+X display = world -x, which a mirror facing the camera shows on the image's LEFT),
blue is the upper half, and row 0 of every output is the top of the image.
"""

import dataclasses
import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")

from blender_addon.core import render, scenegen  # noqa: E402
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from pbrdf.data import sample as psample  # noqa: E402
from pbrdf.polar import fresnel  # noqa: E402
from pbrdf.sensor.rig import DisplaySpec, Rig  # noqa: E402


def _translate(x, y, z, scale=1.0):
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = (x, y, z)
    return tuple(map(tuple, m))


def _spec(objects, materials, rig=None, seed=0):
    return SceneSpec(rig=rig or Rig(), objects=tuple(objects), materials=tuple(materials), seed=seed)


MIRROR = MaterialSpec.metal("mirror", eta=(0.05, 0.05, 0.05), k=(9.0, 9.0, 9.0), roughness=0.0)


class TestDisplayThroughMirror:
    """A mirror facing the camera shows the display directly (normal incidence)."""

    @pytest.fixture(scope="class")
    @classmethod
    def mirror(cls, slab_path):
        spec = _spec([ObjectSpec("slab", slab_path, _translate(0, 0, -0.7), "mirror")], [MIRROR])
        return render.render_stokes(spec, render.RenderSettings(resolution=64, spp=16))

    def test_vertical_polarization(self, mirror):
        h, w = mirror.mask.shape
        s = mirror.stokes[8:-8, 8:-8].reshape(-1, 3, 4)
        lit = s[..., 0] > 0.1
        # Normal incidence keeps s1 (mirror = R0 diag(1, 1, -1, -1)): vertical light stays vertical.
        # Off-axis pixels see the slab at up to 12 degrees, where |r_s| != |r_p| slightly
        # (-0.998 measured), hence 5e-3.
        np.testing.assert_allclose(s[..., 1][lit] / s[..., 0][lit], -1.0, atol=5e-3)
        # Oblique rays through the sheet carry the field Y - (Y.d) d, turned in the image by about
        # -dx*dy (d the ray direction), and the slightly oblique reflection then adds a little
        # retardance (|s3| about 0.01 in the corners, sign by quadrant): only near the optical
        # axis are s2 and s3 exactly 0.
        centre = mirror.stokes[h // 2 - 4 : h // 2 + 4, w // 2 - 4 : w // 2 + 4].reshape(-1, 3, 4)
        lit_c = centre[..., 0] > 0.1
        assert np.abs(centre[..., 2][lit_c] / centre[..., 0][lit_c]).max() < 0.01
        assert np.abs(centre[..., 3][lit_c] / centre[..., 0][lit_c]).max() < 0.01
        assert np.abs(s[..., 3][lit] / s[..., 0][lit]).max() < 0.03

    def test_radiance_is_display_times_fresnel(self, mirror):
        # Display radiance 1 (the sheet's 50 % loss is compensated) times R0 of the mirror.
        r0 = float(fresnel.fresnel_reflectance(1.0, 0.05 - 9.0j))
        s0 = mirror.stokes[16:-16, 8:24, 0, 0]  # well inside the red (left) half of the image
        assert np.median(s0) == pytest.approx(r0, rel=0.01)

    def test_pattern_orientation(self, mirror):
        h, w = mirror.mask.shape
        s0 = mirror.stokes[..., 0]  # (H, W, 3)
        rows_top, rows_bottom = slice(8, h // 2 - 4), slice(h // 2 + 4, h - 8)
        cols_left, cols_right = slice(8, w // 2 - 4), slice(w // 2 + 4, w - 8)
        # Red is the display's right half seen from the object = world -x = the mirror image's left.
        assert s0[:, cols_left, 0].mean() > 0.5 and s0[:, cols_right, 0].max() < 0.02
        assert s0[:, cols_right, 1].mean() > 0.5 and s0[:, cols_left, 1].max() < 0.02
        # Blue is the upper half, and row 0 is the top of the image.
        assert s0[rows_top, :, 2].mean() > 0.5 and s0[rows_bottom, :, 2].max() < 0.02

    def test_polarization_angle_45(self, slab_path):
        # Polarization at +45 degrees from +X toward +Y (seen from the front) is the world
        # direction (-x + y); a normal-incidence mirror keeps the field direction, which the
        # camera frame (x right, y up) sees at 135 degrees: s2 = sin(270 deg) s0 = -s0.
        rig = Rig(display=DisplaySpec(polarization_angle=math.pi / 4))
        spec = _spec([ObjectSpec("slab", slab_path, _translate(0, 0, -0.7), "mirror")], [MIRROR], rig=rig)
        res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=8))
        s = res.stokes[8:-8, 8:-8].reshape(-1, 3, 4)
        lit = s[..., 0] > 0.1
        np.testing.assert_allclose(s[..., 2][lit] / s[..., 0][lit], -1.0, atol=5e-3)


def test_lambertian_slab_matches_irradiance_integral(slab_path):
    """An index-matched pplastic (no specular) is Lambertian: L = rho/pi * E_c per channel, with
    E_c the irradiance from channel c's region of the display (numerical quadrature here)."""
    albedo = (0.8, 0.5, 0.3)
    # ior 1.001: Mitsuba needs distinct indices; R0 = 2.5e-7 is negligible.
    mat = MaterialSpec.plastic("lambert", albedo, roughness=0.5, ior=1.001)
    spec = _spec([ObjectSpec("slab", slab_path, _translate(0.05, -0.03, -0.6), "lambert")], [mat])
    res = render.render_stokes(spec, render.RenderSettings(resolution=48, spp=256))
    disp = spec.rig.display
    # Quadrature over the display (display-local X, Y), radiance 1 per lit channel.
    n = 400
    xs = (np.arange(n) + 0.5) / n * disp.width - disp.width / 2
    ys = (np.arange(n // 2) + 0.5) / (n // 2) * disp.height - disp.height / 2
    gx, gy = np.meshgrid(xs, ys)
    pts = disp.surface_points_world(np.stack([gx.ravel(), gy.ravel()], -1))
    rgb = disp.pattern_rgb_at(np.stack([gx.ravel(), gy.ravel()], -1))
    d_area = disp.width * disp.height / gx.size
    nd = disp.normal_world()
    k = res.window.intrinsics(spec.rig.camera)
    h, w = res.mask.shape
    # Pixels well inside the front face: the surface point is on the plane z = -0.6 + 0.005.
    rows, cols = np.nonzero(res.mask)
    sel = (rows > rows.min() + 4) & (rows < rows.max() - 4) & (cols > cols.min() + 4) & (cols < cols.max() - 4)
    rows, cols = rows[sel][::7], cols[sel][::7]
    z = -0.6 + 0.005
    ratios = []
    for r, c in zip(rows, cols, strict=True):
        ray = np.array([(c + 0.5 - k[0, 2]) / k[0, 0], -(r + 0.5 - k[1, 2]) / k[1, 1], -1.0])
        p = ray * (z / ray[2])
        to = pts - p
        dist2 = np.sum(to**2, -1)
        wdir = to / np.sqrt(dist2)[:, None]
        cos_p = np.clip(wdir[:, 2], 0, None)
        cos_d = np.clip(-(wdir @ nd), 0, None)
        irr = (cos_p * cos_d / dist2) @ rgb * d_area
        expected = np.asarray(albedo) / np.pi * irr
        ratios.append(res.stokes[r, c, :, 0] / expected)
    ratios = np.asarray(ratios)
    # Unbiased (measured mean 1.001, 1.001, 0.999 over 156 pixels) with 2.3 % Monte Carlo noise
    # per pixel at 256 spp.
    np.testing.assert_allclose(ratios.mean(axis=0), 1.0, atol=0.01)
    assert np.all(np.abs(ratios - 1) < 0.12)
    # Lambertian reflection of polarized light is unpolarized.
    pol = np.linalg.norm(res.stokes[rows, cols, :, 1:], axis=-1)
    assert np.all(pol < 0.02 * res.stokes[rows, cols, :, 0] + 1e-4)


class TestSpheres:
    @pytest.fixture(scope="class")
    @classmethod
    def plastic(cls):
        # Dark base so the 4 % specular reflection of the display dominates the highlight.
        mat = MaterialSpec.plastic("plastic", (0.1, 0.1, 0.1), roughness=0.15)
        spec = _spec([ObjectSpec("ball", "builtin:sphere", _translate(0, 0, -0.7, 0.2), "plastic")], [mat])
        return spec, render.render_stokes(spec, render.RenderSettings(resolution=64, spp=64))

    @pytest.fixture(scope="class")
    @classmethod
    def gold(cls):
        mat = MaterialSpec.metal("gold", eta=(0.18, 0.5, 1.3), k=(3.2, 2.3, 1.85), roughness=0.1)
        spec = _spec([ObjectSpec("ball", "builtin:sphere", _translate(0, 0, -0.7, 0.2), "gold")], [mat])
        return spec, render.render_stokes(spec, render.RenderSettings(resolution=64, spp=64))

    def test_normals_and_depth_match_analytic_sphere(self, plastic):
        spec, res = plastic
        k = res.window.intrinsics(spec.rig.camera)
        h, w = res.mask.shape
        jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        d = np.stack([(jj - k[0, 2]) / k[0, 0], -(ii - k[1, 2]) / k[1, 1], -np.ones_like(jj)], -1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        centre, radius = np.array([0, 0, -0.7]), 0.1
        b = d @ centre
        disc = b**2 - (centre @ centre - radius**2)
        hit = disc > 0
        t = b - np.sqrt(np.where(hit, disc, 0))
        p = d * t[..., None]
        n = (p - centre) / radius
        # Interior pixels (away from the silhouette, where a pixel mixes object and background).
        inner = hit & (np.sqrt(np.maximum(disc, 0)) > 0.25 * radius) & res.mask
        cos = np.sum(res.normal[inner] * n[inner], -1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1.5  # tessellated sphere, 2562 vertices
        np.testing.assert_allclose(res.depth[inner], -p[inner][:, 2], atol=2e-3)
        # Mask agrees with the analytic silhouette except on boundary pixels.
        assert np.mean(res.mask != hit) < 0.05

    def test_plastic_lp_at_highlight_diffuse_polarization_at_rim(self, plastic):
        _, res = plastic
        s = res.stokes.sum(axis=2)  # all colour channels together: the display is white overall
        dolp = np.where(res.mask, np.hypot(s[..., 1], s[..., 2]) / np.maximum(s[..., 0], 1e-6), 0)
        h, w = res.mask.shape
        centre = (slice(h // 2 - 4, h // 2 + 4), slice(w // 2 - 4, w // 2 + 4))
        # The display sits behind the camera: the mirror direction at the sphere's centre hits
        # it, and the specular, vertically polarized part dominates (LP = -s1 > 0).
        assert dolp[centre].mean() > 0.3
        assert (-s[..., 1][centre]).mean() > 0.3 * s[..., 0][centre].mean()
        # Near the left and right silhouette mirror directions miss the display. What remains is
        # diffuse light, whose weak polarization from the exit refraction is parallel to the
        # plane of emission: radial, i.e. horizontal there (s1 > 0, LP < 0), 90 degrees from
        # the specular highlight's.
        rows = slice(h // 2 - 3, h // 2 + 3)
        cols = np.nonzero(res.mask[h // 2] & (res.coverage[h // 2] > 0.99))[0]
        for col in (cols[:3], cols[-3:]):
            s_rim = s[rows][:, col]
            assert np.all(s_rim[..., 1] > 0)
            assert np.all(dolp[rows][:, col] < dolp[centre].mean())

    def test_conductor_cp_only_where_incidence_plane_is_oblique(self, gold):
        _, res = gold
        s = res.stokes[..., 0, :]  # red channel (highest reflectance)
        h, w = res.mask.shape
        cy, cx = h / 2, w / 2
        yy, xx = np.mgrid[0:h, 0:w] + 0.5
        lit = res.mask & (s[..., 0] > 0.05)
        cp = np.where(lit, s[..., 3] / np.maximum(s[..., 0], 1e-6), 0)
        ang = np.degrees(np.arctan2(yy - cy, xx - cx)) % 90
        axis = lit & ((ang < 5) | (ang > 85))  # plane of incidence horizontal or vertical
        diag = lit & (np.abs(ang - 45) < 10) & (np.hypot(yy - cy, xx - cx) > 3)
        assert axis.sum() > 10 and diag.sum() > 10
        # Near-normal incidence keeps the retardance small: a few percent on the diagonals
        # (measured about 0.045), Monte Carlo noise (about 0.009) on the axes.
        assert np.abs(cp[diag]).mean() > 0.02
        assert np.abs(cp[diag]).mean() > 3 * np.abs(cp[axis]).mean()
        # The sign follows the quadrant: opposite diagonals of the highlight turn the light
        # with opposite handedness.
        # (The red half of the display lights the left half of the highlight only.)
        upper_left = diag & (yy < cy) & (xx < cx)
        lower_left = diag & (yy > cy) & (xx < cx)
        assert upper_left.sum() > 5 and lower_left.sum() > 5
        assert np.sign(cp[upper_left].mean()) == -np.sign(cp[lower_left].mean())


def test_row_zero_is_top_and_object_ids(tmp_path):
    mats = [MaterialSpec.plastic("a", (0.5, 0.5, 0.5), 0.3), MaterialSpec.plastic("b", (0.2, 0.2, 0.2), 0.3)]
    objs = [
        ObjectSpec("top", "builtin:sphere", _translate(0, 0.08, -0.7, 0.1), "a"),
        ObjectSpec("bottom", "builtin:sphere", _translate(0, -0.08, -0.7, 0.1), "b"),
    ]
    spec = _spec(objs, mats)
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=4))
    rows_top = np.nonzero(res.object_index == 0)[0]
    rows_bottom = np.nonzero(res.object_index == 1)[0]
    assert rows_top.size > 20 and rows_bottom.size > 20
    assert rows_top.mean() < res.mask.shape[0] / 2 < rows_bottom.mean()
    gt = render.ground_truth(spec, res)
    assert np.allclose(gt["albedo"][res.object_index == 1], 0.2)


def test_synthesized_sample_is_valid_and_decodes_to_the_rendered_stokes():
    mat = MaterialSpec.plastic("plastic", (0.6, 0.4, 0.2), roughness=0.3)
    # A white display: no colour edges in the reflections, whose Bayer aliasing (a colour is
    # sampled on one block in four) would move colour between channels by up to 10 % of LP.
    rig = Rig(display=DisplaySpec(pattern="white"))
    spec = _spec([ObjectSpec("ball", "builtin:blob?seed=3", _translate(0, 0, -0.7, 0.25), "plastic")], [mat], rig=rig)
    res = render.render_stokes(spec, render.RenderSettings(resolution=48, spp=16))
    sample, meta = render.synthesize_sample(spec, res, rng=np.random.default_rng(0), noise=False, keep_stokes=True)
    psample.validate_sample(sample, meta)
    assert sample["maps"].shape == (48, 48, 9)
    # The sidecar says how it was rendered: the blob is one convex object, lit directly by the emitter.
    assert (meta["display_model"], meta["integrator"], meta["max_depth"]) == ("emitter", "direct", 2)
    m = sample["mask"]
    # Noise-free camera: the decoded maps are the rendered unpol = s0 + s1 and LP = -s1 up to
    # 12-bit steps and the decoder's interpolation, which redistributes but does not bias them:
    # compare means away from the silhouette.
    from scipy import ndimage

    inner = ndimage.binary_erosion(m, iterations=4)  # the demosaic reaches 2 blocks out
    unpol = res.stokes[..., 0] + res.stokes[..., 1]
    lp = -res.stokes[..., 1]
    for c in range(3):
        assert sample["maps"][..., c][inner].mean() == pytest.approx(unpol[..., c][inner].mean(), rel=0.01)
        # (measured: unpol within 0.5 %, LP within 4 % where the white display's reflection has
        # sharp edges)
        assert sample["maps"][..., 3 + c][inner].mean() == pytest.approx(lp[..., c][inner].mean(), rel=0.06, abs=1e-4)


def test_measured_lambertian_table_matches_pplastic(tmp_path, slab_path):
    """A measured_polarized table with M00 = albedo/pi (all else 0) is a Lambertian, depolarizing
    surface: its S0 must equal the index-matched pplastic slab's, channel by channel, while its
    reflected light is unpolarized. The table is written with Mitsuba's own tensor_io (an
    independent writer; the project's table format is a separate issue)."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    from mitsuba import tensor_io

    albedo = 0.6
    n_phi, n_td, n_th, wvls = 9, 7, 7, np.array([450, 500, 550, 600, 650], np.uint16)
    m = np.zeros((n_phi, n_td, n_th, len(wvls), 4, 4), np.float32)
    m[..., 0, 0] = albedo / np.pi
    table = tmp_path / "lambert.pbsdf"
    tensor_io.write(
        str(table),
        phi_d=np.linspace(-np.pi, np.pi, n_phi, dtype=np.float32)[None],
        theta_d=np.linspace(0, np.pi / 2, n_td, dtype=np.float32)[None],
        theta_h=np.linspace(0, np.pi / 2, n_th, dtype=np.float32)[None],
        wvls=wvls,
        M=m,
    )
    measured = MaterialSpec.measured("table", str(table), (albedo,) * 3, roughness=1.0, metallic=0.0)
    plastic = MaterialSpec.plastic("lambert", (albedo,) * 3, roughness=0.5, ior=1.001)
    out = {}
    for mat in (measured, plastic):
        spec = _spec([ObjectSpec("slab", slab_path, _translate(0, 0, -0.6), mat.name)], [mat])
        out[mat.name] = render.render_stokes(spec, render.RenderSettings(resolution=24, spp=128))
    a, b = out["table"], out["lambert"]
    inner = a.mask & b.mask
    inner[:4], inner[-4:], inner[:, :4], inner[:, -4:] = False, False, False, False
    np.testing.assert_allclose(a.stokes[inner][..., 0].mean(0), b.stokes[inner][..., 0].mean(0), rtol=0.03)
    assert np.abs(a.stokes[inner][..., 1:]).max() < 1e-3 + 0.02 * a.stokes[inner][..., 0].max()


def test_curved_display_keeps_polarization_and_pattern(slab_path):
    """A 1000R display (a curved strip mesh with the pattern as a bitmap) seen in a mirror:
    still vertically polarized, red on the image's left, blue on top."""
    rig = Rig(display=DisplaySpec(curvature_radius=1.0))
    spec = _spec([ObjectSpec("slab", slab_path, _translate(0, 0, -0.7), "mirror")], [MIRROR], rig=rig)
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=16))
    h, w = res.mask.shape
    centre = res.stokes[h // 2 - 4 : h // 2 + 4, w // 2 - 4 : w // 2 + 4].reshape(-1, 3, 4)
    lit = centre[..., 0] > 0.1
    np.testing.assert_allclose(centre[..., 1][lit] / centre[..., 0][lit], -1.0, atol=0.01)
    s0 = res.stokes[..., 0]
    assert s0[6:-6, 6 : w // 2 - 3, 0].mean() > 0.5 and s0[6:-6, w // 2 + 3 : -6, 0].max() < 0.02
    assert s0[6 : h // 2 - 3, 6:-6, 2].mean() > 0.5 and s0[h // 2 + 3 : -6, 6:-6, 2].max() < 0.02


def test_spectral_variant_is_the_fallback_route():
    """Without LLVM the renderer falls back to scalar_spectral_polarized: render_stokes must
    route there and return the same kind of result (object ids, normals, vertical light)."""
    mat = MaterialSpec.plastic("plastic", (0.5, 0.5, 0.5), roughness=0.3)
    spec = _spec([ObjectSpec("ball", "builtin:sphere", _translate(0, 0, -0.7, 0.2), "plastic")], [mat])
    res = render.render_stokes(spec, render.RenderSettings(resolution=16, spp=4, variant="scalar_spectral_polarized"))
    assert res.variant == "scalar_spectral_polarized"
    assert res.stokes.shape == (16, 16, 3, 4)
    assert (res.object_index == 0).sum() == res.mask.sum() > 50
    assert np.all(np.isfinite(res.stokes))


def test_diffuse_material_depolarizes_the_display_light():
    """A Lambertian object in the polarized pipeline: lit (unpol > 0) but no linear polarization left."""
    spec = scenegen.random_scene(Rig(), 5)
    spec = dataclasses.replace(
        spec,
        materials=(MaterialSpec.diffuse("chalk", (0.8, 0.5, 0.3)),),
        objects=(dataclasses.replace(spec.objects[0], material="chalk"),),
    )
    result = render.render_stokes(spec, render.RenderSettings(resolution=16, spp=8))
    s = result.stokes[result.mask]  # (N, 3, 4)
    lit = s[..., 0] > 1e-3
    assert lit[:, 0].mean() > 0.3  # the red half of the display lights the object
    dolp = np.hypot(s[..., 1], s[..., 2])[lit] / s[..., 0][lit]
    assert np.median(dolp) < 1e-3


# --------------------------------------------------------------------------- speed: path length, tables, kernel reuse


def _metal_object(shape, seed=0):
    gold = MaterialSpec.metal("gold", eta=(0.18, 0.5, 1.3), k=(3.2, 2.3, 1.85), roughness=0.2)
    return _spec([ObjectSpec("o", shape, _translate(0.02, -0.01, -0.7, 0.25), "gold")], [gold], seed=seed)


@pytest.mark.parametrize(("shape", "auto_depth"), [("builtin:sphere", 2), ("builtin:torus", 3)])
def test_auto_max_depth_is_direct_light_only_where_that_changes_nothing(shape, auto_depth):
    """max_depth None renders a sphere with direct light only (depth 2), the same as with one
    interreflection within noise; a torus sees itself, so it keeps depth 3, and there direct
    light alone is visibly darker (measured at 48 px, 256 spp: -3.8 % mean S0, noise 0.1 %).
    Noise of the sphere's mean S0 between seeds at 32 px, 64 spp: 0.2 % (direct, depth 2) and
    0.4 % (path, depth 3); at 256 spp half that, so 0.5 % is about 2.5 sigma of the difference."""
    res = {}
    for depth, seed in ((None, 1), (2, 2), (3, 3)):
        settings = render.RenderSettings(resolution=32, spp=256, max_depth=depth)
        res[depth] = render.render_stokes(_metal_object(shape, seed), settings)
    assert res[None].max_depth == auto_depth and res[3].max_depth == 3
    m = res[3].mask
    s0 = {d: r.stokes[m][..., 0].mean() for d, r in res.items()}
    if auto_depth == 2:
        assert abs(s0[2] / s0[3] - 1) < 0.005
    else:
        assert s0[2] / s0[3] < 0.98


def test_table_material_switches_channels_by_parameters_as_a_rebuild_with_the_plugin(gold_table, monkeypatch):
    """Table materials render with table_bsdf and switch channels by a parameter update; the same
    scene rebuilt per channel with measured_polarized (the previous route) gives the same images
    (same seeds and sampling: alpha 0.2 is one of ALPHA_SAMPLE_LEVELS)."""
    from blender_addon.core import mitsuba_scene as ms

    mat = MaterialSpec.measured("gold", str(gold_table), (0.9, 0.6, 0.3), roughness=0.2**0.5, metallic=1.0)
    spec = _spec([ObjectSpec("o", "builtin:blob?seed=1", _translate(0.02, -0.01, -0.7, 0.25), "gold")], [mat])
    settings = render.RenderSettings(resolution=32, spp=16)
    ours = render.render_stokes(spec, settings)
    monkeypatch.setattr(ms, "_table_bsdf", lambda material: False)
    plugin = render.render_stokes(spec, settings)
    m = ours.mask
    assert m.sum() > 200 and np.array_equal(m, plugin.mask)
    for c in range(3):
        a, b = ours.stokes[m][:, c], plugin.stokes[m][:, c]
        assert np.abs(a - b).max() < 1e-4 * np.abs(b[:, 0]).max()
    assert ours.stokes[m][..., 0].std(axis=0).min() > 0  # lit in every channel


def test_kernels_compiled_once_serve_later_samples(gold_table):
    """The second sample of each kind compiles nothing, although its crop window, its material
    values and (for tables) its table data and importance-sampling roughness differ."""
    settings = render.RenderSettings(resolution=32, spp=3)
    blob = "builtin:blob?seed=1"
    other = gold_table.parent / "other.pbsdf"
    other.write_bytes(gold_table.read_bytes())
    near, far = _translate(0.02, -0.01, -0.7, 0.25), _translate(-0.05, 0.03, -0.6, 0.15)
    cases = {
        "analytic": [
            (MaterialSpec.plastic("m", (0.6, 0.4, 0.2), roughness=0.3), near),
            (MaterialSpec.plastic("m", (0.2, 0.5, 0.7), roughness=0.6), far),
        ],
        "table": [
            (MaterialSpec.measured("m", str(gold_table), (0.9, 0.6, 0.3), 0.3, 1.0), near),
            (MaterialSpec.measured("m", str(other), (0.9, 0.6, 0.3), 0.7, 1.0), far),
        ],
    }
    for kind, samples in cases.items():
        results = [
            render.render_stokes(_spec([ObjectSpec("o", blob, pose, "m")], [mat], seed=i), settings)
            for i, (mat, pose) in enumerate(samples)
        ]
        assert results[0].window != results[1].window
        assert results[1].seconds["jit_compile"] == 0.0, kind
