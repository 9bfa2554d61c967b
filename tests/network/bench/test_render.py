"""network.bench.render: rendered-map error against time, default vs naive configuration."""

import statistics

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from network.bench import render  # noqa: E402

pytestmark = pytest.mark.mitsuba


def test_bench_render_default_beats_naive():
    from blender_addon.core import render as renderer
    from blender_addon.core.scenegen import benchmark_scene

    result = render.run(renderer, benchmark_scene(), resolution=32, ref_spp=128, spp=(4, 16))
    default = next(v for k, v in result.items() if k.startswith("default"))
    naive = next(v for k, v in result.items() if k.startswith("naive"))
    # Error falls with samples, and the default configuration is far more accurate per spp
    # (next-event estimation through the polarizer sheet, stratified samples).
    assert default["points"][1]["rel_rmse_unpol_lp"] < default["points"][0]["rel_rmse_unpol_lp"]
    for d, n in zip(default["points"], naive["points"], strict=True):
        assert d["rel_rmse_unpol_lp"] < 0.5 * n["rel_rmse_unpol_lp"]
    assert result["speedup_default_over_naive_at_2pct"] > 5
    # The one timing rule: one warm-up render per point (the first compiles), one timed render.
    for entry in (default, naive):
        assert entry["first_call_seconds_incl_jit"] == entry["points"][0]["warmup_seconds"][0]
        for p in entry["points"]:
            assert p["warmup_runs"] == 1 and p["repeats"] == 1 and len(p["seconds_all"]) == 1
            assert p["seconds"] == p["seconds_median"] == statistics.median(p["seconds_all"])
            assert f"{p['spp']} spp" in p["what"]
        # The time to 2 % error follows from the listed points (err ~ a / sqrt(spp), seconds ~ b * spp).
        a = np.median([p["rel_rmse_unpol_lp"] * np.sqrt(p["spp"]) for p in entry["points"]])
        b = np.median([p["seconds"] / p["spp"] for p in entry["points"]])
        assert entry["seconds_for_2pct"] == pytest.approx(b * (a / render.TARGET_ERROR) ** 2, rel=1e-9)
    assert result["speedup_default_over_naive_at_2pct"] == pytest.approx(
        naive["seconds_for_2pct"] / default["seconds_for_2pct"], rel=1e-9
    )
    assert result["reference"]["warmup_runs"] == 0 and "reference" in result["reference"]["what"]
