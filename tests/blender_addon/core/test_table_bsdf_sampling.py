"""table_bsdf: ``sample`` draws directions with the density its own ``pdf`` reports (chi-square), and its
weight is ``eval / pdf`` with ``eval`` carrying the cosine.

The chi-square test follows Mitsuba's own BSDF tests (``mitsuba.chi2``): histogram sampled directions on a
(cos theta, phi) grid, integrate the pdf over each cell numerically, pool the cells with small expected
counts, and reject at a low significance.
"""

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")
stats = pytest.importorskip("scipy.stats")

from blender_addon.core import table_bsdf  # noqa: E402
from pbrdf.brdf import table  # noqa: E402

#: Samples per histogram: a cell holding 1e5 of them resolves the pdf's integral to 0.3 %.
N_SAMPLES = 1_000_000
#: Histogram cells in cos(theta_o) and phi_o; odd, so that no cell edge falls on the plane of incidence.
RES_COS, RES_PHI = 41, 81
#: Gauss-Legendre nodes per cell and axis: the GGX lobe of alpha 0.1 spans about one cell in cos(theta_o).
NODES = 12
#: Overall significance of the chi-square tests below (Sidak-corrected per test).
SIGNIFICANCE = 0.01
#: Pooled cells of fewer expected samples than this (the usual validity rule for chi-square).
MIN_EXPECTED = 5.0
CASES = [(alpha, theta_i) for alpha in (0.1, 0.5) for theta_i in (5.0, 40.0, 75.0)]


def _context(wi):
    """A BSDF context and an interaction with incident direction(s) ``wi`` (n, 3) in the local frame."""
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(np.asarray(wi, dtype=np.float32).T)
    return mi.BSDFContext(), si


def _incident(theta_deg, n):
    t = np.radians(theta_deg)
    return np.tile([np.sin(t), 0.0, np.cos(t)], (n, 1))


def _histogram(bsdf, theta_i, rng):
    """Counts of sampled directions per (cos theta_o, phi_o) cell, and the number with no direction (pdf 0)."""
    ctx, si = _context(_incident(theta_i, N_SAMPLES))
    bs, _ = bsdf.sample(ctx, si, mi.Float(rng.random(N_SAMPLES)), mi.Point2f(rng.random((2, N_SAMPLES))))
    wo = np.array(bs.wo).T
    valid = np.array(bs.pdf) > 0
    cos_t = wo[valid, 2]
    phi = np.mod(np.arctan2(wo[valid, 1], wo[valid, 0]), 2 * np.pi)
    counts, _, _ = np.histogram2d(cos_t, phi, bins=(RES_COS, RES_PHI), range=((0, 1), (0, 2 * np.pi)))
    return counts, int((~valid).sum())


def _expected(bsdf, theta_i):
    """Integral of the reported pdf over each cell (Gauss-Legendre in cos theta_o and phi_o), times N."""
    x, w = np.polynomial.legendre.leggauss(NODES)
    # nodes of every cell: cos theta in [i, i+1] / RES_COS, phi in [j, j+1] * 2 pi / RES_PHI
    c = (np.arange(RES_COS)[:, None] + (x[None, :] + 1) / 2) / RES_COS  # (RES_COS, NODES)
    p = (np.arange(RES_PHI)[:, None] + (x[None, :] + 1) / 2) * 2 * np.pi / RES_PHI
    cc, pp = np.meshgrid(c.ravel(), p.ravel(), indexing="ij")
    s = np.sqrt(np.clip(1 - cc**2, 0, None))
    wo = np.stack([s * np.cos(pp), s * np.sin(pp), cc], axis=-1).reshape(-1, 3)
    ctx, si = _context(_incident(theta_i, len(wo)))
    pdf = np.array(bsdf.pdf(ctx, si, mi.Vector3f(wo.T.astype(np.float32)))).astype(np.float64)
    pdf = pdf.reshape(RES_COS, NODES, RES_PHI, NODES)
    cell = (1 / RES_COS) * (2 * np.pi / RES_PHI) / 4  # the Jacobian of [-1, 1]^2 onto a cell (d cos d phi)
    return N_SAMPLES * cell * np.einsum("injm,n,m->ij", pdf, w, w)


def _chi_square_p(observed, expected):
    """p-value of Pearson's chi-square after pooling cells expected below :data:`MIN_EXPECTED` into one."""
    observed, expected = np.ravel(observed), np.ravel(expected)
    small = expected < MIN_EXPECTED
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    if exp[-1] < MIN_EXPECTED:  # the pool is still too small: fold it into the smallest cell
        k = np.argmin(exp[:-1])
        obs[k] += obs[-1]
        exp[k] += exp[-1]
        obs, exp = obs[:-1], exp[:-1]
    chi2 = np.sum((obs - exp) ** 2 / exp)
    return stats.chi2.sf(chi2, len(obs) - 1), len(obs)


@pytest.mark.parametrize(("alpha", "theta_i"), CASES)
def test_sampled_directions_follow_the_reported_pdf(mono, gold_table, alpha, theta_i):
    bsdf = mi.load_dict({"type": table_bsdf.PLUGIN, "filename": str(gold_table), "wavelength": 532.0,
                         "alpha_sample": alpha})  # fmt: skip
    counts, invalid = _histogram(bsdf, theta_i, np.random.default_rng(int(100 * alpha + theta_i)))
    expected = _expected(bsdf, theta_i)
    # the mass below the horizon (GGX reflections that leave the surface) is a cell too: normalisation is tested
    observed = np.append(counts.ravel(), invalid)
    expected = np.append(expected.ravel(), max(N_SAMPLES - expected.sum(), 0.0))
    p, cells = _chi_square_p(observed, expected)
    assert cells > 100  # enough resolution to see a wrong lobe
    assert p > 1 - (1 - SIGNIFICANCE) ** (1 / len(CASES)), (p, cells)


def test_weight_is_eval_over_pdf_with_the_cosine_in_eval(mono, gold_table, tmp_path):
    """A table of constant ``m00 = rho / pi`` (others 0) is a Lambertian reflector: ``eval`` is
    ``rho / pi * cos theta_o`` and the sample weight is that over the pdf."""
    t = table.load_table(gold_table, mmap=False)
    rho = 0.7
    m = np.zeros_like(t.M)
    m[..., 0, 0] = rho / np.pi
    path = tmp_path / "lambert.pbsdf"
    table.save_table(path, table.PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, m), for_mitsuba=True)
    bsdf = mi.load_dict({"type": table_bsdf.PLUGIN, "filename": str(path), "wavelength": 532.0})
    n = 20_000
    rng = np.random.default_rng(11)
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    ctx, si = _context(wi)
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random((2, n))))
    wo = np.array(bs.wo).T
    pdf = np.array(bs.pdf)
    weight = np.array(weight)[:, :, 0]
    value = np.array(bsdf.eval(ctx, si, bs.wo))[:, :, 0]
    ok = pdf > 0
    assert ok.mean() > 0.8
    np.testing.assert_allclose(value[0, 0, ok], rho / np.pi * wo[ok, 2], rtol=1e-5)  # the cosine is in eval
    np.testing.assert_allclose(weight[0, 0, ok] * pdf[ok], rho / np.pi * wo[ok, 2], rtol=1e-4)
    np.testing.assert_allclose(weight[..., ok], value[..., ok] / pdf[ok], rtol=1e-5, atol=1e-7)
    assert np.all(weight[..., ~ok] == 0)  # no direction, no weight
    np.testing.assert_allclose(np.delete(weight.reshape(16, n), 0, axis=0), 0.0, atol=1e-7)  # unpolarizing
