"""textured_bsdf: textured materials render, region by region, as the untextured materials they hold.

Each textured path is compared with an independent reference: two renders of Mitsuba's plain
(untextured) plugins with each region's constants, the same seeds and sample positions. The slab
faces the camera with planar OpenGL UVs (u = +x, v = +y), so the image's top half is the
texture's top half.
"""

import dataclasses
import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")
trimesh = pytest.importorskip("trimesh")

from blender_addon.core import render, textured_bsdf  # noqa: E402
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from blender_addon.core.textures import MaterialTextures, TextureSpec  # noqa: E402
from pbrdf.brdf import seeds, table  # noqa: E402
from pbrdf.sensor.rig import DisplaySpec, Rig  # noqa: E402
from tests.blender_addon.core.textured_helpers import halves, png, pose, uv_slab_file  # noqa: E402

SETTINGS = render.RenderSettings(resolution=32, spp=32)
WHITE = Rig(display=DisplaySpec(pattern="white"))


@pytest.fixture(scope="module")
def uv_slab(tmp_path_factory):
    return uv_slab_file(tmp_path_factory.mktemp("mesh"))


def render_one(slab, material, rig=WHITE, settings=SETTINGS, tilt=0.0, toward="x"):
    obj = ObjectSpec("slab", slab, pose(tilt, toward), material.name)
    spec = SceneSpec(rig=rig, objects=(obj,), materials=(material,))
    return render.render_stokes(spec, settings)


def assert_same_region(a, b, region, rel=0.04):
    """Stokes means of a region agree per channel and component, relative to S0."""
    ma, mb = a.stokes[region].mean(axis=0), b.stokes[region].mean(axis=0)  # (3, 4)
    scale = np.maximum(mb[:, :1], 1e-4)
    np.testing.assert_allclose(ma / scale, mb / scale, atol=rel)


def test_top_of_the_texture_is_the_top_of_the_image_and_transforms_apply(mono, uv_slab, tmp_path):
    bright_top = png(tmp_path, "top.png", 230, 20)
    mat = MaterialSpec.plastic("p", (0.5,) * 3, 0.4)
    res = render_one(uv_slab, dataclasses.replace(mat, textures=MaterialTextures(albedo=TextureSpec(bright_top))))
    top, bottom = halves(res)
    s0 = res.stokes[..., 0, 0]
    assert s0[top].mean() > 4 * s0[bottom].mean()
    # KHR_texture_transform offset (0.5, 0): the left half of the surface looks up the right half.
    bright_left = png(tmp_path, "left.png", None, 20, left=230)
    tex = TextureSpec(bright_left, offset=(0.5, 0.0))
    res = render_one(uv_slab, dataclasses.replace(mat, textures=MaterialTextures(albedo=tex)))
    cols = np.nonzero(res.mask)[1]
    mid = (cols.min() + cols.max()) / 2
    rr, cc = np.nonzero(res.mask)
    s0 = res.stokes[..., 0, 0]
    assert s0[rr[cc > mid + 3], cc[cc > mid + 3]].mean() > 4 * s0[rr[cc < mid - 3], cc[cc < mid - 3]].mean()


def test_textured_pplastic_equals_the_plain_plastics_it_holds(mono, uv_slab, tmp_path):
    tex = MaterialTextures(
        albedo=TextureSpec(png(tmp_path, "a.png", (204, 102, 51), (51, 153, 230))),
        roughness=TextureSpec(png(tmp_path, "r.png", 77, 179), channels=(0,), factor=(1.0,)),
    )
    textured = MaterialSpec("t", "pplastic", (0.5,) * 3, 0.5, 0.0, ior=1.5, textures=tex)
    res = render_one(uv_slab, textured)
    top, bottom = halves(res)
    for region, rgb, r in ((top, (204, 102, 51), 77), (bottom, (51, 153, 230), 179)):
        plain = render_one(uv_slab, MaterialSpec.plastic("t", tuple(c / 255 for c in rgb), r / 255, ior=1.5))
        assert_same_region(res, plain, region)
    # and differs from the other half's constants (the test can fail)
    other = render_one(uv_slab, MaterialSpec.plastic("t", (51 / 255, 153 / 255, 230 / 255), 179 / 255))
    assert (
        np.abs(res.stokes[top].mean(0)[:, 0] - other.stokes[top].mean(0)[:, 0]).max()
        > 0.2 * res.stokes[top][..., 0].mean()
    )


