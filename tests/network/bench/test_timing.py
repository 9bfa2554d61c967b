"""network.bench.timing: the one timing rule (warm-up calls, timed repeats, median and every sample)."""

import statistics

import pytest

from network.bench.timing import RULE, Timing, machine, time_call


def test_warmup_then_repeats_and_the_last_result():
    calls = []
    timing, result = time_call(lambda: calls.append(None) or len(calls), "count calls", repeat=4, warmup=2)
    assert len(calls) == 6 and result == 6
    assert timing.warmup_runs == 2 and timing.repeats == 4
    assert timing.median == statistics.median(timing.samples)
    entry = timing.to_dict()
    assert entry["what"] == "count calls"
    assert entry["seconds_all"] == list(timing.samples) and entry["warmup_seconds"] == list(timing.warmup)
    assert entry["seconds_median"] == timing.median


def test_sync_wraps_every_call():
    events = []
    time_call(lambda: events.append("call"), "x", repeat=2, warmup=1, sync=lambda: events.append("sync"))
    assert events == ["sync", "call", "sync"] * 3


def test_median_of_known_samples():
    t = Timing("x", (3.0, 1.0, 2.0, 10.0), (5.0,))
    assert t.median == 2.5 and t.repeats == 4 and t.warmup_runs == 1


@pytest.mark.parametrize(("repeat", "warmup"), [(0, 1), (1, -1)])
def test_bad_counts(repeat, warmup):
    with pytest.raises(ValueError, match="repeat >= 1 and warmup >= 0"):
        time_call(lambda: None, "x", repeat=repeat, warmup=warmup)


def test_rule_and_machine():
    assert "median" in RULE and "warmup_runs" in RULE
    info = machine(numpy="1.0")
    assert info["cpus"] >= 1 and info["numpy"] == "1.0" and info["python"].count(".") == 2
