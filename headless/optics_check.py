"""The optics/camera round trip on a built-in analytic scene: two spheres, no renderer, no network.

    python headless/optics_check.py [--out out/optics-check] [--height 384] [--width 512] [--seed 0] [--quiet]

A dielectric sphere and a gold sphere sit 0.7 m in front of the camera; behind the camera the
LCD shows the RGB binary pattern with vertically polarized light. The scene is shaded
analytically (Fresnel reflection of the display through the Mueller algebra, Lambertian
diffuse), then goes through the camera model (QWP, micro-polarizers, IMX250MYR mosaic,
Poisson-Gaussian noise, 12-bit HDR brackets) and back through the decoder, exactly as a real
capture would (network.demo.optics).

Writes to --out: inputs.png and nine_maps.png (decoded, true and error maps), maps.npy,
mask.npy and truth_maps.npy, the raw brackets as a capture folder (capture/) and metrics.json
(per-map errors, mask agreement, seconds per stage), then prints the per-map errors.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="optics_check.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("out/optics-check"),
                        help="output folder (default out/optics-check)")  # fmt: skip
    parser.add_argument("--height", type=int, default=384, help="raw height in pixels, multiple of 4 (default 384)")
    parser.add_argument("--width", type=int, default=512, help="raw width in pixels, multiple of 4 (default 512)")
    parser.add_argument("--seed", type=int, default=0, help="camera noise seed (default 0)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar (the errors still print)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.height % 4 or args.width % 4 or min(args.height, args.width) < 16:
        parser.error("--height and --width must be multiples of 4 and at least 16")
    from network.demo.optics import run_optics_check  # noqa: PLC0415

    try:
        metrics = run_optics_check(args.out, height=args.height, width=args.width, seed=args.seed,
                                   progress=not args.quiet)  # fmt: skip
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    raw, maps = metrics["raw_shape"], metrics["decoded_shape"]
    print(f"round trip: {raw[1]}x{raw[2]} raw, {raw[0]} brackets -> {maps[0]}x{maps[1]} maps")
    for name, m in metrics["maps"].items():
        print(f"  {name:8s} MAE {m['mae']:.4f}  (truth mean {m['truth_mean']:.4f})")
    print("  timings: " + ", ".join(f"{k} {v:.2f}" for k, v in metrics["timings"].items()))
    print(f"figures and metrics: {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
