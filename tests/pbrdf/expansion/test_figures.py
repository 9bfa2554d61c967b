"""pbrdf.expansion.figures: sphere panels whose colour scales fit the data, labels, captions."""

import dataclasses

import numpy as np
import pytest
from PIL import Image

from pbrdf.brdf import seeds
from pbrdf.brdf.table import PBRDFTable
from pbrdf.expansion import figures

GRID = (8, 6, 16)
GOLD = next(m for m in seeds.SEED_MATERIALS if m.name == "gold")


def _faint_cp_table() -> PBRDFTable:
    """A white-billiard table given a small linear-to-circular term: CP/S0 of about 1e-3 under 45-degree light."""
    t = seeds.seed_table(seeds.SEED_MATERIALS[1], GRID)
    m = np.array(t.M, dtype=np.float64)
    ramp = 0.5 + np.sin(np.asarray(t.theta_h))[None, None, :, None]  # varies over the sphere
    m[..., 3, 2] = 2e-3 * m[..., 0, 0] * ramp
    return dataclasses.replace(t, M=m.astype(np.float32), name="faint")


def test_sphere_polarimetry_cp45_is_zero_for_dielectrics_and_not_for_metals():
    # Unpolarized light: no circular part for any seed (one reflection); 45-degree linear light: a metal's
    # retardance makes it partly circular, a dielectric's does not.
    di = figures.sphere_polarimetry(seeds.seed_table(seeds.SEED_MATERIALS[1], GRID), 32)
    gold = figures.sphere_polarimetry(seeds.seed_table(GOLD, GRID), 32)
    for p in (di, gold):
        assert np.abs(p["docp"]).max() < 1e-9 and p["inside"].sum() > 0.7 * 32 * 32
    assert np.abs(di["cp45"]).max() < 1e-9
    assert np.abs(gold["cp45"][gold["inside"]]).mean() > 1e-2


def test_a_faint_cp_panel_is_not_flat_in_the_png(tmp_path):
    table = _faint_cp_table()
    cp = figures.sphere_polarimetry(table, 64)
    inside = cp["inside"]
    assert 3e-4 < np.abs(cp["cp45"][inside]).max() < 1e-2  # the regime a fixed 0..1 scale draws as one colour
    boxes = figures.material_figure(tmp_path / "f.png", [table], ["faint: a test table"], "test")
    img = np.asarray(Image.open(tmp_path / "f.png").convert("RGB"), dtype=np.float64)
    left, top, right, bottom = boxes[0, "cp45"]
    cx, cy, half = (left + right) // 2, (top + bottom) // 2, (right - left) // 4  # well inside the sphere
    panel = img[cy - half : cy + half, cx - half : cx + half]
    assert panel.std(axis=(0, 1)).max() > 5.0, "the CP/S0 panel of a faint material is flat"
    # Never an all-black panel: the colour panel and the DoLP panel show the sphere too.
    for key in ("colour", "dolp"):
        left, top, right, bottom = boxes[0, key]
        assert img[top:bottom, left:right].mean() > 40, key


def test_seed_labels_name_each_seed_and_spectralon_is_lambertian():
    spectralon = seeds.seed_table(seeds.SEED_MATERIALS[0], (4, 3, 4))
    # A Disney roughness fitted to a lobe-less material ends at a bound (0 or 1): it is not shown.
    label = figures.seed_label(spectralon, [0.88] * 3, 0.0, 0.0)
    assert label.startswith("spectralon") and "Lambertian" in label
    assert "roughness 0.00" not in label and "r 0.00" not in label
    gold = seeds.seed_table(GOLD, (4, 3, 4))
    label = figures.seed_label(gold, [1.0, 0.76, 0.49], 0.29, 1.0)
    assert "gold" in label and "conductor" in label and "k 2.46" in label and "metallic 1.00" in label


def test_captions_explain_the_panels():
    for name in ("figure_seeds.png", "figure_generated.png"):
        text = figures.caption(name, 19)
        for words in ("gamma 2.2", "99th percentile", "45°", "exactly 0", "red positive"):
            assert words in text, (name, words)
    assert figures.caption("figure_seeds.png", 19).startswith("All 19 seed materials")
    with pytest.raises(KeyError):
        figures.caption("other.png", 1)
