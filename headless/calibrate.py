"""Calibrate the rig's imperfections from captures of lab targets and write the calibrated rig JSON.

    python headless/calibrate.py --input CAPTURES_DIR --out rig.json [--quiet]
    python -m headless.calibrate --input CAPTURES_DIR --out rig.json

Estimates the QWP fast-axis angle and retardance per channel, the analyzer extinction per channel,
the display's degree and angle of polarization, its angular emission profile and tone response,
the 3 x 3 display-to-camera cross-talk, the lens vignetting and the ambient light per channel
(pbrdf/sensor/calibration.py, calibration_display.py; why these targets: docs/calibration.md),
prints one line per field, and writes rig.json atomically: a rig file (pbrdf.sensor.rig.Rig) whose
"camera" -> "model" is the "camera_model" an object's capture.json takes, and whose "display" holds
the polarization, the emission profile and the tone response. Nothing is written unless every target is
usable and every estimate physical; otherwise one line "error: <what is missing or which field>"
on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402
from pbrdf.data.calibration_captures import load_targets  # noqa: E402
from pbrdf.sensor.calibration import calibrate  # noqa: E402

EXIT_BAD_INPUT = 2

_EPILOG = """\
CAPTURES_DIR layout: one capture folder per target (capture.json + raw brackets, the format of
pbrdf/data/capture.py), any folder names, each capture.json with a "target" key:
  dark/        "target": "dark"           the display off, the camera as for the white targets
  white_r/     "target": "white", "display_channel": "R", "albedo": 0.99, "distance_m": 0.7
  white_g/     ... "display_channel": "G"   a flat Lambertian reflectance standard facing the
  white_b/     ... "display_channel": "B"   camera, the display showing that primary alone
  white_r_050/ ... "level": 0.5             optional, per primary: the same at commanded levels
                                            below 1 (the display's tone response)
  white_r_near/ ... "distance_m": 0.4       optional: the same at a second distance, full level
                                            (the display's angular emission profile)
  polarizer_000/  "target": "polarizer", "polarizer_angle_deg": 0
  polarizer_030/  ... (>= 3 distinct angles)   the camera facing the display (all white) through
                                               a linear polarizer at that angle (analyzer frame)
Each capture may carry "dark_files" (display off, same bracket); without them the dark target's
frames are used. The white targets need the rig geometry ("rig": display pose and size) and may
give "intrinsics"; every capture's "camera_model" gives the sensor and bracket.

output: rig.json; decode an object capture with it: infer.py (or decode.py) --input CAPTURE --rig rig.json.
"""


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="calibrate.py", description=__doc__, epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, metavar="CAPTURES_DIR", required=True,
                        help="folder of target capture folders (layout below)")  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, help="rig JSON file to write (atomically)")
    parser.add_argument("--quiet", action="store_true", help="only the written path (no per-field lines)")
    return parser


def _line(name: str, entry: dict) -> str:
    value = entry["value"]
    text = "-" if value is None else json.dumps(value, default=float)
    return f"{name}: {text} ({entry['note']})"


def run(captures: Path, out: Path, *, quiet: bool = False) -> Path:
    """Load the targets, calibrate and write ``out``; prints the per-field lines unless ``quiet``.

    Raises:
        ValueError: a missing or unusable target, or a non-physical estimate (one line).
        OSError: unreadable captures or an unwritable ``out``.
    """
    start = time.perf_counter()
    cal = calibrate(load_targets(captures))
    if out.exists() and out.is_dir():
        raise IsADirectoryError(f"{out}: output path is a folder; give a file name such as rig.json")
    cal.rig.save(out)
    if not quiet:
        for name, entry in cal.report.items():
            print(_line(name, entry))
        print(f"sensor offset (DN, R G B): {' '.join(f'{o:.2f}' for o in cal.offset_dn)}")
        print(f"calibrated in {time.perf_counter() - start:.2f} s")
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 for bad input)."""
    args = build_parser().parse_args(argv)

    def work() -> int:
        print(run(args.input, args.out, quiet=args.quiet))
        return 0

    return held_warnings(work, status=EXIT_BAD_INPUT)


if __name__ == "__main__":
    raise SystemExit(main())
