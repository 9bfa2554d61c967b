"""network.bench.decode: our decoder against the exact Stokes images (and polanalyser when installed)."""

import statistics

import numpy as np
import pytest

from network.bench import decode


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
    # The full grid has 4 x the output pixels of the half grid: its peak must be well above (measured 3.6 x).
    assert result["ours_full"]["peak_mib"] > 2 * result["ours_half"]["peak_mib"]
    pa = result["polanalyser"]
    assert "skipped" in pa or (pa["repeats"] == 3 and "speed_ratio_polanalyser_1_bracket_over_ours_4_brackets_half"
                               in result)  # fmt: skip


def test_scene_is_physical():
    s = decode.smooth_stokes_scene(16, 24)
    assert s.shape == (16, 24, 3, 4)
    assert np.all(s[..., 0] > 0) and np.all(s[..., 0] >= np.linalg.norm(s[..., 1:], axis=-1) - 1e-12)


def test_bad_size():
    with pytest.raises(ValueError, match="multiples of 4"):
        decode.run(height=30, width=32)
