"""Write synthetic calibration target captures from a rig with known imperfections.

    python tools/make_calibration_captures.py --out CAPTURES_DIR [--rig TRUE_RIG.json] [--size 128] [--seed 0]

Forms the dark, white (R, G, B; again at commanded levels 0.25 and 0.5, and at 0.4 m) and polarizer
targets of docs/calibration.md in closed form
(pbrdf/sensor/calibration_targets.py), passes them through the camera model with noise and saves
one capture folder per target under CAPTURES_DIR, plus CAPTURES_DIR/true_rig.json (the rig they
came from) for comparison with what headless/calibrate.py estimates. Without --rig the rig is an
example with every imperfection on (EXAMPLE_IMPERFECTIONS). The raw frame is --size x --size
pixels, with a focal length of 0.94 --size pixels (the real camera's field of view).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

if not __package__:  # run as a file (python tools/x.py): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: The example rig's camera-model imperfections (and the display's below).
EXAMPLE_IMPERFECTIONS = {
    "qwp_angle": 0.03,
    "qwp_retardance": [1.50, 1.62, 1.66],
    "extinction_ratio": [80.0, 120.0, 200.0],
    "ambient": [0.004, 0.006, 0.003],
    "crosstalk": [[0.92, 0.06, 0.01], [0.08, 0.95, 0.05], [0.02, 0.07, 0.90]],
    "vignetting_poly": [-0.1, 0.03, 0.0],
}
EXAMPLE_DISPLAY = {
    "degree_of_polarization": 0.97,
    "polarization_angle": math.pi / 2 + 0.04,
    "emission_exponent": 0.8,
    "tone_gamma": [2.2, 2.0, 2.4],
}


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="make_calibration_captures.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="folder to write the target capture folders into")
    parser.add_argument("--rig", type=Path, default=None, help="the true rig JSON (default: the example rig)")
    parser.add_argument("--size", type=int, default=128, help="raw frame size in pixels, a multiple of 4")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.size < 8 or args.size % 4:
        parser.error(f"--size must be a multiple of 4 and at least 8; got {args.size}")
    from pbrdf.data.calibration_captures import save_targets  # noqa: PLC0415
    from pbrdf.sensor.calibration_targets import simulate_targets  # noqa: PLC0415
    from pbrdf.sensor.projection import pinhole_intrinsics  # noqa: PLC0415
    from pbrdf.sensor.rig import Rig  # noqa: PLC0415

    focal = 0.94 * args.size
    if args.rig is not None:
        rig = Rig.load(args.rig)
    else:
        model = {**EXAMPLE_IMPERFECTIONS, "vignetting_focal_px": focal}
        rig = Rig.from_dict({"display": EXAMPLE_DISPLAY, "camera": {"model": model}})
    k = pinhole_intrinsics(focal, args.size, args.size)
    targets = simulate_targets(rig, (args.size, args.size), rng=np.random.default_rng(args.seed), intrinsics=k)
    args.out.mkdir(parents=True, exist_ok=True)
    save_targets(args.out, targets)
    rig.save(args.out / "true_rig.json")
    print(f"wrote {len(targets)} target captures and true_rig.json to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
