"""Fixtures shared by the Mitsuba tests of blender_addon/core (imports happen when a test asks)."""

import pytest


@pytest.fixture(scope="module")
def mono():
    """Mitsuba in a ``*_mono_polarized`` JIT variant with the table BSDF registered; skip without one."""
    mi = pytest.importorskip("mitsuba")
    from blender_addon.core import passes, table_bsdf

    passes.set_variant(passes.choose_variant())
    if not mi.variant().endswith("_mono_polarized") or mi.variant().startswith("scalar"):
        pytest.skip("needs a *_mono_polarized JIT variant (Dr.Jit's LLVM backend)")
    table_bsdf.register()
    return mi


@pytest.fixture(scope="module")
def gold_table(tmp_path_factory):
    """A small conductor table (strong linear and circular terms) on uniform axes."""
    from pbrdf.brdf import seeds, table

    gold = next(m for m in seeds.SEED_MATERIALS if m.name == "gold")
    path = tmp_path_factory.mktemp("tables") / "gold.pbsdf"
    table.save_table(path, seeds.seed_table(gold, (9, 7, 16)), for_mitsuba=True)
    return path
