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
    # Every written table's Disney label passed the held-out fit check (its ground truth is usable).
    for sidecar in (tmp_path / "tables").glob("gen_*.json"):
        meta = json.loads(sidecar.read_text())
        assert meta["fit_ok"] is True and meta["fit_error"] <= 0.5
    assert all("fit_error" in s for s in manifest["seeds"])
    assert (tmp_path / "figure_generated.png").is_file() and (tmp_path / "figure_seeds.png").is_file()
    # The seed figure shows every seed (not the first `figures` of them), each named; `figures` caps the other one.
    from PIL import Image

    with Image.open(tmp_path / "figure_seeds.png") as img:
        labels = img.text["Description"].split("\n\n")
    assert [label.split(":")[0] for label in labels] == [m.name.replace("_", " ") for m in seeds.SEED_MATERIALS]
    with Image.open(tmp_path / "figure_generated.png") as img:
        assert len(img.text["Description"].split("\n\n")) == min(2, report.written)
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


DEAD = 999_999_999  # above any pid_max: the pid of a killed run that no process can have


def test_components_below_one_are_refused():
    for k_i, k_p in ((0, 0), (0, 3), (3, 0), (-1, 2)):
        with pytest.raises(ValueError, match=rf"^--components must be two integers >= 1 \(K_I K_P\), got {k_i} {k_p}$"):
            ExpansionConfig(out=".", k_intensity=k_i, k_polarization=k_p)
    for kw, flag in (({"count": 0}, "--count"), ({"max_attempts": 0}, "max_attempts"), ({"grid": (8, 1, 4)}, "grid"),
                     ({"min_valid_fraction": 1.5}, "min_valid_fraction"), ({"figures": -1}, "figures")):  # fmt: skip
        with pytest.raises(ValueError, match=f"^{flag} must"):
            ExpansionConfig(out=".", **kw)


def test_a_run_removes_the_temporaries_of_a_killed_one(tmp_path):
    out = tmp_path / "x"
    tmp = f"tmp-{DEAD}-0a1b2c3d"
    leftovers = [f"seeds/.spectralon_8x6x16.pbsdf.{tmp}", f"tables/.gen_00000.pbsdf.{tmp}",
                 f"tables/.gen_00000.json.{tmp}", f"model/.generator.pt.{tmp}", f"model/.pca.npz.{tmp}",
                 f".manifest.json.{tmp}", f".materials.json.{tmp}", f".figure_seeds.png.{tmp}"]  # fmt: skip
    kept = ["notes.txt", f".notes.txt.{tmp}", "tables/readme.txt", f"tables/.gen_00000.pbsdf.old-{DEAD}-0a1b2c3d"]
    for name in leftovers + kept:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(b"half")
    cfg = ExpansionConfig(out=out, count=1, grid=GRID, generator_steps=20, fit_samples=100, figures=1)
    run_expansion(cfg, progress=False)
    assert not [n for n in leftovers if (out / n).exists()]
    assert all((out / n).read_bytes() == b"half" for n in kept)
    # Nothing of the run's own left behind either.
    assert not [p for p in out.rglob("*") if ".tmp" in p.name and p.name not in {n.split("/")[-1] for n in kept}]