def test_metallic_texture_blends_the_dielectric_and_a_metal_of_that_reflectance(mono, uv_slab, tmp_path):
    albedo = (0.9, 0.6, 0.3)
    tex = MaterialTextures(metallic=TextureSpec(png(tmp_path, "m.png", 0, 255), channels=(0,), factor=(1.0,)))
    textured = MaterialSpec("t", "pplastic", albedo, 0.3, 0.5, ior=1.5, textures=tex)
    res = render_one(uv_slab, textured)
    top, bottom = halves(res)
    assert_same_region(res, render_one(uv_slab, MaterialSpec.plastic("t", albedo, 0.3, ior=1.5)), top)
    # n = 1: R0 = k^2 / (4 + k^2), so k = 2 sqrt(R0 / (1 - R0)).
    k = tuple(2 * math.sqrt(a / (1 - a)) for a in albedo)
    metal = MaterialSpec.metal("t", (1.0, 1.0, 1.0), k, 0.3)
    np.testing.assert_allclose(metal.albedo, albedo, rtol=1e-6)
    ref = render_one(uv_slab, metal)
    assert_same_region(res, ref, bottom)
    lp_top = np.abs(res.stokes[top].mean(0)[:, 1:3]).sum()
    assert np.abs(res.stokes[bottom].mean(0)[:, 1:3]).sum() > 0  # polarized both ways
    assert lp_top > 0


def test_conductor_albedo_texture_sets_each_texels_reflectance(mono, uv_slab, tmp_path):
    """A conductor whose albedo texture is its own R0 renders as the untextured conductor."""
    gold = MaterialSpec.metal("g", (0.16, 0.43, 1.38), (3.5, 2.4, 1.9), 0.3)
    level = tuple(int(round(255 * a)) for a in gold.albedo)
    tex = MaterialTextures(albedo=TextureSpec(png(tmp_path, "g.png", level, level)))
    res = render_one(uv_slab, dataclasses.replace(gold, textures=tex))
    ref = render_one(uv_slab, gold)
    top, bottom = halves(res)
    assert_same_region(res, ref, top | bottom, rel=0.03)


