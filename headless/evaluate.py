"""Evaluate a model against ground truth, the photometric-stereo baseline and constant answers.

    python headless/evaluate.py --split test [--input out/splits] [--checkpoint models/small/model.pt] [--out DIR]
    python headless/evaluate.py --input DIR [--checkpoint M] [--out DIR] [--real CAPTURES] [--limit N] [--quiet]
    python headless/evaluate.py --write-train-stats FILE --input TRAIN_DIR

Both evaluations make one report (network/evaluation.py): on every scene the model (default: the
shipped one), calibrated photometric stereo and the constant predictor (normal facing the camera,
training means from --train-stats, default train_stats.json beside the checkpoint, else the
shipped model's) are scored on the object coverage of the ground truth (normal MAE, albedo PSNR /
si-PSNR / LPIPS, roughness and metallic RMSE, depth from the integrated normals), with per-scene
and pixel-weighted means and 95 % bootstrap intervals over scenes. Samples that keep their raw
brackets go through the real-capture path (raw brackets -> decode -> automatic foreground mask ->
model); others give their stored maps and mask.

--split test scores every test split found under --input (default out/splits; render them with
`make test-sets`), --split NAME one of them (only test splits are accepted), into test_splits.md
and test_splits.json (strict JSON) in --out (default INPUT/eval).
--input DIR alone scores any rendered dataset with ground truth (headless/render.py), e.g. a
user's own, into evaluation.md and evaluation.json in --out (default DIR/eval).
--real DIR adds the model's re-rendering error on real captures (real.md).
--refine adds the row "network + refinement" (network/refine.py: each object's albedo scale fitted
so that the re-rendered unpol matches the capture) and the paired per-scene differences.
--write-train-stats FILE computes the training means from the train split at --input.
--distance-error E [E ...] instead scores the model alone with each scene's distance (its median
true depth) scaled by 1 + e and 1 - e (network/distance_sensitivity.py), into
distance_sensitivity.md/.json: how a lighting-aware model's albedo degrades with a tape measure
off by e (a light-blind model's rows are equal by construction); with --refine the refined maps
are scored instead, the refinement fitting each albedo scale at the same wrong distance.
The input ablation (one model per input variant) is headless/ablation.py.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings, require  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="evaluate.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, help="model.pt/checkpoint.pt (default: the shipped model)")
    parser.add_argument("--split", metavar="NAME", help="'test' (every test split under --input) or one split name")
    parser.add_argument("--train-stats", type=Path, help="training means for the constant row")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes (default: 2, or 1 on a one-core machine)")  # fmt: skip
    parser.add_argument("--device", choices=["cpu", "cuda", "auto"], default="cpu",
                        help="the model's device (default cpu; every --jobs worker uses it)")  # fmt: skip
    parser.add_argument("--write-train-stats", type=Path, metavar="FILE", help="compute training means from --input")
    parser.add_argument("--input", type=Path, metavar="DIR",
                        help="rendered dataset with ground truth (with --split: the folder of the splits)")  # fmt: skip
    parser.add_argument("--real", type=Path, help="folder of real captures: re-rendering error")
    parser.add_argument("--out", type=Path, help="output folder (default INPUT/eval)")
    parser.add_argument("--limit", type=int, help="evaluate only the first N samples")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--distance-error", type=float, nargs="+", metavar="E",
                        help="score with the object distance off by +-E (e.g. 0.05 0.2) instead")  # fmt: skip
    parser.add_argument("--refine", action="store_true",
                        help="add the 'network + refinement' row (network/refine.py) with paired per-scene "
                             "differences and their 95 %% intervals")  # fmt: skip
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error, printed as one ``error:`` line)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    if args.write_train_stats is not None:
        require(parser, args, "--input")
        return held_warnings(lambda: _write_train_stats(args))
    if args.split is None:
        require(parser, args, "--input")
    return held_warnings(lambda: _evaluate(args))


def _write_train_stats(args: argparse.Namespace) -> int:
    from network.constant import save_statistics, train_statistics  # noqa: PLC0415

    stats = train_statistics(args.input, limit=args.limit)
    path = save_statistics(stats, args.write_train_stats)
    print(f"{stats['samples']} samples, {stats['pixels']} pixels: albedo {stats['albedo']}, "
          f"roughness {stats['roughness']:.3f}, metallic {stats['metallic']:.3f}\nwrote {path}")  # fmt: skip
    return 0


def _split_folders(root: Path, split: str) -> tuple[list[Path], list[str]]:
    """The rendered test-split folders under ``root`` for ``--split`` and the names not rendered.

    Raises:
        FileNotFoundError: none of them is rendered.
        ValueError: an unknown split name, or a folder that is not a test split.
    """
    from pbrdf.data.splits import get_split, require_role, test_splits  # noqa: PLC0415

    names = [s.name for s in test_splits()] if split == "test" else [get_split(split).name]
    folders = [root / n for n in names if (root / n).is_dir()]
    if not folders:
        raise FileNotFoundError(
            f"{root}: no test split folders ({', '.join(names)}); render them with `make test-sets`"
        )
    for f in folders:
        require_role(f, ("test",), "the final evaluation")
    return folders, [n for n in names if not (root / n).is_dir()]


def _evaluate(args: argparse.Namespace) -> int:
    """``--split`` or ``--input DIR``: one report per dataset, the model's row named by its checkpoint."""
    import time  # noqa: PLC0415

    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.constant import STATS_FILE, load_statistics  # noqa: PLC0415
    from network.distributed import resolve_device  # noqa: PLC0415
    from network.evaluation import evaluate_dataset, results_markdown, write_results  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415

    t0 = time.perf_counter()
    device = resolve_device(args.device)  # first: a missing GPU is the one error worth reporting
    for flag, value in (("--limit", args.limit), ("--jobs", args.jobs)):
        if value is not None and value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    if args.split is not None:
        root = args.input or Path("out/splits")
        folders, missing = _split_folders(root, args.split)
    else:
        root, missing = args.input, []
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: dataset folder not found")
        folders = [root]
    ckpt_path = args.checkpoint or Path(DEFAULT_CHECKPOINT)
    model, ckpt = load_checkpoint(ckpt_path)
    beside = ckpt_path.parent / STATS_FILE  # else the shipped model's, as the demo does
    stats = load_statistics(
        args.train_stats or (beside if beside.is_file() else DEFAULT_CHECKPOINT.parent / STATS_FILE)
    )
    model.to(device)
    if args.distance_error:
        return _sensitivity(model, ckpt, stats, folders, args, root)
    results = [
        evaluate_dataset(model, ckpt, f, stats, limit=args.limit, progress=not args.quiet, jobs=args.jobs,
                         checkpoint_path=ckpt_path, refine=args.refine)
        for f in folders
    ]  # fmt: skip
    out = args.out or root / "eval"
    files = write_results(results, out, "test_splits" if args.split is not None else "evaluation")
    for r in results:
        print(results_markdown(r))
    if args.real is not None:
        files.append(_real(model, ckpt, args, out, results[0]["model"]))
    if missing:
        print(f"not rendered (skipped): {', '.join(missing)}")
    print(f"checkpoint {ckpt_path}; {time.perf_counter() - t0:.0f} s; wrote " + ", ".join(str(f) for f in files))
    return 0


