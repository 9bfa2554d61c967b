"""texture_truth: the ground truth of a textured scene is the texture at the rendered hits, pixel-filtered."""

import dataclasses
import json
import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")
trimesh = pytest.importorskip("trimesh")

from blender_addon.core import render  # noqa: E402
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from blender_addon.core.textures import MaterialTextures, TextureSpec  # noqa: E402
from pbrdf.brdf import seeds, table  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402
from tests.blender_addon.core.textured_helpers import halves, png, pose, uv_slab_file  # noqa: E402

CELLS = 8  # checker cells across the texture
SIZE = 64  # texture pixels across


@pytest.fixture(scope="module")
def uv_slab(tmp_path_factory):
    return uv_slab_file(tmp_path_factory.mktemp("mesh"))


def checker(folder, name, a, b, *, cells=CELLS):
    from PIL import Image

    i, j = np.mgrid[:SIZE, :SIZE] * cells // SIZE
    img = np.where(((i + j) % 2 == 0)[..., None], np.array(a, np.uint8), np.array(b, np.uint8))
    Image.fromarray(np.broadcast_to(img, (SIZE, SIZE, 3)).astype(np.uint8)).save(folder / name)
    return str(folder / name)


def cell_value(uv, a, b, cells=CELLS):
    """The checker's value at OpenGL UVs, cell by cell (image row 0 at the top: row = (1 - v) * SIZE)."""
    i = np.floor((1 - uv[..., 1]) * cells).astype(int)
    j = np.floor(uv[..., 0] * cells).astype(int)
    return np.where(((i + j) % 2 == 0)[..., None], np.asarray(a, float), np.asarray(b, float))


def edge_distance(uv, cells=CELLS):
    """Distance in UV from the nearest checker edge, per coordinate."""
    f = np.mod(uv * cells, 1.0)
    return np.minimum(f, 1 - f) / cells


def test_checker_truth_equals_the_texture_at_the_rendered_uvs(mono, uv_slab, tmp_path):
    a, b = (230, 51, 102), (26, 179, 128)
    tex = MaterialTextures(
        albedo=TextureSpec(checker(tmp_path, "a.png", a, b)),
        roughness=TextureSpec(checker(tmp_path, "r.png", 51, 204, cells=4), channels=(1,), factor=(1.0,)),
    )
    mat = MaterialSpec("c", "pplastic", (0.5,) * 3, 0.5, 0.0, ior=1.5, textures=tex)
    # Turned about y and z: the checker's edges run across pixels at an angle, the scale varies.
    c, s = math.cos(0.5), math.sin(0.5)
    m = np.asarray(pose(30.0)) @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("o", uv_slab, tuple(map(tuple, m)), "c"),), materials=(mat,))
    res = render.render_stokes(spec, render.RenderSettings(resolution=96, spp=16))
    gt = render.ground_truth(spec, res)
    # the same pixel sample positions as the first colour pass: the same coverage, sample by sample
    np.testing.assert_allclose(res.truth["coverage"], res.coverage, atol=1e-6)
    uv = res.truth["uv"]
    inside = res.coverage > 0.999
    du = np.abs(np.gradient(uv, axis=0)) + np.abs(np.gradient(uv, axis=1))  # the pixel's UV footprint
    for key, values, cells, lo_hi in (("albedo", gt["albedo"], CELLS, (a, b)), ("roughness", gt["roughness"], 4,
                                                                                 (51, 204))):  # fmt: skip
        expected = cell_value(uv, np.asarray(lo_hi[0]) / 255, np.asarray(lo_hi[1]) / 255, cells)
        if key == "roughness":
            expected = expected[..., 0]
        clear = inside & np.all(edge_distance(uv, cells) > du + 0.5 / SIZE, axis=-1)
        assert clear.sum() > 200
        err = np.abs(values - expected).reshape(*clear.shape, -1).max(axis=-1)
        # away from edges: the texture itself (8-bit levels, float32 filtering)
        assert np.quantile(err[clear], 0.99) < 2e-3, key
        # everywhere on the object: within interpolation error of the pixel-filtered edges
        near = inside & ~clear
        assert (err[near] < np.abs(np.subtract(*lo_hi)).max() / 255).all()
    # the coloured checker reached the stokes image too: S0 follows the albedo, cell by cell
    s0 = res.stokes[..., 0, 0]
    bright = inside & (gt["albedo"][..., 0] > 0.8)
    dark = inside & (gt["albedo"][..., 0] < 0.15)
    assert s0[bright].mean() > 2 * s0[dark].mean()


