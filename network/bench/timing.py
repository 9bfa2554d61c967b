"""The one timing rule of every benchmark: warm-up calls, then timed repeats, median and all samples.

Every timed entry in a benchmark's JSON comes from :func:`time_call` and says exactly what was
timed (``what``), how many untimed warm-up calls ran first (``warmup_runs``, with their
seconds), how many timed calls followed (``repeats``), their median (``seconds_median``) and
every sample (``seconds_all``). The median, not the minimum: it is what a user waiting for the
call sees on a shared machine, and with all samples reported a reader can take the minimum.

Example:
    >>> calls = []
    >>> t, result = time_call(lambda: calls.append(1) or len(calls), "append to a list", warmup=2, repeat=3)
    >>> result, len(calls), t.repeats, t.warmup_runs
    (5, 5, 3, 2)
    >>> sorted(t.to_dict())
    ['repeats', 'seconds_all', 'seconds_median', 'warmup_runs', 'warmup_seconds', 'what']
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["RULE", "Timing", "machine", "time_call", "time_interleaved"]

#: The rule in words, written into every benchmark's JSON as ``timing_rule``.
RULE = (
    "each timed entry: `warmup_runs` untimed calls, then `repeats` timed calls of exactly `what`; "
    "`seconds_median` is their median, `seconds_all` every sample (wall clock, time.perf_counter; "
    "CUDA work is synchronised before and after each call)"
)


@dataclass(frozen=True)
class Timing:
    """Wall-clock samples of one call under :data:`RULE`.

    Attributes:
        what: exactly what was timed (the call and its inputs, in words).
        samples: seconds of each timed call, in order.
        warmup: seconds of each untimed warm-up call, in order.
    """

    what: str
    samples: tuple[float, ...]
    warmup: tuple[float, ...] = ()

    @property
    def median(self) -> float:
        """Median of :attr:`samples` in seconds."""
        return statistics.median(self.samples)

    @property
    def repeats(self) -> int:
        """Number of timed calls."""
        return len(self.samples)

    @property
    def warmup_runs(self) -> int:
        """Number of warm-up calls."""
        return len(self.warmup)

    def to_dict(self) -> dict[str, Any]:
        """The JSON entry.

        Returns:
            ``what``, ``warmup_runs``, ``warmup_seconds``, ``repeats``, ``seconds_median`` and ``seconds_all``.
        """
        return {
            "what": self.what,
            "warmup_runs": self.warmup_runs,
            "warmup_seconds": list(self.warmup),
            "repeats": self.repeats,
            "seconds_median": self.median,
            "seconds_all": list(self.samples),
        }


def time_call(
    fn: Callable[[], Any],
    what: str,
    *,
    repeat: int = 5,
    warmup: int = 1,
    sync: Callable[[], None] | None = None,
) -> tuple[Timing, Any]:
    """Time ``fn()`` under the one rule: ``warmup`` untimed calls, then ``repeat`` timed calls.

    Args:
        fn: the call to time, without arguments.
        what: exactly what ``fn`` does, for the JSON entry.
        repeat: timed calls, >= 1.
        warmup: untimed calls before them, >= 0 (their seconds are kept too).
        sync: called before starting and before stopping each clock (e.g.
            ``torch.cuda.synchronize``), so that asynchronous work is counted.

    Returns:
        ``(timing, result)``: the :class:`Timing` and the last call's return value.

    Raises:
        ValueError: ``repeat < 1`` or ``warmup < 0``.
    """
    if repeat < 1 or warmup < 0:
        raise ValueError(f"need repeat >= 1 and warmup >= 0, got repeat={repeat}, warmup={warmup}")
    sync = sync or (lambda: None)
    seconds: list[float] = []
    result = None
    for _ in range(warmup + repeat):
        sync()
        t0 = time.perf_counter()
        result = fn()
        sync()
        seconds.append(time.perf_counter() - t0)
    return Timing(what, tuple(seconds[warmup:]), tuple(seconds[:warmup])), result


def time_interleaved(
    calls: dict[str, tuple[Callable[[], Any], str]],
    *,
    repeat: int = 5,
    warmup: int = 1,
    sync: Callable[[], None] | None = None,
) -> dict[str, tuple[Timing, Any]]:
    """Time several calls side by side under the one rule, their calls alternating.

    ``warmup`` rounds of one untimed call of each, then ``repeat`` rounds of one timed call of
    each, in the order of ``calls``: a load that changes on a shared machine falls on every call
    alike, so their ratios hold even when their absolute times drift.

    Args:
        calls: ``name -> (fn, what)``, as :func:`time_call`'s ``fn`` and ``what``.
        repeat: timed calls of each, >= 1.
        warmup: untimed calls of each before them, >= 0.
        sync: as for :func:`time_call`.

    Returns:
        ``name -> (timing, result)``: each call's :class:`Timing` and its last return value.

    Raises:
        ValueError: ``repeat < 1`` or ``warmup < 0``.

    Example:
        >>> order = []
        >>> out = time_interleaved({"a": (lambda: order.append("a"), "a"), "b": (lambda: order.append("b"), "b")},
        ...                        repeat=2, warmup=1)
        >>> "".join(order), out["a"][0].repeats, out["b"][0].warmup_runs
        ('ababab', 2, 1)
    """
    if repeat < 1 or warmup < 0:
        raise ValueError(f"need repeat >= 1 and warmup >= 0, got repeat={repeat}, warmup={warmup}")
    seconds: dict[str, list[float]] = {k: [] for k in calls}
    results: dict[str, Any] = {}
    for _ in range(warmup + repeat):
        for k, (fn, what) in calls.items():
            timing, results[k] = time_call(fn, what, repeat=1, warmup=0, sync=sync)
            seconds[k].append(timing.samples[0])
    return {
        k: (Timing(what, tuple(seconds[k][warmup:]), tuple(seconds[k][:warmup])), results[k])
        for k, (_, what) in calls.items()
    }


def machine(**versions: str) -> dict[str, Any]:
    """The machine a benchmark ran on: CPU count, load average, Python and the given versions.

    Args:
        **versions: extra ``name=version`` entries (e.g. ``numpy=np.__version__``).

    Returns:
        ``{"cpus", "load_average", "python", **versions}``.
    """
    load = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return {"cpus": os.cpu_count(), "load_average": load, "python": platform.python_version(), **versions}
