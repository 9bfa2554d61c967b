"""Thin command-line entry points: each ``headless/x.py`` is a ``main(argv=None) -> int`` over a ``build_parser()``.

The library code they call lives in the packages below (``pbrdf``, ``blender_addon``,
``network``; the demo in ``network.demo``, the benchmarks in ``network.bench``). The shared
flag conventions are in :mod:`headless._cli`.
"""
