"""network.bench.decode: our decoder against the exact Stokes images (and polanalyser when installed)."""

import statistics

import numpy as np
import pytest

from network.bench import decode
from pbrdf.sensor import camera


def test_small_run_is_exact_and_timed():
    result = decode.run(height=64, width=96, repeat=3, warmup=1)
    for grid, shape in (("half", [32, 48, 9]), ("full", [64, 96, 9])):
        entry = result[f"ours_{grid}"]
        assert entry["output_shape"] == shape
        assert entry["repeats"] == 3 and entry["warmup_runs"] == 1 and len(entry["seconds_all"]) == 3
        assert entry["seconds_median"] == statistics.median(entry["seconds_all"])
        assert f"grid={grid!r}" in entry["what"] and "64x96" in entry["what"]
        assert entry["stokes_max_abs_error_noise_free"] < 2e-3
        # The call allocates at least its float32 nine maps; tracemalloc sees numpy's buffers.
        assert entry["peak_mib"] >= np.prod(shape) * 4 / 2**20 and entry["peak_memory"].startswith("tracemalloc")
    # The full grid has 4 x the output pixels of the half grid: its peak must be well above (measured 2.9 x).
    assert result["ours_full"]["peak_mib"] > 2 * result["ours_half"]["peak_mib"]
    sat = result["ours_full_saturated"]
    assert sat["output_shape"] == [64, 96, 9] and sat["repeats"] == 3 and "saturated" in sat["what"]
    # The longest exposure saturates about 30 % of the blocks (noise moves a few), the highlight every
    # exposure; its blocks, widened by the demosaic's support, are masked.
    fractions = sat["saturated_fraction_per_exposure"]
    assert len(fractions) == 4 and 0.25 < fractions[-1] < 0.4
    assert 0 < fractions[0] <= fractions[-1] and 0 < sat["masked_fraction"] < 0.2
    pa = result["polanalyser"]
    if "skipped" in pa:
        assert result["meets_target"] is None
    else:
        assert pa["repeats"] == 3
        for route in ("half", "full", "full_saturated"):
            ratio = result[f"speed_ratio_polanalyser_1_bracket_over_ours_4_brackets_{route}"]
            assert ratio == pytest.approx(pa["seconds_median"] / result[f"ours_{route}"]["seconds_median"])
        full_ratios = [
            result[f"speed_ratio_polanalyser_1_bracket_over_ours_4_brackets_{r}"] for r in ("full", "full_saturated")
        ]
        assert result["meets_target"] == (min(full_ratios) >= 1.0)


def test_saturated_scene_saturates_the_longest_exposure_only_where_asked():
    model = camera.CameraModel()
    truth = decode.smooth_stokes_scene(64, 80)
    raws = camera.simulate_capture(decode.saturated_scene(truth, model, fraction=0.5), model, noise=False)
    fractions = decode._saturated_fractions(raws, model.sensor)
    disc = fractions[0]  # the highlight saturates every exposure; nothing else saturates the shortest
    assert 0 < disc < 0.05 and all(f >= disc for f in fractions)
    assert fractions[-1] == pytest.approx(0.5, abs=0.03)


def test_scene_is_physical():
    s = decode.smooth_stokes_scene(16, 24)
    assert s.shape == (16, 24, 3, 4)
    assert np.all(s[..., 0] > 0) and np.all(s[..., 0] >= np.linalg.norm(s[..., 1:], axis=-1) - 1e-12)


def test_bad_size():
    with pytest.raises(ValueError, match="multiples of 4"):
        decode.run(height=30, width=32)
