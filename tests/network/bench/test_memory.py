"""network.bench.memory: peak memory of a call, traced (numpy) and resident (torch)."""

import numpy as np

from network.bench.memory import resident_peak_mib, traced_peak_mib


def test_traced_peak_sees_a_numpy_array():
    peak = traced_peak_mib(lambda: np.ones(2**20))  # 8 MiB of float64
    assert 7.9 < peak < 9.0


def test_resident_peak_returns_the_result_and_says_how():
    peak, how, out = resident_peak_mib(lambda: np.ones(4 * 2**20).sum())  # 32 MiB touched
    assert out == 4 * 2**20
    if how.startswith("VmHWM"):  # Linux with a writable /proc/self/clear_refs: the peak is reset, so it is exact
        assert 30.0 < peak < 48.0, peak
    else:  # the fallback only sees growth of the process peak
        assert how == "growth of getrusage ru_maxrss (process peak)" and peak >= 0.0
