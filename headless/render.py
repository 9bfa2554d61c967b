"""Generate a synthetic dataset of polarized display captures.

Random objects in front of the polarized display are rendered with Mitsuba 3, passed through
the camera model and the decoder.

    python headless/render.py --out DIR --count N [--resolution 384] [--seed S] [--spp 32]
        [--assets DIR] [--pbrdfs DIR] [--rig FILE] [--resume] [--shard K/N]

Each sample is DIR/samples/NNNNNN.exr (nine maps, mask, normal, albedo, roughness, metallic,
depth; optionally Stokes) plus a JSON sidecar (rig, pose, material, Disney parameters, seeds,
versions); DIR/manifest.json lists the completed samples. Every sample is a pure function of
--seed and its index: --shard K/N renders the indices i with i % N == K (run N processes, e.g.
a job array, into the same folder), --resume skips completed samples after a kill.

Without --assets the built-in procedural shapes are used; without --pbrdfs, analytic
polarimetric materials (pplastic and rough conductors) with random parameters.
(The Blender route, `blender -b -P headless/render.py -- ...`, is planned.)
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="render.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="dataset folder")
    parser.add_argument("--count", type=int, required=True, help="total number of samples in the dataset")
    parser.add_argument("--resolution", type=int, default=384, help="sample size in pixels (default 384)")
    parser.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    parser.add_argument("--spp", type=int, default=32, help="samples per pixel per colour pass (default 32)")
    parser.add_argument("--assets", type=Path, help="folder of GLB/GLTF/OBJ/PLY assets (default: procedural shapes)")
    parser.add_argument("--pbrdfs", type=Path, help="folder with materials.json and pBRDF tables (default: analytic)")
    parser.add_argument("--rig", type=Path, help="rig JSON overriding the default rig (calibrated rigs)")
    parser.add_argument("--resume", action="store_true", help="continue a killed run: skip completed samples")
    parser.add_argument("--shard", default="0/1", help="K/N: render only indices i with i %% N == K (default 0/1)")
    parser.add_argument("--keep-stokes", action="store_true", help="also store the rendered Stokes images")
    parser.add_argument("--keep-raw", action="store_true", help="also store the raw HDR bracket (capture folder)")
    parser.add_argument("--no-noise", action="store_true", help="noise-free camera model")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("-v", "--verbose", action="store_true", help="log tracebacks of failed samples")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")

    from blender_addon.core.generate import GenerateConfig, generate  # noqa: PLC0415
    from pbrdf.dataset import parse_shard  # noqa: PLC0415

    try:
        cfg = GenerateConfig(
            out=args.out,
            count=args.count,
            resolution=args.resolution,
            seed=args.seed,
            spp=args.spp,
            assets=args.assets,
            pbrdfs=args.pbrdfs,
            rig=args.rig,
            resume=args.resume,
            shard=parse_shard(args.shard),
            keep_stokes=args.keep_stokes,
            keep_raw=args.keep_raw,
            noise=not args.no_noise,
        )
        report = generate(cfg, progress=not args.quiet)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(report.summary())
    return 1 if report.failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