@pytest.fixture(scope="module")
def two_tables(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tables")
    out = []
    for name in ("gold", "red_billiard"):
        m = next(s for s in seeds.SEED_MATERIALS if s.name == name)
        path = folder / f"{name}.pbsdf"
        table.save_table(path, seeds.seed_table(m, (9, 7, 16)), for_mitsuba=True)
        out.append(str(path))
    return out


def test_table_mixture_with_weights_0_and_1_is_each_table(mono, uv_slab, two_tables, tmp_path):
    gold, red = two_tables
    weights = TextureSpec(png(tmp_path, "w.png", 0, 255), channels=(0,), factor=(1.0,))
    own = MaterialSpec.measured("t", gold, (0.9, 0.6, 0.3), 0.3, 1.0)
    mixed = dataclasses.replace(own, textures=MaterialTextures(tables=(red,), weights=weights))
    res = render_one(uv_slab, mixed)
    top, bottom = halves(res)
    assert_same_region(res, render_one(uv_slab, own), top)
    assert_same_region(res, render_one(uv_slab, MaterialSpec.measured("t", red, (0.5, 0.1, 0.1), 0.3, 0.0)), bottom)


def test_table_albedo_texture_scales_the_mueller_matrix(mono, uv_slab, two_tables, tmp_path):
    """Albedo texture = half the table's fitted albedo: every Stokes component halves."""
    gold = two_tables[0]
    own = MaterialSpec.measured("t", gold, (0.8, 0.6, 0.4), 0.3, 1.0)
    half = TextureSpec(png(tmp_path, "h.png", (102, 77, 51), (102, 77, 51)))
    res = render_one(uv_slab, dataclasses.replace(own, textures=MaterialTextures(albedo=half)))
    ref = render_one(uv_slab, own)
    top, bottom = halves(res)
    region = top | bottom
    scale = np.array([102 / 255 / 0.8, 77 / 255 / 0.6, 51 / 255 / 0.4])
    a, b = res.stokes[region].mean(0), ref.stokes[region].mean(0) * scale[:, None]
    np.testing.assert_allclose(a / b[:, :1], b / b[:, :1], atol=0.04)


def test_flat_normal_map_changes_nothing(mono, uv_slab, tmp_path):
    mat = MaterialSpec.plastic("p", (0.6, 0.5, 0.4), 0.4)
    rig = Rig()  # the rgb_halves display: LP and intensity depend on the surface's tilt
    plain = render_one(uv_slab, mat, rig=rig)
    flat = png(tmp_path, "flat.png", (128, 128, 255), (128, 128, 255))
    res = render_one(uv_slab, dataclasses.replace(mat, textures=MaterialTextures(normal=TextureSpec(flat))), rig=rig)
    top, bottom = halves(res)
    assert_same_region(res, plain, top | bottom, rel=0.03)


@pytest.mark.parametrize("toward", ["x", "y"])
def test_tilted_normal_map_renders_as_the_tilted_surface(mono, uv_slab, tmp_path, toward):
    """A constant map tilted by 12 degrees toward +u (= +x) or +v (= +y, glTF's +y): as the slab turned so."""
    mat = MaterialSpec.plastic("p", (0.6, 0.5, 0.4), 0.4)
    rig = Rig()  # the rgb_halves display: LP and intensity depend on the surface's tilt
    theta = math.radians(12)
    n = (math.sin(theta), 0.0, math.cos(theta)) if toward == "x" else (0.0, math.sin(theta), math.cos(theta))
    enc = tuple(int(round(255 * (c + 1) / 2)) for c in n)
    tilted = dataclasses.replace(mat, textures=MaterialTextures(normal=TextureSpec(png(tmp_path, "t.png", enc, enc))))
    res = render_one(uv_slab, tilted, rig=rig)
    turned = render_one(uv_slab, mat, rig=rig, tilt=12.0, toward=toward)
    away = render_one(uv_slab, mat, rig=rig, tilt=-12.0, toward=toward)
    region = halves(res, margin=0.3)[0] | halves(res, margin=0.3)[1]
    centre = region & (halves(turned, margin=0.3)[0] | halves(turned, margin=0.3)[1])
    err = np.abs(res.stokes[centre].mean(0) - turned.stokes[centre].mean(0)).max()
    err_away = np.abs(res.stokes[centre].mean(0) - away.stokes[centre].mean(0)).max()
    s0 = res.stokes[centre].mean(0)[:, 0].max()
    assert err < 0.05 * s0 and err_away > 2 * err


@pytest.mark.slow  # measured_polarized compiles its kernels (about 20 s)
def test_textured_table_on_a_non_uniform_grid_uses_the_plugin_and_rebuilds(mono, uv_slab, two_tables, tmp_path):
    t = table.load_table(two_tables[0], mmap=False)
    theta_h = t.theta_h.copy()
    theta_h[1:-1] = np.sqrt(theta_h[1:-1] / theta_h[-1]) * theta_h[-1]
    path = tmp_path / "uneven.pbsdf"
    table.save_table(path, table.PBRDFTable(t.phi_d, t.theta_d, theta_h, t.wavelengths, t.M), for_mitsuba=True)
    half = TextureSpec(png(tmp_path, "h.png", (102, 77, 51), (102, 77, 51)))
    own = MaterialSpec.measured("u", str(path), (0.8, 0.6, 0.4), 0.3, 1.0)
    mat = dataclasses.replace(own, textures=MaterialTextures(albedo=half))
    assert "measured_polarized" in str(textured_bsdf.bsdf_dict(mat, 0))
    assert textured_bsdf.channel_updates(mat, 1, "obj.bsdf") is None  # rebuilt per channel
    res, ref = render_one(uv_slab, mat), render_one(uv_slab, own)
    region = halves(res)[0] | halves(res)[1]
    scale = np.array([102 / 255 / 0.8, 77 / 255 / 0.6, 51 / 255 / 0.4])
    a, b = res.stokes[region].mean(0), ref.stokes[region].mean(0) * scale[:, None]
    np.testing.assert_allclose(a / b[:, :1], b / b[:, :1], atol=0.04)
