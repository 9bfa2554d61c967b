"""Expand a small set of pBRDFs into many physically valid ones (the paper's Section 6).

    python headless/expand_pbrdf.py --out DIR [--count 2000] [--input DIR] [--seed S] [--quiet]

--input is a folder of measured seed tables (.pbsdf/.hpbrdf); without it the built-in analytic
seed set (spectralon, billiard resins, silicones, ceramics, plastics, gold, brass, chrome,
steel, aluminium) stands in for the measured tables. Writes DIR/tables/gen_NNNNN.pbsdf (Mitsuba
measured_polarized format, 5 bands) with a JSON sidecar each (fitted Disney parameters,
validity), DIR/materials.json (what `headless/render.py --pbrdfs DIR` reads), DIR/manifest.json
(explained variance, validity statistics, timings), DIR/model/ (PCA bases, generator
checkpoint) and figures (pbrdf.expansion.figures): a sphere per material with its colour and
DoLP under unpolarized light and its signed CP/S0 under 45-degree linear light, each on a scale
fitted to it, for every seed (figure_seeds.png) and up to 8 generated tables
(figure_generated.png). A killed run continues where it
stopped when started again with the same arguments (the temporary files it left are removed).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="expand_pbrdf.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--count", type=int, default=2000, help="tables to generate (default 2000)")
    parser.add_argument("--input", type=Path, metavar="DIR",
                        help="folder of measured .pbsdf/.hpbrdf seed tables (default: the built-in set)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    parser.add_argument("--components", type=int, nargs=2, default=[10, 10], metavar=("K_I", "K_P"),
                        help="PCA components for intensity and polarization, each >= 1 (default 10 10)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    from pbrdf.expansion.run import ExpansionConfig, run_expansion  # noqa: PLC0415

    try:
        if args.count < 1:
            raise ValueError(f"--count must be >= 1, got {args.count}")
        if args.input is not None and not args.input.is_dir():
            raise FileNotFoundError(f"--input {args.input}: not a folder")
        cfg = ExpansionConfig(
            out=args.out, count=args.count, seed=args.seed, measured=args.input,
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
