"""Benchmarks with JSON output (behind ``headless/bench.py``): run time against error, side by side.

One module per benchmark, each with a ``run(...) -> dict``: :mod:`network.bench.decode`
(``decode``: raw bracket -> nine maps, against polanalyser), :mod:`network.bench.render`
(``render``: rendered maps, error against time, default vs naive configuration),
:mod:`network.bench.expansion` (``pbrdf``: PCA, validity filter, expansion speed) and
:mod:`network.bench.model` (``network``: inference and training time, memory, stride error).
All of them time with the one rule of :mod:`network.bench.timing` (warm-up calls, then timed
repeats; median and every sample; each entry says what it timed) and measure memory with
:mod:`network.bench.memory`.
"""

#: Benchmark name (the ``headless/bench.py`` sub-command) -> module under ``network.bench``.
BENCHMARKS = {"decode": "decode", "render": "render", "pbrdf": "expansion", "network": "model"}

__all__ = ["BENCHMARKS"]
