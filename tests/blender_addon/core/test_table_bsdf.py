"""table_bsdf: the one-wavelength table BSDF evaluates, samples and switches channels like ``measured_polarized``."""

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")

from blender_addon.core import mitsuba_scene as ms  # noqa: E402
from blender_addon.core import table_bsdf  # noqa: E402
from blender_addon.core.spec import MaterialSpec  # noqa: E402
from pbrdf.brdf import table  # noqa: E402


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


@pytest.fixture(scope="module")
def tiny_coupling_table(gold_table, tmp_path_factory):
    """The gold table with a negligible m30 (up to 5e-4 of m00 in each cell, as in the generated
    tables) and a small but real m02 (up to 1 %)."""
    t = table.load_table(gold_table, mmap=False)
    m = t.M.copy()
    peak = np.abs(m[..., 0, 0]).max()
    assert np.abs(m[..., [0, 0, 1, 2, 3, 3], [2, 3, 2, 1, 0, 1]]).max() < 1e-12 * peak  # the seed's zeros
    rng = np.random.default_rng(7)
    m[..., 3, 0] = 5e-4 * m[..., 0, 0] * rng.uniform(-1, 1, m.shape[:-2])
    m[..., 0, 2] = 1e-2 * m[..., 0, 0] * rng.uniform(-1, 1, m.shape[:-2])
    path = tmp_path_factory.mktemp("tables") / "tiny.pbsdf"
    table.save_table(path, table.PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, m), for_mitsuba=True)
    return path


def test_needed_entries_leave_out_only_what_cannot_matter(gold_table, tiny_coupling_table, tmp_path):
    # gold: every entry but the structural zeros m02 m03 m12 m13 m20 m21 m30 m31
    gold = (0, 1, 4, 5, 10, 11, 14, 15)
    assert table_bsdf.needed_entries(gold_table) == gold
    assert table_bsdf.needed_entries(gold_table, linear_light=True) == (0, 1, 4, 5, 10, 14)
    # m02 at 1 % is needed, m30 at 5e-4 is not
    assert table_bsdf.needed_entries(tiny_coupling_table) == (0, 1, 2, 4, 5, 10, 11, 14, 15)
    t = table.load_table(tiny_coupling_table, mmap=False)
    m = t.M.copy()
    m[0, 0, 0, 0, 2, 1] = np.nan  # a NaN bin kept (not written for Mitsuba): m21 counts as needed
    nan_path = tmp_path / "nan.pbsdf"
    table.save_table(nan_path, table.PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, m))
    assert table_bsdf.needed_entries(nan_path) == (0, 1, 2, 4, 5, 9, 10, 11, 14, 15)


def test_linear_light_leaves_the_response_to_linear_light_unchanged(mono, tiny_coupling_table):
    """With ``linear_light`` the BSDF maps unpolarized and linearly polarized light as the plugin
    does (to the negligible m30, 5e-4 of S0), while circularly polarized light is no longer reflected right:
    the skipped column only ever multiplies S3."""
    props = {"filename": str(tiny_coupling_table), "wavelength": 532.0, "alpha_sample": 0.2}
    ours = mi.load_dict({"type": table_bsdf.PLUGIN, **props, "linear_light": True})
    plugin = mi.load_dict({"type": "measured_polarized", **props})
    wi, wo = _directions(4000, 8), _directions(4000, 9)
    a, _ = _eval_pdf(ours, wi, wo, mi.TransportMode.Radiance)
    b, _ = _eval_pdf(plugin, wi, wo, mi.TransportMode.Radiance)
    ok = np.isfinite(b).all(axis=(0, 1))
    a, b = a[..., ok], b[..., ok]
    scale = np.abs(b[0, 0]).max()
    rng = np.random.default_rng(10)
    psi = rng.uniform(0, np.pi, a.shape[-1])
    linear = np.stack([np.ones_like(psi), np.cos(2 * psi), np.sin(2 * psi), np.zeros_like(psi)])
    out_a, out_b = np.einsum("ijn,jn->in", a, linear), np.einsum("ijn,jn->in", b, linear)
    # float32 round-off (2e-4 of the largest m00, test above) and the skipped m30
    assert np.all(np.abs(out_a - out_b) < 5e-4 * np.abs(out_b[0]) + 2e-4 * scale)
    assert np.abs(out_a - out_b)[3].max() > 1e-6 * scale  # m30 was indeed skipped
    circular = np.array([1.0, 0.0, 0.0, 1.0])
    assert np.abs(np.einsum("ijn,j->in", a - b, circular)).max() > 0.05 * scale