def test_untextured_scenes_keep_per_object_constants(mono, uv_slab):
    mat = MaterialSpec.plastic("p", (0.3, 0.4, 0.5), 0.6)
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("o", uv_slab, pose(), "p"),), materials=(mat,))
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=4))
    assert res.truth is None and "truth" not in res.seconds
    gt = render.ground_truth(spec, res)
    sel = res.object_index == 0
    np.testing.assert_array_equal(gt["albedo"][sel], np.broadcast_to(np.float32([0.3, 0.4, 0.5]), (int(sel.sum()), 3)))


def test_truth_pass_reports_an_untextured_objects_constants(mono, uv_slab, monkeypatch):
    """In a textured scene an untextured object's truth is its constants (a 2 x 2 bitmap in the truth pass)."""
    mat = MaterialSpec.metal("m", (0.2, 0.5, 1.1), (3.0, 2.5, 2.0), 0.3)
    monkeypatch.setattr(render, "needs_truth_pass", lambda spec: True)  # as beside a textured object
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("o", uv_slab, pose(20.0), "m"),), materials=(mat,))
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=4))
    region = res.mask
    assert res.truth is not None and region.sum() > 100
    n = int(region.sum())
    np.testing.assert_allclose(res.truth["albedo"][region], np.broadcast_to(mat.albedo, (n, 3)), rtol=1e-5)
    np.testing.assert_allclose(res.truth["roughness"][region], mat.roughness, rtol=1e-5)
    np.testing.assert_allclose(res.truth["metallic"][region], mat.metallic, rtol=1e-5)


def test_normal_map_truth_is_the_tilted_normal(mono, uv_slab, tmp_path):
    theta = math.radians(20)
    enc = tuple(int(round(255 * (c + 1) / 2)) for c in (0.0, math.sin(theta), math.cos(theta)))
    tex = MaterialTextures(normal=TextureSpec(png(tmp_path, "n.png", enc, enc)), normal_scale=1.0)
    mat = MaterialSpec("p", "pplastic", (0.5,) * 3, 0.4, 0.0, ior=1.5, textures=tex)
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("o", uv_slab, pose(), "p"),), materials=(mat,))
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=4))
    top, bottom = halves(res)
    # tilted toward +v = +y (glTF's +y, up in the image); camera frame = world frame here
    expected = 2 * np.array(enc) / 255 - 1  # the 8-bit map's normal
    expected /= np.linalg.norm(expected)
    np.testing.assert_allclose(res.normal[top | bottom], np.broadcast_to(expected, (int((top | bottom).sum()), 3)),
                               atol=2e-3)  # fmt: skip
    # normal_scale 0.5 halves the tangent part before renormalizing
    half = dataclasses.replace(mat, textures=dataclasses.replace(tex, normal_scale=0.5))
    spec = dataclasses.replace(spec, materials=(half,))
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=4))
    n = (2 * np.array(enc) / 255 - 1) * [0.5, 0.5, 1.0]
    np.testing.assert_allclose(res.normal[top | bottom].mean(0), n / np.linalg.norm(n), atol=2e-3)


