"""Peak memory of a call, for the benchmarks (measured in its own run, apart from the timing).

Two measures, each named in the JSON next to its number:

- :func:`traced_peak_mib`: the peak of Python-traced allocations (``tracemalloc``; numpy
  arrays included). Tracing slows the call down, so it never runs inside a timed call.
- :func:`resident_peak_mib`: for torch, whose CPU tensors bypass ``tracemalloc``: the kernel's
  resident-set high-water mark (``VmHWM``, reset through ``/proc/self/clear_refs`` after glibc's
  ``malloc_trim``) minus the resident set at the start; without ``/proc``, the growth of
  ``getrusage`` ``ru_maxrss`` (0 unless the process peak grows). On CUDA,
  ``torch.cuda.max_memory_allocated`` above the allocation at the start.

Example:
    >>> peak = traced_peak_mib(lambda: bytearray(4 * 2**20))
    >>> 3.9 < peak < 4.5
    True
"""

from __future__ import annotations

import contextlib
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["resident_peak_mib", "traced_peak_mib"]


def traced_peak_mib(fn: Callable[[], Any]) -> float:
    """Peak Python-traced memory of one call of ``fn``, in MiB.

    Args:
        fn: the call, without arguments.

    Returns:
        The ``tracemalloc`` peak during the call.
    """
    tracemalloc.start()
    tracemalloc.reset_peak()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 2**20


def _proc_status_kib(key: str) -> int | None:
    """A ``/proc/self/status`` field in KiB (e.g. ``VmRSS``), or None without ``/proc``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _malloc_trim() -> None:
    """Hand freed heap pages back to the kernel (glibc), so that reusing them counts as resident growth again."""
    import ctypes  # noqa: PLC0415
    import ctypes.util  # noqa: PLC0415

    name = ctypes.util.find_library("c")
    if name:
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(name).malloc_trim(0)


def resident_peak_mib(fn: Callable[[], Any], device: str = "cpu") -> tuple[float, str, Any]:
    """Peak memory above the start while ``fn()`` runs (torch tensors included).

    Args:
        fn: the call, without arguments (it may time itself, e.g. wrap :func:`~network.bench.timing.time_call`).
        device: ``"cpu"`` or ``"cuda[:N]"``.

    Returns:
        ``(peak MiB, how it was measured, fn's return value)``.
    """
    if device.startswith("cuda"):
        import torch  # noqa: PLC0415

        torch.cuda.synchronize()
        start = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()
        out = fn()
        torch.cuda.synchronize()
        return (torch.cuda.max_memory_allocated() - start) / 2**20, "torch.cuda.max_memory_allocated", out
    try:
        _malloc_trim()
        Path("/proc/self/clear_refs").write_text("5")
        start = _proc_status_kib("VmRSS")
    except OSError:
        start = None
    if start is not None:
        out = fn()
        peak = (_proc_status_kib("VmHWM") - start) / 1024
        return peak, "VmHWM (reset via /proc/self/clear_refs after malloc_trim) - VmRSS at start", out
    import resource  # noqa: PLC0415

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = fn()
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    return grown, "growth of getrusage ru_maxrss (process peak)", out
