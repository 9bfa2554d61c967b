"""The built-in seed set: seed tables equal to the analytic model, physical, with sensible Disney fits."""

import numpy as np

from pbrdf.brdf import microfacet, seeds, table
from pbrdf.expansion import expand

GRID = (8, 6, 16)


def test_seed_table_matches_analytic_model():
    """Tabulating inverts the table evaluation: a rough material on a fine grid comes back."""
    mat = seeds.SeedMaterial("rough_gold", "metal", "conductor", 0.8, n=(1.46,) * 5, k=(1.95,) * 5)
    t = seeds.seed_table(mat, grid=(49, 31, 61))
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, 300, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.2
    wi, wo = v / np.linalg.norm(v, axis=-1, keepdims=True)
    a = table.evaluate(t, wi, wo, 550.0)
    b = microfacet.conductor_pbrdf(wi, wo, eta=complex(1.46, -1.95), alpha=0.64)
    # Linear interpolation on the grid: a few percent of the peak (measured 4 % at 73x46x91).
    assert np.abs(a - b).max() < 0.08 * np.abs(b).max()
    # The polarization terms, frames included, not only the intensity.
    assert np.abs(a[:, 1:, 0] - b[:, 1:, 0]).max() < 0.1 * np.abs(b[:, 1:, 0]).max()


def test_seed_set_is_physical_and_fits_are_sensible():
    tabs = seeds.seed_tables(grid=GRID)
    assert len(tabs) == len(seeds.SEED_MATERIALS) >= 15
    m = np.stack([np.asarray(t.M, dtype=np.float64).reshape(-1, 5, 4, 4) for t in tabs])
    _, verdicts = expand.filter_tables(m)
    assert all(v.accepted for v in verdicts)
    gold = next(t for t in tabs if t.name == "gold")
    fit = expand.fit_table_disney(gold, n=400)
    assert fit.metallic > 0.8 and fit.albedo[0] > fit.albedo[2]  # gold: metallic, reddish-yellow