def test_table_mixture_truth_mixes_the_tables_fitted_parameters(mono, uv_slab, tmp_path):
    entries = []
    for name, albedo, rough, metal in (("gold", (0.9, 0.6, 0.3), 0.3, 1.0), ("red", (0.5, 0.1, 0.1), 0.6, 0.0)):
        seed = next(s for s in seeds.SEED_MATERIALS if s.name == ("gold" if name == "gold" else "red_billiard"))
        table.save_table(tmp_path / f"{name}.pbsdf", seeds.seed_table(seed, (9, 7, 16)), for_mitsuba=True)
        entries.append(
            {"name": name, "table": f"{name}.pbsdf", "albedo": albedo, "roughness": rough, "metallic": metal}
        )
    (tmp_path / "materials.json").write_text(json.dumps(entries))
    weights = TextureSpec(png(tmp_path, "w.png", 64, 255), channels=(0,), factor=(1.0,))
    own = MaterialSpec.measured("t", str(tmp_path / "gold.pbsdf"), (0.9, 0.6, 0.3), 0.3, 1.0)
    mat = dataclasses.replace(own, textures=MaterialTextures(tables=(str(tmp_path / "red.pbsdf"),), weights=weights))
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("o", uv_slab, pose(), "t"),), materials=(mat,))
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=4))
    gt = render.ground_truth(spec, res)
    top, bottom = halves(res)
    w = 64 / 255
    np.testing.assert_allclose(gt["roughness"][top], (1 - w) * 0.3 + w * 0.6, atol=1e-4)
    np.testing.assert_allclose(gt["metallic"][top], 1 - w, atol=1e-4)
    np.testing.assert_allclose(gt["albedo"][bottom], np.broadcast_to([0.5, 0.1, 0.1], (int(bottom.sum()), 3)),
                               atol=1e-4)  # fmt: skip


def test_wavefront_colour_passes_render_what_the_symbolic_ones_render(mono, uv_slab, tmp_path, monkeypatch):
    """render.WAVEFRONT_TEXTURED changes how Dr.Jit compiles, not what is rendered (the symbolic render)."""
    tex = MaterialTextures(albedo=TextureSpec(checker(tmp_path, "c.png", (200, 40, 40), (30, 30, 200))),
                           normal=TextureSpec(png(tmp_path, "n.png", (160, 128, 240), (128, 150, 240))))  # fmt: skip
    mats = (MaterialSpec("t", "pplastic", (0.5,) * 3, 0.3, 0.0, ior=1.5, textures=tex),
            MaterialSpec("m", "pplastic", (0.9, 0.6, 0.3), 0.25, 0.0, ior=1.5))  # fmt: skip
    objs = (ObjectSpec("a", uv_slab, pose(25, "x"), "t"), ObjectSpec("b", uv_slab, pose(-35, "y"), "m"))
    spec = SceneSpec(rig=Rig(), objects=objs, materials=mats)
    settings = render.RenderSettings(resolution=32, spp=4)
    runs = {}
    for on in (False, True):
        monkeypatch.setattr(render, "WAVEFRONT_TEXTURED", on)
        runs[on] = render.render_stokes(spec, settings)
    ref, wave = runs[False], runs[True]
    assert "aovs" in wave.seconds and "aovs" not in ref.seconds  # the AOV-only pass ran
    assert ref.mask.any() and np.abs(ref.normal[ref.mask][:, 0]).max() > 0.2  # tilted: normals have an x part
    np.testing.assert_array_equal(wave.object_index, ref.object_index)
    np.testing.assert_allclose(wave.coverage, ref.coverage, atol=1e-6)
    np.testing.assert_allclose(wave.normal, ref.normal, atol=1e-5)
    np.testing.assert_allclose(wave.depth, ref.depth, atol=1e-6)
    scale = np.abs(ref.stokes[..., 0]).max()
    np.testing.assert_allclose(wave.stokes, ref.stokes, atol=1e-3 * scale)


def test_the_truth_pass_variant_switch_stays_quiet_in_a_long_render(mono, uv_slab, monkeypatch, recwarn):
    """Every switch re-applies @drjit.syntax to Mitsuba's integrators; a long render must not warn of it."""
    import warnings

    import drjit.ast

    monkeypatch.setattr(drjit.ast, "_syntax_counter", 5000)  # as after ~300 textured scenes in one process
    monkeypatch.setattr(render, "needs_truth_pass", lambda spec: True)
    mat = MaterialSpec.plastic("p", (0.3, 0.4, 0.5), 0.6)
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("o", uv_slab, pose(), "p"),), materials=(mat,))
    warnings.simplefilter("always")
    res = render.render_stokes(spec, render.RenderSettings(resolution=16, spp=1))
    assert res.truth is not None
    assert drjit.ast._syntax_counter > 5000  # the switch did re-decorate: the case is exercised
    assert not [w for w in recwarn if "AST-transforming" in str(w.message)]
