"""The paper's Table 3 at this machine's scale: six runs with one budget, scored on one test split.

    python headless/ablation.py [--input out/splits] [--out out/ablation] [--scenes 500] [--steps 500]
        [--runs white,spectral,polar,full,analytic,expanded] [--stage all|train|evaluate] [--quiet]

Trains the four input variants (uniform white illumination, + spectral multiplexing, +
polarization, + circular polarization) and the two pBRDF sources (analytic only, expanded tables
only) with the same model, steps, batch, learning rate and seed (network.ablation), then scores
each through the real-capture path on test-scenes (white: its twin test-scenes-white) next to the
constant predictor and photometric stereo, with 95 % bootstrap intervals. Writes OUT/ablation.md
(the table and the paper's trends, checked) and OUT/ablation.json. Training resumes: run the same
command again after a kill, finished runs are not retrained.

Needs, under --input: train-engine and val-engine's pBRDF library (`make train-data`),
train-engine-white (`python headless/render.py --split train-engine-white --count SCENES
--pbrdfs out/splits/pbrdfs-train`), test-scenes and test-scenes-white (`make ablation-data`
renders what is missing).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import model_override  # noqa: E402

RUN_NAMES = ("white", "spectral", "polar", "full", "analytic", "expanded")  # network.ablation.RUNS


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="ablation.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, default=Path("out/splits"), help="rendered splits (default out/splits)")
    parser.add_argument("--out", type=Path, default=Path("out/ablation"), help="output folder (default out/ablation)")
    parser.add_argument("--scenes", type=int, default=500, help="training scenes per run (default 500)")
    parser.add_argument("--steps", type=int, default=500, help="training steps per run (default 500)")
    parser.add_argument("--batch-size", type=int, default=4, help="samples per step (default 4)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every run (default 0)")
    parser.add_argument("--config", choices=["toy", "small", "paper"], default="small", help="model preset (small)")
    parser.add_argument("--overrides", nargs="+", type=model_override, default=[], metavar="KEY=VALUE",
                        help="ModelConfig fields replacing the ablation's (image_size=128 canonical_size=64 "
                        "train_pixels=1024 infer_chunk=4096)")  # fmt: skip
    parser.add_argument("--runs", default=",".join(RUN_NAMES), help=f"comma-separated subset of {','.join(RUN_NAMES)}")
    parser.add_argument("--stage", choices=["all", "train", "evaluate"], default="all", help="what to do (default all)")
    parser.add_argument("--limit", type=int, help="score only the first N test scenes")
    parser.add_argument("--jobs", type=int, default=1, help="evaluation processes (default 1)")
    parser.add_argument("--device", choices=["cpu", "cuda", "auto"], default="cpu", help="training device (cpu)")
    parser.add_argument("--train-stats", type=Path, help="training means for the constant row "
                        "(default OUT/train_stats.json, computed from train-engine once)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    args = build_parser().parse_args(argv)
    from network import ablation, constant  # noqa: PLC0415

    command = "python headless/ablation.py " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:])
    )
    try:
        cfg = ablation.AblationConfig(
            splits=args.input, out=args.out, scenes=args.scenes, steps=args.steps, batch_size=args.batch_size,
            seed=args.seed, config=args.config, overrides={**ablation.DEFAULT_OVERRIDES, **dict(args.overrides)},
            runs=tuple(r for r in args.runs.split(",") if r), limit=args.limit, jobs=args.jobs, device=args.device,
        )  # fmt: skip
        stats = None
        if args.stage != "train":
            path = args.train_stats or args.out / "train_stats.json"
            if not path.is_file():
                path.parent.mkdir(parents=True, exist_ok=True)
                constant.save_statistics(constant.train_statistics(args.input / "train-engine"), path)
            stats = constant.load_statistics(path)
        say = (lambda _m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
        ablation.run_ablation(cfg, stats=stats or {}, command=command, train=args.stage != "evaluate",
                              evaluate=args.stage != "train", progress=not args.quiet, log=say)  # fmt: skip
    except (ValueError, OSError, FloatingPointError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if args.stage != "train":
        print(f"wrote {args.out / 'ablation.md'} and {args.out / 'ablation.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
