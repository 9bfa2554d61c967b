"""Write examples/capture: one synthetic capture folder in exactly the real-capture format.

    python tools/make_example_capture.py [--out examples/capture] [--seed 7] [--resolution 128] [--height H] [--quiet]

Renders one random scene with the project's renderer (Mitsuba 3 under the polarized display),
passes it through the camera model (four noisy 12-bit raw brackets of the IMX250MYR mosaic)
and saves the raw frames plus capture.json (pbrdf/data/capture.py, format "pdir-capture/1").
The extra keys "rig" (the display/camera rig), "intrinsics" (3x3, of the raw grid) and
"distance_m" let the real-data loss place the pixels; the ground truth goes to
<out>_truth.npz beside the folder (examples/capture_truth.npz) for checking predictions.

The renderer's frames are square; --height H (even, below --resolution) keeps the middle H
decoded rows, so --resolution 1224 --height 1024 gives the sensor's own 2448 x 2048 raw frame
(the crop moves the principal point with it; the truth is cropped alike).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

if not __package__:  # run as a file (python tools/x.py): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


_TRUTH = ("mask", "normal", "albedo", "roughness", "metallic", "depth")


def _row_crop(resolution: int, height: int | None) -> int:
    """First decoded row kept by ``--height`` (even, so the raw crop starts on the mosaic's 4-row tile)."""
    return 0 if height is None else (resolution - height) // 4 * 2


def _height_flag(height: int | None) -> str:
    return "" if height is None else f" --height {height}"


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="make_example_capture.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("examples/capture"), help="capture folder to write")
    parser.add_argument("--seed", type=int, default=7, help="scene seed (default 7)")
    parser.add_argument("--resolution", type=int, default=128, help="decoded map size (raw is twice; default 128)")
    parser.add_argument("--height", type=int, default=None,
                        help="keep the middle HEIGHT decoded rows (even; default: square)")  # fmt: skip
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel per colour pass (default 64)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar (the summary line still prints)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.height is not None and not (0 < args.height <= args.resolution and args.height % 2 == 0):
        parser.error(f"--height must be even and in 2..{args.resolution} (--resolution); got {args.height}")
    from pbrdf.sensor.rig import Rig  # noqa: PLC0415

    cam = Rig().camera  # the raw frame must fit the sensor, as a real capture does (pbrdf.data.capture_decode)
    if 2 * args.resolution > cam.sensor_width_px or 2 * (args.height or args.resolution) > cam.sensor_height_px:
        parser.error(f"the raw frame (twice --resolution, twice --height) must fit the {cam.sensor_width_px} x "
                     f"{cam.sensor_height_px} sensor; e.g. --resolution 1224 --height 1024")  # fmt: skip
    from blender_addon.core.generate import GenerateConfig, generate  # noqa: PLC0415
    from pbrdf.data import capture  # noqa: PLC0415
    from pbrdf.data import sample as psample  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_open  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as tmp:
        generate(GenerateConfig(out=Path(tmp), count=1, resolution=args.resolution, spp=args.spp, seed=args.seed,
                                keep_raw=True), progress=not args.quiet)  # fmt: skip
        sample, meta = psample.read_sample(Path(tmp), 0)
        raw = capture.load_capture(Path(tmp) / "samples" / f"000000{psample.RAW_SUFFIX}")
        k = np.asarray(meta["intrinsics"], dtype=np.float64)
        k[:2] *= 2.0  # the raw grid has twice the decoded resolution
        top = _row_crop(args.resolution, args.height)
        rows = slice(top, top + (args.height or args.resolution))
        k[1, 2] -= 2 * top  # raw rows above the crop are gone
        sample = {key: np.asarray(value)[rows] for key, value in sample.items() if key in _TRUTH}
        depth = sample["depth"][sample["mask"].astype(bool)]
        extra = {"rig": meta["rig"], "intrinsics": k.tolist(), "distance_m": float(np.median(depth)),
                 "source": f"synthetic: tools/make_example_capture.py --seed {args.seed} --resolution "
                           f"{args.resolution}{_height_flag(args.height)} --spp {args.spp}"}  # fmt: skip
        if args.out.exists():
            shutil.rmtree(args.out)
        raws = raw.raws[:, 2 * rows.start : 2 * rows.stop]  # an even offset keeps the mosaic's phase (4 x 4 tile)
        capture.save_capture(args.out, raws, raw.model, extra=extra)
        with atomic_open(args.out.parent / f"{args.out.name}_truth.npz") as f:
            np.savez_compressed(f, **{key: sample[key] for key in _TRUTH})
    print(f"wrote {args.out} and {args.out.name}_truth.npz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
