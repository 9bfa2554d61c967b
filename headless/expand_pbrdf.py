"""Expand a small set of pBRDFs into many physically valid ones (the paper's Section 6).

    python headless/expand_pbrdf.py --out DIR [--count 2000] [--measured DIR] [--seed S]

Without --measured the built-in analytic seed set (spectralon, billiard resins, silicones,
ceramics, plastics, gold, brass, chrome, steel, aluminium) stands in for the measured tables.
Writes DIR/tables/gen_NNNNN.pbsdf (Mitsuba measured_polarized format, 5 bands) with a JSON
sidecar each (fitted Disney parameters, validity), DIR/materials.json (what
`headless/render.py --pbrdfs DIR` reads), DIR/manifest.json (explained variance, validity
statistics, timings), DIR/model/ (PCA bases, generator checkpoint) and figures: spheres under
unpolarized light with intensity, DoLP and DoCP for a sample of seed and generated materials.
A killed run continues where it stopped when started again with the same arguments.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="expand_pbrdf.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--count", type=int, default=2000, help="tables to generate (default 2000)")
    parser.add_argument("--measured", type=Path, help="folder of measured .pbsdf/.hpbrdf files (default: built-in)")
    parser.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    parser.add_argument("--components", type=int, nargs=2, default=[10, 10], metavar=("K_I", "K_P"),
                        help="PCA components for intensity and polarization (default 10 10)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    from pbrdf.expansion.run import ExpansionConfig, run_expansion  # noqa: PLC0415

    try:
        if args.count < 1:
            raise ValueError(f"--count must be >= 1, got {args.count}")
        if args.measured is not None and not args.measured.is_dir():
            raise FileNotFoundError(f"--measured {args.measured}: not a folder")
        cfg = ExpansionConfig(
            out=args.out, count=args.count, seed=args.seed, measured=args.measured,
            k_intensity=args.components[0], k_polarization=args.components[1],
        )  # fmt: skip
        report = run_expansion(cfg, progress=not args.quiet)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(report.summary())
    print(f"materials: {(args.out / 'materials.json').resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
