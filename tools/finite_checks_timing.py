"""Time the hot paths the finite-result checks touch (docs/measurements/pbrdf.md, "No NaN leaves").

    python tools/finite_checks_timing.py [--repeat 7]

Prints the median wall time of: ``mueller.rotator`` and ``mueller.retarder`` on 1e5 angles, one
scalar ``rotator`` call, ``microfacet.dielectric_pbrdf`` on 1e5 direction pairs and
``mueller.jones_to_mueller`` on 1e5 matrices. Run it from two checkouts (before and after a change)
side by side: ``PYTHONPATH=OTHER_CHECKOUT python tools/finite_checks_timing.py``.
"""

from __future__ import annotations

import argparse
import os
import sys
import timeit
from pathlib import Path

import numpy as np

if not __package__ and "PYTHONPATH" not in os.environ:  # this checkout, unless PYTHONPATH names another
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pbrdf.brdf import microfacet  # noqa: E402
from pbrdf.polar import mueller  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Run the timings; prints one line per entry (seconds)."""
    parser = argparse.ArgumentParser(prog="finite_checks_timing.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--repeat", type=int, default=7, help="timed calls per entry (median printed)")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    t = rng.uniform(-3, 3, 100_000)
    wi, wo = (rng.normal(size=(100_000, 3)) for _ in range(2))
    for w in (wi, wo):
        w[:, 2] = np.abs(w[:, 2])
        w /= np.linalg.norm(w, axis=-1, keepdims=True)
    j = rng.normal(size=(100_000, 2, 2)) + 1j * rng.normal(size=(100_000, 2, 2))
    entries = {
        "rotator (1e5 angles)": lambda: mueller.rotator(t),
        "retarder (1e5 angles)": lambda: mueller.retarder(1.5, t),
        "rotator (one scalar call)": lambda: mueller.rotator(0.3),
        "dielectric_pbrdf (1e5 pairs)": lambda: microfacet.dielectric_pbrdf(wi, wo, albedo=0.5, eta=1.5, alpha=0.2),
        "jones_to_mueller (1e5)": lambda: mueller.jones_to_mueller(j),
    }
    print(f"pbrdf from {Path(mueller.__file__).resolve().parents[2]}")
    for name, fn in entries.items():
        fn()  # warm-up
        print(f"{name}: {np.median(timeit.repeat(fn, number=1, repeat=args.repeat)):.3g} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