def _sensitivity(model, ckpt: dict, stats, folders: list[Path], args: argparse.Namespace, root: Path) -> int:
    """``--distance-error``: :func:`network.distance_sensitivity.distance_sensitivity` per folder."""
    from network.distance_sensitivity import distance_sensitivity, sensitivity_markdown  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415
    from pbrdf.io.strict_json import dumps_strict  # noqa: PLC0415

    errors = sorted({s * e for e in args.distance_error for s in (1, -1)})
    results = [distance_sensitivity(model, ckpt, f, stats, errors, limit=args.limit, refine=args.refine)
               for f in folders]  # fmt: skip
    out = args.out or root / "eval"
    out.mkdir(parents=True, exist_ok=True)
    md = "\n".join(sensitivity_markdown(r) for r in results)
    atomic_write_text(out / "distance_sensitivity.json", dumps_strict({"results": results}) + "\n")
    atomic_write_text(out / "distance_sensitivity.md", md)
    print(md + f"wrote {out / 'distance_sensitivity.md'}")
    return 0


def _real(model, ckpt: dict, args: argparse.Namespace, out: Path, label: str) -> Path:
    """``--real``: print the model's re-rendering error on the real captures and write ``OUT/real.md``."""
    from network.rerender_error import rerender_error, rerender_markdown  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    text = rerender_markdown(rerender_error(model.cpu(), ckpt["inputs"], args.real, limit=args.limit), label)
    print(text)
    return atomic_write_text(out / "real.md", text)


if __name__ == "__main__":
    raise SystemExit(main())
