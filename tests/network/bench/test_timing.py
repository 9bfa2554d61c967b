"""network.bench.timing: the one timing rule (warm-up calls, timed repeats, median and every sample)."""

import statistics
import time

import pytest

from network.bench.timing import RULE, Timing, machine, time_call, time_interleaved


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


def test_interleaved_calls_alternate_and_each_keeps_its_own_samples():
    log = []

    def slower_each_time():  # its n-th call sleeps n * 20 ms: the warm-ups are its two quickest calls
        log.append("s")
        time.sleep(0.02 * log.count("s"))
        return len(log)

    def quick():
        log.append("q")
        return len(log)

    out = time_interleaved({"slow": (slower_each_time, "sleep n * 20 ms"), "quick": (quick, "no sleep")},
                           repeat=3, warmup=2)  # fmt: skip
    assert "".join(log) == "sq" * 5  # warm-up rounds, then timed rounds, each round in the order given
    slow, fast = out["slow"][0], out["quick"][0]
    assert (slow.what, slow.warmup_runs, slow.repeats, fast.repeats) == ("sleep n * 20 ms", 2, 3, 3)
    assert max(slow.warmup) < min(slow.samples) and min(slow.samples) >= 0.06  # calls 3-5 are the timed ones
    assert max(fast.samples) < 0.02  # each call's own clock
    assert out["slow"][1] == 9 and out["quick"][1] == 10  # the last call's return value
    with pytest.raises(ValueError, match="repeat >= 1"):
        time_interleaved({"a": (lambda: None, "a")}, repeat=0)
