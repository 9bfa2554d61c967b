"""network.bench.expansion: PCA error falls with components; validity filter and expansion are timed."""

import statistics

import numpy as np
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
    assert 0 < vf["valid_fraction"] <= 1 and vf["target_matrices_per_second"] == expansion.TARGET_MATRICES_PER_SECOND
    for route in ("before", "eigvalsh", "after"):
        r = vf[route]
        assert r["what"] and r["repeats"] == 2 and len(r["cpu_seconds_all"]) == 2
        assert r["matrices_per_second"] == pytest.approx(vf["matrices"] / r["seconds_median"])
        assert r["matrices_per_second_cpu"] == pytest.approx(vf["matrices"] / r["cpu_seconds_median"])
        assert r["meets_target"] == (r["matrices_per_second_cpu"] >= expansion.TARGET_MATRICES_PER_SECOND)
        assert r["meets_target_wall_clock"] == (r["matrices_per_second"] >= expansion.TARGET_MATRICES_PER_SECOND)
    assert vf["disagreements_after_vs_before"] == vf["disagreements_after_vs_eigvalsh"] == 0
    assert vf["per_matrix_loop"]["what"] and vf["matrices_per_second_per_matrix_loop"] > 0
    exp = result["expansion"]
    for run in (exp["before"], exp["after"]):
        assert run["written"] == 2 and 0 < run["acceptance_rate"] <= 1 and run["repeats"] == 1
        assert run["meets_target"] == (run["extrapolated_minutes_for_2000"] < expansion.TARGET_MINUTES_FOR_2000)
        assert len(run["attempt_of_each_table"]) == 2
    assert exp["same_tables"]


def test_before_filter_is_the_old_rule():
    # The reference route: valid where Givens-Kostinski and Cloude both pass. It accepts and
    # rejects as the current filter does on physical, repairable and hopeless tables.
    from pbrdf.expansion import expand
    from pbrdf.polar import mueller

    rng = np.random.default_rng(0)
    good = np.broadcast_to(mueller.depolarizer(0.3), (1, 50, 2, 4, 4)).copy() * rng.uniform(0.1, 1, (1, 50, 2, 1, 1))
    few = good.copy()
    few[0, :2, 0] = np.diag([1.0, 1, 1, -1])  # GK ok, Cloude not: 2 of 100 invalid
    bad = good @ np.diag([1.0, 1, 1, -1])  # depolarizer(0.3) with s3 flipped: still physical
    bad[0, :, :, 0, 1] = 2 * bad[0, :, :, 0, 0]  # over-polarizing everywhere
    tables = np.concatenate([good, few, bad])
    old, v_old = expansion.filter_tables_before(tables)
    new, v_new = expand.filter_tables(tables)
    assert [v.accepted for v in v_old] == [v.accepted for v in v_new] == [True, True, False]
    assert [v.cloude_fraction for v in v_old] == [v.cloude_fraction for v in v_new]
    assert v_old[1].gk_fraction == v_new[1].gk_fraction == 1.0
    np.testing.assert_allclose(new, old, atol=1e-12)
