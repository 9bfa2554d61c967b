"""Evaluate trained models against ground truth, the photometric-stereo baseline and constant answers.

    python headless/evaluate.py --split test [--input out/splits] [--checkpoint models/small/model.pt] [--out DIR]
    python headless/evaluate.py --write-train-stats FILE --input TRAIN_DIR
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

--split test scores every test split found under --input (default out/splits; render them with
`make test-sets`), --split NAME one of them, through the real-capture path (raw brackets ->
decode -> automatic foreground mask -> model), against the calibrated photometric-stereo
baseline and the constant predictor (normal facing the camera, training means from
--train-stats, default train_stats.json beside the checkpoint), on the object coverage, with
per-scene and pixel-weighted means and 95 % bootstrap intervals. Writes test_splits.md and
test_splits.json (strict JSON) to --out (default INPUT/eval). Only test splits are accepted.
--write-train-stats FILE computes those training means from the train split at --input.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import require  # noqa: E402


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
    parser.add_argument("--checkpoint", action="append", metavar="[VARIANT=]PATH",
                        help="model.pt/checkpoint.pt; repeat as VARIANT=PATH for the input ablation "
                             "(default with --split: the shipped model)")  # fmt: skip
    parser.add_argument("--split", metavar="NAME", help="'test' (every test split under --input) or one split name")
    parser.add_argument("--train-stats", type=Path, help="training means for the constant row (--split)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="--split: worker processes (default: 2, or 1 on a one-core machine)")  # fmt: skip
    parser.add_argument("--device", choices=["cpu", "cuda", "auto"], default="cpu",
                        help="--split: the model's device (default cpu; every --jobs worker uses it)")  # fmt: skip
    parser.add_argument("--write-train-stats", type=Path, metavar="FILE", help="compute training means from --input")
    parser.add_argument("--input", type=Path, metavar="DIR", help="rendered dataset with ground truth (required)")
    parser.add_argument("--white-data", type=Path, help="the same scenes rendered with the white pattern")
    parser.add_argument("--real", type=Path, help="folder of real captures: re-rendering error")
    parser.add_argument("--out", type=Path, help="output folder (default INPUT/eval)")
    parser.add_argument("--limit", type=int, help="evaluate only the first N samples")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    if args.write_train_stats is not None:
        require(parser, args, "--input")
        return _write_train_stats(args)
    if args.split is not None:
        return _evaluate_splits(args)
    require(parser, args, "--input")
    if not args.checkpoint:
        parser.error("the following arguments are required: --checkpoint")
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


def _write_train_stats(args: argparse.Namespace) -> int:
    from network.constant import save_statistics, train_statistics  # noqa: PLC0415

    try:
        stats = train_statistics(args.input, limit=args.limit)
        path = save_statistics(stats, args.write_train_stats)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{stats['samples']} samples, {stats['pixels']} pixels: albedo {stats['albedo']}, "
          f"roughness {stats['roughness']:.3f}, metallic {stats['metallic']:.3f}\nwrote {path}")  # fmt: skip
    return 0


def _evaluate_splits(args: argparse.Namespace) -> int:
    import time  # noqa: PLC0415

    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.constant import STATS_FILE, load_statistics  # noqa: PLC0415
    from network.distributed import resolve_device  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415
    from network.split_eval import evaluate_split, split_markdown, write_split_results  # noqa: PLC0415
    from pbrdf.data.splits import get_split, test_splits  # noqa: PLC0415

    t0 = time.perf_counter()
    root = args.input or Path("out/splits")
    try:
        device = resolve_device(args.device)  # first: a missing GPU is the one error worth reporting
        if args.checkpoint and len(args.checkpoint) > 1:
            raise ValueError("--split scores one checkpoint")
        ckpt_path = Path(args.checkpoint[0]) if args.checkpoint else Path(DEFAULT_CHECKPOINT)
        names = [s.name for s in test_splits()] if args.split == "test" else [get_split(args.split).name]
        folders = [root / n for n in names if (root / n).is_dir()] if args.split == "test" else [root / names[0]]
        if not folders or not all(f.is_dir() for f in folders):
            raise FileNotFoundError(
                f"{root}: no test split folders ({', '.join(names)}); render them with `make test-sets`"
            )
        stats = load_statistics(args.train_stats or ckpt_path.parent / STATS_FILE)
        model, ckpt = load_checkpoint(ckpt_path)
        model.to(device)
        results = [
            evaluate_split(model, ckpt, f, stats, limit=args.limit, progress=not args.quiet, jobs=args.jobs,
                           checkpoint_path=ckpt_path)
            for f in folders
        ]  # fmt: skip
        files = write_split_results(results, args.out or root / "eval")
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for r in results:
        print(split_markdown(r))
    missing = [n for n in names if not (root / n).is_dir()]
    if missing:
        print(f"not rendered (skipped): {', '.join(missing)}")
    print(f"checkpoint {ckpt_path}; {time.perf_counter() - t0:.0f} s; wrote " + ", ".join(str(f) for f in files))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
