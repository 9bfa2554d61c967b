"""table_bsdf: the one-wavelength table BSDF evaluates, samples and switches channels like ``measured_polarized``."""

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")

from blender_addon.core import mitsuba_scene as ms  # noqa: E402
from blender_addon.core import passes, table_bsdf  # noqa: E402
from blender_addon.core.spec import MaterialSpec  # noqa: E402
from pbrdf.brdf import seeds, table  # noqa: E402


@pytest.fixture(scope="module")
def gold_table(tmp_path_factory):
    """A small conductor table (strong linear and circular terms) on uniform axes."""
    gold = next(m for m in seeds.SEED_MATERIALS if m.name == "gold")
    path = tmp_path_factory.mktemp("tables") / "gold.pbsdf"
    table.save_table(path, seeds.seed_table(gold, (9, 7, 16)), for_mitsuba=True)
    return path


@pytest.fixture(scope="module")
def mono():
    passes.set_variant(passes.choose_variant())
    if not mi.variant().endswith("_mono_polarized") or mi.variant().startswith("scalar"):
        pytest.skip("needs a *_mono_polarized JIT variant (Dr.Jit's LLVM backend)")
    table_bsdf.register()
    return mi


def _directions(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _eval_pdf(bsdf, wi, wo, mode):
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(wi.T.astype(np.float32))
    ctx = mi.BSDFContext(mode)
    w = mi.Vector3f(wo.T.astype(np.float32))
    return np.array(bsdf.eval(ctx, si, w))[:, :, 0], np.array(bsdf.pdf(ctx, si, w))


@pytest.mark.parametrize("wavelength", ms.CHANNEL_WAVELENGTHS_NM)
def test_eval_and_pdf_equal_the_plugin(mono, gold_table, wavelength):
    props = {"filename": str(gold_table), "wavelength": wavelength, "alpha_sample": 0.2}
    ours = mi.load_dict({"type": table_bsdf.PLUGIN, **props})
    plugin = mi.load_dict({"type": "measured_polarized", **props})
    wi, wo = _directions(4000, 1), _directions(4000, 2)
    for mode in (mi.TransportMode.Radiance, mi.TransportMode.Importance):
        a, pa = _eval_pdf(ours, wi, wo, mode)
        b, pb = _eval_pdf(plugin, wi, wo, mode)
        # float32 round-off (measured: 2e-4 of m00 at most, 1e-5 at the 99.9th percentile)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-3 * np.abs(b[0, 0]).max())
        assert np.abs(a - b).max(axis=(0, 1)).mean() < 1e-5 * np.abs(b[0, 0]).max()
        np.testing.assert_allclose(pa, pb, rtol=1e-4, atol=1e-6)
    assert np.abs(b[1:, 1:]).max() > 0.1 * np.abs(b[0, 0]).max()  # a polarizing table


def test_sample_matches_eval_over_pdf(mono, gold_table):
    bsdf = mi.load_dict({"type": table_bsdf.PLUGIN, "filename": str(gold_table), "wavelength": 532.0,
                         "alpha_sample": 0.1})  # fmt: skip
    n = 2000
    wi = _directions(n, 3)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(wi.T.astype(np.float32))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(4)
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random((2, n))))
    value, pdf = _eval_pdf(bsdf, wi, np.array(bs.wo).T, mi.TransportMode.Radiance)
    ok = np.array(bs.pdf) > 0
    assert ok.mean() > 0.8
    np.testing.assert_allclose(np.array(bs.pdf)[ok], pdf[ok], rtol=1e-4)
    np.testing.assert_allclose(np.array(weight)[:, :, 0][:, :, ok], value[:, :, ok] / pdf[ok], rtol=1e-3, atol=1e-5)


def test_channel_switch_by_parameters_equals_a_new_bsdf(mono, gold_table):
    """``channel_updates`` replaces the data: the result equals a BSDF built at that wavelength."""
    mat = MaterialSpec.measured("gold", str(gold_table), (0.9, 0.6, 0.3), roughness=0.3, metallic=1.0)
    bsdf = mi.load_dict(ms.bsdf_dict(mat, 0))
    assert ms.bsdf_dict(mat, 0)["type"] == table_bsdf.PLUGIN
    params = mi.traverse(bsdf)
    params.update({k.removeprefix("obj.bsdf."): v for k, v in ms.channel_updates("obj", mat, 2).items()})
    fresh = mi.load_dict(ms.bsdf_dict(mat, 2))
    wi, wo = _directions(500, 5), _directions(500, 6)
    a, _ = _eval_pdf(bsdf, wi, wo, mi.TransportMode.Radiance)
    b, _ = _eval_pdf(fresh, wi, wo, mi.TransportMode.Radiance)
    np.testing.assert_array_equal(a, b)
    c, _ = _eval_pdf(mi.load_dict(ms.bsdf_dict(mat, 0)), wi, wo, mi.TransportMode.Radiance)
    assert np.abs(c - b).max() > 0.01 * np.abs(b).max()  # the channels differ (gold is coloured)


def test_non_uniform_axes_fall_back_to_the_plugin(mono, gold_table, tmp_path):
    t = table.load_table(gold_table, mmap=False)
    theta_h = t.theta_h.copy()
    theta_h[1:-1] = np.sqrt(theta_h[1:-1] / theta_h[-1]) * theta_h[-1]  # denser near 0, as in MERL-style grids
    path = tmp_path / "uneven.pbsdf"
    table.save_table(path, table.PBRDFTable(t.phi_d, t.theta_d, theta_h, t.wavelengths, t.M), for_mitsuba=True)
    assert table_bsdf.uniform_axes(gold_table) and not table_bsdf.uniform_axes(path)
    mat = MaterialSpec.measured("uneven", str(path), (0.5, 0.5, 0.5), roughness=0.5, metallic=1.0)
    d = ms.bsdf_dict(mat, 1)
    assert d["type"] == "measured_polarized" and d["alpha_sample"] in ms.ALPHA_SAMPLE_LEVELS
    assert ms.channel_updates("obj", mat, 1) is None  # the renderer reloads the scene per channel


def test_channel_matrices_interpolate_between_bands(gold_table):
    t = table.load_table(gold_table, mmap=False)
    m, axes = table_bsdf.channel_matrices(gold_table, 630.0)
    w = (630.0 - 600.0) / 50.0
    expected = (1 - w) * t.M[..., 3, :, :] + w * t.M[..., 4, :, :]
    np.testing.assert_allclose(m.reshape(expected.shape), expected, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(table_bsdf.channel_matrices(gold_table, 400.0)[0].reshape(expected.shape),
                               t.M[..., 0, :, :], rtol=1e-6)  # fmt: skip
    assert [len(a) for a in axes] == [9, 7, 16]
