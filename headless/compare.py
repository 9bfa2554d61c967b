"""Compare two evaluations of the same test scenes, scene by scene, with paired 95 % intervals.

    python headless/compare.py --before out/eval-shipped --after out/eval-candidate [--out compare.md] [--gate]

--before and --after are what headless/evaluate.py wrote (a folder holding test_splits.json or
evaluation.json, or that JSON file itself): typically the shipped model and a candidate scored on
the same splits. For every split both scored and every metric (normal MAE, albedo PSNR and
si-PSNR, roughness and metallic RMSE), the table gives both per-scene means, the paired mean
improvement (positive: --after is better) with its 95 % bootstrap interval over the scenes, and a
verdict (better / worse / no difference). The table prints (--quiet: only its last line, what
is worse), and with --out is also written (atomically). With --gate the exit status is 3 when
--after is worse on any split and metric: the check a model passes before it replaces the shipped
one (network/compare.py).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402

#: Status of --gate when the candidate is worse somewhere.
WORSE = 3


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="compare.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--before", type=Path, required=True, help="the reference's evaluation (folder or JSON)")
    parser.add_argument("--after", type=Path, required=True, help="the candidate's evaluation (folder or JSON)")
    parser.add_argument("--out", type=Path, help="also write the table here (markdown)")
    parser.add_argument("--gate", action="store_true", help=f"exit {WORSE} when --after is worse anywhere")
    parser.add_argument("--quiet", action="store_true", help="print only the verdict line (and the path written)")
    return parser


def _results(path: Path, flag: str) -> list[dict]:
    """The ``results`` list of an evaluation folder or JSON file (one clear error otherwise)."""
    if path.is_dir():
        found = [path / n for n in ("test_splits.json", "evaluation.json") if (path / n).is_file()]
        if not found:
            raise FileNotFoundError(f"{flag} {path}: no test_splits.json or evaluation.json in it")
        path = found[0]
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{flag} {path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    results = data.get("results") if isinstance(data, dict) else None
    if not isinstance(results, list) or not all(isinstance(r, dict) for r in results):
        raise ValueError(f"{flag} {path}: not an evaluation (no 'results' list; write it with headless/evaluate.py)")
    return results


def _compare(args: argparse.Namespace) -> int:
    from network.compare import compare_markdown, compare_results, worse_cells  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    before, after = _results(args.before, "--before"), _results(args.after, "--after")
    rows = compare_results(before, after)
    if not rows:
        raise ValueError("--before and --after share no split with per-scene scores")
    md = compare_markdown(rows, str(args.before), str(args.after))
    print(md.strip().splitlines()[-1] if args.quiet else md)
    if args.out is not None:
        atomic_write_text(args.out, md)
        print(f"wrote {args.out}")
    return WORSE if args.gate and worse_cells(rows) else 0


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, 2 on bad input, 3 with --gate when worse)."""
    args = build_parser().parse_args(argv)
    return held_warnings(lambda: _compare(args))


if __name__ == "__main__":
    raise SystemExit(main())
