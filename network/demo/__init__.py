"""The demo behind ``make demo`` and its report, plus the analytic optics round trip.

Modules: :mod:`network.demo.pipeline` (the end-to-end pipeline, ``headless/demo.py``),
:mod:`network.demo.report` (figures and ``report.html``), :mod:`network.demo.optics` (the
analytic two-sphere optics/camera round trip, ``headless/optics_check.py``). The demo sits on
top of the library (pbrdf, ``blender_addon.core``, network); its Blender stage runs
``headless/relight.py --jobs`` in its own process, so nothing here imports bpy.
"""

from network.demo.pipeline import DemoConfig, run_demo

__all__ = ["DemoConfig", "run_demo"]
