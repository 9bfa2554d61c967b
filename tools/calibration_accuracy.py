"""Measure self-calibration: recovery error per field on noisy synthetic targets, and the calibrate runtime.

    python tools/calibration_accuracy.py [--seeds 5] [--size 128]

For each of three rigs (the test's: mild, strong, nominal; tests/pbrdf/sensor/test_calibration.py)
and each seed, forms the target captures (pbrdf/sensor/calibration_targets.py, noise on),
calibrates (pbrdf/sensor/calibration.py) and prints the largest error over the seeds per field
group (``1 / extinction_ratio`` for the extinction, the falloff map for the vignetting), then the
median and range of the calibration time (targets in memory: no file I/O).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

if not __package__:  # run as a file (python tools/x.py): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pbrdf.sensor.calibration import calibrate, rig_errors  # noqa: E402
from pbrdf.sensor.calibration_targets import simulate_targets  # noqa: E402
from pbrdf.sensor.camera import CameraModel  # noqa: E402
from pbrdf.sensor.projection import pinhole_intrinsics  # noqa: E402
from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig  # noqa: E402


def rigs(focal: float) -> dict[str, Rig]:
    """The three rigs of the test (same imperfections)."""

    def rig(model: dict, dop: float, angle: float, exponent: float = 0.0, gamma=(1.0, 1.0, 1.0)) -> Rig:
        display = DisplaySpec(
            degree_of_polarization=dop, polarization_angle=angle, emission_exponent=exponent, tone_gamma=gamma
        )
        return Rig(display, CameraSpec(model=CameraModel(**model)))

    return {
        "mild": rig({"qwp_angle": 0.03, "qwp_retardance": (1.50, 1.62, 1.66), "extinction_ratio": (80, 120, 200),
                     "ambient": (0.004, 0.006, 0.003), "vignetting_focal_px": focal,
                     "crosstalk": [[0.92, 0.06, 0.01], [0.08, 0.95, 0.05], [0.02, 0.07, 0.9]],
                     "vignetting_poly": (-0.1, 0.03, 0.0)}, 0.97, math.pi / 2 + 0.04, 0.8, (2.2, 2.0, 2.4)),
        "strong": rig({"qwp_angle": -0.08, "qwp_retardance": (1.32, 1.45, 1.80), "extinction_ratio": (12, 30, 50),
                       "ambient": (0.03, 0.02, 0.04), "vignetting_focal_px": focal,
                       "crosstalk": [[0.8, 0.15, 0.05], [0.18, 0.85, 0.12], [0.04, 0.2, 0.75]],
                       "vignetting_poly": (-0.3, 0.1, -0.05)}, 0.85, math.pi / 2 - 0.09, 1.8, (1.6, 2.6, 1.9)),
        "nominal": rig({}, 1.0, math.pi / 2),
    }  # fmt: skip


#: Table labels of :func:`pbrdf.sensor.calibration.rig_errors`' keys.
LABELS = {"leak": "1/extinction_ratio", "vignetting": "vignetting map", "degree_of_polarization": "display DoP",
          "polarization_angle": "display angle", "emission_exponent": "display emission exponent",
          "tone_gamma": "display tone gamma"}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Run the measurement; prints a markdown table."""
    parser = argparse.ArgumentParser(prog="calibration_accuracy.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--seeds", type=int, default=5, help="noise seeds per rig")
    parser.add_argument("--size", type=int, default=128, help="raw frame size (a multiple of 4)")
    args = parser.parse_args(argv)
    focal = 0.94 * args.size
    k = pinhole_intrinsics(focal, args.size, args.size)
    worst: dict[str, dict[str, float]] = {}
    times = []
    for name, rig in rigs(focal).items():
        for seed in range(args.seeds):
            targets = simulate_targets(rig, (args.size, args.size), rng=np.random.default_rng(seed), intrinsics=k)
            start = time.perf_counter()
            est = calibrate(targets).rig
            times.append(time.perf_counter() - start)
            for field, err in rig_errors(est, rig, (args.size, args.size)).items():
                worst.setdefault(field, {})[name] = max(worst.get(field, {}).get(name, 0.0), err)
    names = list(rigs(focal))
    print("| field | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for field, per in worst.items():
        print(f"| {LABELS.get(field, field)} | " + " | ".join(f"{per[n]:.2e}" for n in names) + " |")
    print(f"\ncalibrate: median {np.median(times):.2f} s, range {min(times):.2f} - {max(times):.2f} s "
          f"over {len(times)} runs ({args.size} x {args.size} raw frames, {len(targets)} targets)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
