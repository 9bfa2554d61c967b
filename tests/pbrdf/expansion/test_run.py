"""The expansion pipeline end to end on a tiny configuration: valid Mitsuba tables, a material
library the renderer reads, resumable."""

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from pbrdf.brdf import seeds, table  # noqa: E402
from pbrdf.expansion.run import ExpansionConfig, run_expansion  # noqa: E402

GRID = (8, 6, 16)


def test_expansion_run_and_resume(tmp_path):
    cfg = ExpansionConfig(out=tmp_path, count=4, grid=GRID, generator_steps=300, fit_samples=200, figures=2)
    report = run_expansion(cfg, progress=False)
    assert report.written + report.failed == 4 and report.written >= 2
    materials = json.loads((tmp_path / "materials.json").read_text())
    assert len(materials) == report.written
    for m in materials:
        t = table.load_table(tmp_path / m["table"])
        assert t.M.shape == (*GRID, 5, 4, 4) and np.all(np.isfinite(t.M))
        assert 0 <= m["roughness"] <= 1 and 0 <= m["metallic"] <= 1
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["validity"]["mean_cloude_fraction"] >= 0.95
    assert (tmp_path / "figure_generated.png").is_file() and (tmp_path / "figure_seeds.png").is_file()
    # Resume: nothing is regenerated, nothing lost.
    again = run_expansion(cfg, progress=False)
    assert again.written == 0 and again.skipped == report.written
    # The renderer's material library reads it.
    from blender_addon.core import scenegen

    lib = scenegen.load_material_library(tmp_path)
    assert len(lib) == report.written and lib[0].kind == "measured"


def test_measured_folder_is_used_instead_of_the_seed_set(tmp_path):
    """--input (measured tables): real-format tables (here two seed materials written at another grid with 7
    bands, like an hpBRDF subset) are resampled to the working grid and 5 bands."""
    from pbrdf.expansion.run import load_measured

    folder = tmp_path / "measured"
    for mat in seeds.SEED_MATERIALS[:2]:
        t = seeds.seed_table(mat, grid=(10, 8, 12))
        wl = np.arange(410, 700, 40.0)  # 7 whole-nanometre bands
        t7 = table.resample(t, wavelengths=wl)  # clamped outside 450-650: a 7-band file
        table.save_table(folder / f"{mat.name}.hpbrdf", t7)
    tabs = load_measured(folder, GRID)
    assert [t.name for t in tabs] == sorted(m.name for m in seeds.SEED_MATERIALS[:2])
    assert all(t.M.shape == (*GRID, 5, 4, 4) for t in tabs)
    cfg = ExpansionConfig(out=tmp_path / "out", count=2, grid=GRID, measured=folder, generator_steps=100,
                          fit_samples=150, figures=0)  # fmt: skip
    report = run_expansion(cfg, progress=False)
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["seed_source"] == str(folder) and len(manifest["seeds"]) == 2
    assert report.written + report.failed == 2
