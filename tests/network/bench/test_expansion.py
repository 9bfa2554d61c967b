"""network.bench.expansion: PCA error falls with components; validity filter and expansion are timed."""

import statistics

import pytest

from network.bench import expansion


@pytest.mark.slow
def test_small_run():
    result = expansion.run(count=2, repeat=2, warmup=0)
    errors = [r["rel_rmse_held_in"] for r in result["reconstruction"]]
    assert errors == sorted(errors, reverse=True) and errors[-1] < errors[0]
    for r in result["reconstruction"]:
        assert r["repeats"] == 2 and r["warmup_runs"] == 0 and len(r["seconds_all"]) == 2
        assert r["seconds"] == r["seconds_median"] == statistics.median(r["seconds_all"])
        assert f"({r['components'].split('+')[0]}+" in r["what"]
    vf = result["validity_filter"]
    assert 0 < vf["valid_fraction"] <= 1 and vf["speedup"] > 1
    assert vf["vectorised"]["what"] and vf["per_matrix_loop"]["what"]
    exp = result["expansion"]
    assert exp["written"] == 2 and 0 < exp["acceptance_rate"] <= 1 and exp["repeats"] == 1
