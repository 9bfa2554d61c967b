"""Evaluate trained models against ground truth and the photometric-stereo baseline.

    python headless/evaluate.py --checkpoint runs/full/model.pt --input DIR [--out DIR] [--limit N] [--quiet]
    python headless/evaluate.py --checkpoint white=runs/w/model.pt --checkpoint spectral=runs/s/model.pt \\
        --checkpoint polar=runs/p/model.pt --checkpoint full=runs/f/model.pt --input DIR --white-data WDIR

--input is a rendered dataset with ground truth (headless/render.py). Prints and writes (to
--out, default INPUT/eval) the paper's Table 1 (photometric stereo vs ours:
normal MAE, albedo PSNR / LPIPS / si-PSNR / si-LPIPS, roughness and metallic RMSE, and the
difference to the baseline) in table1.md, the Table 3 input ablation in table3.md (one
checkpoint per variant as VARIANT=PATH; variants: white, spectral, polar, full; a bare PATH takes
its variant from the checkpoint's "inputs"), and everything per sample in metrics.json.
The 'white' variant needs the same scenes rendered with the white display pattern
(`headless/render.py --rig white.json`, white.json = {"display": {"pattern": "white"}}): --white-data.
--real DIR adds the re-rendering error on real captures (real.md). --data still works for one
release (use --input).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import add_deprecated, require  # noqa: E402


def _checkpoints(values: list[str]) -> dict[str, Path] | Path:
    """The --checkpoint values: ``["PATH"]`` -> PATH; ``["VARIANT=PATH", ...]`` -> {VARIANT: PATH}.

    Raises:
        ValueError: several checkpoints without ``VARIANT=``, or a variant given twice.
    """
    from network.inputs import INPUT_VARIANTS  # noqa: PLC0415

    if len(values) == 1 and "=" not in values[0]:
        return Path(values[0])
    out: dict[str, Path] = {}
    for v in values:
        variant, sep, path = v.partition("=")
        if not sep or not path:
            raise ValueError(
                f"--checkpoint {v!r}: with several checkpoints use VARIANT=PATH ({', '.join(INPUT_VARIANTS)})"
            )
        if variant in out:
            raise ValueError(f"--checkpoint: variant {variant!r} given twice")
        out[variant] = Path(path)
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="evaluate.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", action="append", required=True, metavar="[VARIANT=]PATH",
                        help="model.pt/checkpoint.pt; repeat as VARIANT=PATH for the input ablation")  # fmt: skip
    parser.add_argument("--input", type=Path, metavar="DIR", help="rendered dataset with ground truth (required)")
    parser.add_argument("--white-data", type=Path, help="the same scenes rendered with the white pattern")
    parser.add_argument("--real", type=Path, help="folder of real captures: re-rendering error")
    parser.add_argument("--out", type=Path, help="output folder (default INPUT/eval)")
    parser.add_argument("--limit", type=int, help="evaluate only the first N samples")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_deprecated(parser, "--data", new="--input", type=Path)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    require(parser, args, "--input")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    from network.evaluate import evaluate, real_markdown, table1_markdown, table3_markdown, write_results  # noqa: PLC0415

    try:
        result = evaluate(_checkpoints(args.checkpoint), args.input, limit=args.limit, white_data=args.white_data,
                          real=args.real, progress=not args.quiet)  # fmt: skip
        files = write_results(result, args.out or args.input / "eval")
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table1_markdown(result))
    if len(result["methods"]) > 2:
        print(table3_markdown(result))
    if result.get("real"):
        print(real_markdown(result))
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
