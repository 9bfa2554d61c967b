"""network.bench.render: time per sample to 2 % map error, default vs naive configurations, JIT apart."""

import statistics

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from network.bench import render  # noqa: E402

pytestmark = pytest.mark.mitsuba


def test_fit_to_target_subtracts_the_reference_noise():
    # err^2 = a^2 / spp + e_ref^2 with a = 0.4, e_ref = 0.01: the fit recovers spp^-1/2 and a.
    pts = [{"spp": s, "seconds": 0.2 + 0.05 * s, "rel_rmse_unpol_lp": (0.16 / s + 1e-4) ** 0.5} for s in (4, 8, 32)]
    fit = render.fit_to_target(pts, ref_var=1e-4)
    assert fit["error_exponent"] == pytest.approx(-0.5, abs=1e-9)
    assert fit["spp_for_2pct"] == pytest.approx(400.0, rel=1e-9)
    assert fit["seconds_per_sample_at_2pct"] == pytest.approx(0.2 + 0.05 * 400, rel=1e-9)
    assert fit["rel_rmse_corrected"] == pytest.approx([0.4 / np.sqrt(s) for s in (4, 8, 32)], rel=1e-9)
    # Noisy timings with a falling slope still give a positive time per sample.
    noisy = [{**p, "seconds": 1.0 - 0.01 * p["spp"]} for p in pts]
    assert render.fit_to_target(noisy, ref_var=1e-4)["seconds_per_sample_at_2pct"] > 0
    # Without the correction the reference's noise looks like slower convergence (more spp).
    assert render.fit_to_target(pts, ref_var=0.0)["spp_for_2pct"] > 1.02 * fit["spp_for_2pct"]
    # A point below the reference's noise has no corrected error; the others still give the fit.
    low = [*pts, {"spp": 64, "seconds": 3.4, "rel_rmse_unpol_lp": 0.005}]
    assert render.fit_to_target(low, ref_var=1e-4)["rel_rmse_corrected"][-1] is None


def test_bench_render_default_beats_naive_and_reports_jit_apart(tmp_path):
    from blender_addon.core import render as renderer
    from headless.bench import render_scenes

    scenes = render_scenes(["analytic", "table"], None, tmp_path)
    result = render.run(renderer, scenes, resolution=32, ref_spp=64, spp=(4, 16), naive=["analytic"])
    analytic, table = result["scenes"]["analytic"], result["scenes"]["table"]
    assert set(analytic["configs"]) == set(render.CONFIGS) and set(table["configs"]) == {"default", "sheet"}
    default, sheet, naive_path, naive_volpath = (analytic["configs"][k] for k in render.CONFIGS)
    # The polarized emitter and the sheet are two models of the same light: the same error per spp
    # (within the noise of one 32 px render), at no more time per call.
    for scene in (analytic, table):
        for d, s in zip(scene["configs"]["default"]["points"], scene["configs"]["sheet"]["points"], strict=True):
            assert 0.7 < d["rel_rmse_unpol_lp"] / s["rel_rmse_unpol_lp"] < 1.4
    assert default["max_depth"] == sheet["max_depth"]
    # Error falls with samples, and the default configuration is more accurate per spp: next-event
    # estimation through the polarizer sheet (path has none), stratified samples (naive volpath has none).
    for entry in (default, table["configs"]["default"]):
        assert entry["points"][1]["rel_rmse_unpol_lp"] < entry["points"][0]["rel_rmse_unpol_lp"]
        assert 0 < entry["spp_for_2pct"] < 200 and entry["seconds_per_sample_at_2pct"] > 0
    for d, p, v in zip(default["points"], naive_path["points"], naive_volpath["points"], strict=True):
        assert d["rel_rmse_unpol_lp"] < 0.5 * p["rel_rmse_unpol_lp"]
        assert d["rel_rmse_unpol_lp"] < v["rel_rmse_unpol_lp"] < p["rel_rmse_unpol_lp"]
    # Accuracy per sample decides (timings on a shared machine do not belong in a test): the
    # default needs fewer spp for 2 %, and every reported time and speed-up is positive.
    assert default["spp_for_2pct"] < naive_volpath["spp_for_2pct"] < naive_path["spp_for_2pct"]
    for cfg in ("sheet", "naive_path", "naive_volpath"):
        assert analytic[f"speedup_default_over_{cfg}_at_2pct"] > 0
    # The convex blob is rendered with direct light only: path needs one bounce more for the sheet.
    assert default["max_depth"] == 2 and naive_path["max_depth"] == 3 and naive_volpath["max_depth"] == 2
    for scene in (analytic, table):
        ref_err = scene["reference_rel_rmse_estimate"]
        assert 0 < ref_err < scene["configs"]["default"]["points"][-1]["rel_rmse_unpol_lp"]
        assert scene["reference"]["warmup_runs"] == 0 and "reference" in scene["reference"]["what"]
        for entry in scene["configs"].values():
            # The one timing rule: one warm-up render per point (the first call compiles), one timed render.
            assert entry["first_call_seconds_incl_jit"] == entry["points"][0]["warmup_seconds"][0]
            assert entry["jit_compile_seconds_later_calls_max"] == 0.0  # the timed calls reuse the kernels
            assert len(entry["jit_compile_seconds_first_call"]) == len(entry["points"])
            for p in entry["points"]:
                assert p["warmup_runs"] == 1 and p["repeats"] == 1 and len(p["seconds_all"]) == 1
                assert p["seconds"] == p["seconds_median"] == statistics.median(p["seconds_all"])
                assert f"{p['spp']} spp" in p["what"] and entry["what"] in p["what"]
            # The time to 2 % follows from the listed points and the reference's noise.
            fit = render.fit_to_target(entry["points"], ref_err**2)
            assert entry["seconds_per_sample_at_2pct"] == pytest.approx(fit["seconds_per_sample_at_2pct"], rel=1e-9)
            corrected = [c for c in entry["rel_rmse_corrected"] if c is not None]
            assert all(c < p["rel_rmse_unpol_lp"] for c, p in zip(corrected, entry["points"], strict=False))
    assert analytic["speedup_default_over_naive_path_at_2pct"] == pytest.approx(
        naive_path["seconds_per_sample_at_2pct"] / default["seconds_per_sample_at_2pct"], rel=1e-9
    )
