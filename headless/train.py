"""Train the feed-forward network on rendered samples (and real captures).

    python headless/train.py --input DIR [--real DIR] --config toy|small|medium|paper --out DIR [--steps N] [--resume]

Writes OUT/checkpoint.pt (model, optimizer, step, per-rank RNG states; resumable), OUT/model.pt
(state dict, config and input variant: what infer.py loads), OUT/log.csv (one row per step:
losses, learning rate, real-loss weight, gradient norm), OUT/val.csv (with --val) and
TensorBoard events in OUT/tb (when tensorboard is installed). --resume continues a killed run
exactly where its last checkpoint was (network.train); at the final step it rewrites a missing or
stale model.pt from the checkpoint. Every run removes the temporary files (.NAME.tmp-PID-HEX) a
killed run left beside these files. --input and --val may be packs (headless/pack.py: memory-mapped
shards, recognised by their index.json); --workers N loads batches in N processes without changing them.
--time-budget SECONDS ends the chunk by the clock (validated and saved); --rewarm-from STEP --rewarm-steps N
ramps the learning rate again after a resume with a fresh optimizer (network.chunk_state, tools/gpu_chunk.sh).

Several GPUs or machines: launch the same command with torchrun, e.g.

    torchrun --standalone --nproc_per_node 4 headless/train.py --input DIR --config paper --out DIR

(--batch-size is per process; gloo on CPUs, nccl on GPUs; only rank 0 writes files).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import flag_wording, model_override, require  # noqa: E402

INPUTS = ("white", "spectral", "polar", "full")  # network.inputs.INPUT_VARIANTS (not imported: --help stays fast)
SCALES = ("calibrated", "exposure-invariant")  # network.data.INPUT_SCALES


#: The TrainConfig fields that network.train's errors name (``max_skipped=3``), all flags here.
FLAGGED = ("resume", "max_skipped", "config", "overrides", "inputs", "input_scale", "init_from", "time_budget",
           "rewarm_from", "rewarm_steps")  # fmt: skip


class _Parser(argparse.ArgumentParser):
    """Bad arguments give one line on stderr (``error: ...``) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = _Parser(prog="train.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--input",
        type=Path,
        metavar="DIR",
        help="dataset folder (headless/render.py) or its pack (headless/pack.py); required",
    )
    parser.add_argument("--also", type=Path, action="append", default=[], metavar="DIR",
                        help="another training dataset (or pack) whose samples join --input's (repeatable; e.g. the "
                        "data a fine-tuned model was trained on, replayed beside the new data)")  # fmt: skip
    parser.add_argument("--real", type=Path, help="folder of real captures (capture folders and/or samples)")
    parser.add_argument("--val", type=Path, help="held-out dataset (or pack): normal MAE every --val-every steps")
    parser.add_argument(
        "--config", default="toy", choices=["toy", "small", "medium", "paper"], help="model size (default toy)"
    )
    parser.add_argument(
        "--overrides", nargs="+", type=model_override, default=[], metavar="KEY=VALUE",
        help="ModelConfig fields to replace, e.g. image_size=128 train_pixels=1024 (JSON values)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--steps", type=int, default=100, help="total steps (default 100)")
    parser.add_argument("--indices", type=Path, metavar="FILE",
                        help="JSON list of the sample indices of --input to train on (default: all)")  # fmt: skip
    parser.add_argument("--stop-after", type=int, default=None, metavar="N",
                        help="end this chunk after step N (with a checkpoint); schedules still span --steps, "
                        "so a later --resume continues the same run")  # fmt: skip
    parser.add_argument(
        "--time-budget",
        type=float,
        default=None,
        metavar="SECONDS",
        help="end this chunk after SECONDS of training, validated and saved (a GPU lease's minutes)",
    )
    parser.add_argument(
        "--rewarm-from",
        type=int,
        default=0,
        metavar="STEP",
        help="re-warm the learning rate linearly from STEP (a chunk resumed with a fresh optimizer)",
    )
    parser.add_argument("--rewarm-steps", type=int, default=0, metavar="N",
                        help="steps of that re-warm (default 0: none)")  # fmt: skip
    parser.add_argument("--batch-size", type=int, default=1, help="samples per step and process (default 1)")
    parser.add_argument("--lr", type=float, default=8e-5, help="AdamW peak learning rate (default 8e-5)")
    parser.add_argument("--weight-decay", type=float, default=0.05, help="AdamW weight decay (default 0.05)")
    parser.add_argument("--lr-warmup", type=int, default=0, help="linear learning-rate warm-up steps (default 0)")
    parser.add_argument("--lr-decay-steps", type=int, help="cosine decay horizon (default --steps)")
    parser.add_argument("--min-lr-ratio", type=float, default=0.1, help="final lr / peak lr (default 0.1)")
    parser.add_argument("--clip", type=float, default=1.0, help="gradient-norm clipping (default 1.0)")
    parser.add_argument("--real-weight", type=float, default=0.1, help="real-loss weight after warm-up (default 0.1)")
    parser.add_argument("--real-start", type=int, default=0, help="step where the real-loss ramp starts (default 0)")
    parser.add_argument("--real-warmup", type=int, default=0, help="steps of the linear real-weight ramp (default 0)")
    parser.add_argument("--inputs", default="full", choices=INPUTS, help="input variant (Table 3; default full)")
    parser.add_argument("--input-scale", default="calibrated", choices=SCALES,
                        help="calibrated (default): absolute brightness, maps / display radiance (albedo absolute); "
                        "exposure-invariant: per-image level (for uncalibrated captures)")  # fmt: skip
    parser.add_argument("--bf16", action="store_true", help="bf16 autocast for the forward pass (for GPUs)")
    parser.add_argument("--device", default="auto", choices=["cpu", "cuda", "auto"], help="device (default auto)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument("--checkpoint-every", type=int, default=50, help="steps between checkpoints (default 50)")
    parser.add_argument("--val-every", type=int, default=0, help="steps between validations (default: checkpoints)")
    parser.add_argument("--val-samples", type=int, default=8, help="validation samples (default 8)")
    parser.add_argument("--max-skipped", type=int, default=10, help="non-finite steps tolerated (default 10)")
    parser.add_argument("--workers", type=int, default=0, help="data-loading processes per loader (default 0: the "
                        "main process; the batches do not depend on it)")  # fmt: skip
    parser.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard events")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    parser.add_argument("--init-from", type=Path, metavar="CKPT",
                        help="start from this model.pt's weights (fine-tuning; with --overrides light_input=true the "
                        "light input's new weights start at zero, so step 0 is exactly CKPT's model)")  # fmt: skip
    parser.add_argument("--distill-from", type=Path, metavar="CKPT",
                        help="a frozen teacher model.pt (same input variant and scale) whose --distill-keys maps the "
                        "model is also pulled towards at every training pixel: fine-tuning without forgetting what "
                        "the teacher did well (network/distill.py)")  # fmt: skip
    parser.add_argument("--distill-weight", type=float, default=0.0, metavar="W",
                        help="weight of that term (default 0: off, no teacher pass)")  # fmt: skip
    parser.add_argument("--distill-keys", nargs="+", default=["metallic"], metavar="MAP",
                        choices=["normal", "albedo", "roughness", "metallic"],
                        help="maps distilled (default: metallic)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _read_indices(path: Path | None) -> list[int] | None:
    """The ``--indices`` file: a JSON list of sample indices (ValueError naming the file otherwise)."""
    if path is None:
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"--indices {path}: unreadable ({exc})") from None
    if not isinstance(data, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in data):
        raise ValueError(f"--indices {path}: expected a JSON list of integers")
    return data


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    require(parser, args, "--input")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    from network.train import TrainConfig, train  # noqa: PLC0415

    try:
        cfg = TrainConfig(
            data=args.input, also=tuple(args.also), indices=_read_indices(args.indices), out=args.out,
            config=args.config, steps=args.steps,
            stop_after=args.stop_after, batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
            warmup_steps=args.lr_warmup, decay_steps=args.lr_decay_steps,
            min_lr_ratio=args.min_lr_ratio, clip=args.clip, seed=args.seed, resume=args.resume,
            checkpoint_every=args.checkpoint_every, overrides=dict(args.overrides), real=args.real,
            real_weight=args.real_weight, real_start=args.real_start, real_warmup=args.real_warmup,
            inputs=args.inputs, input_scale=args.input_scale, bf16=args.bf16, device=args.device, val=args.val,
            val_every=args.val_every, val_samples=args.val_samples, max_skipped=args.max_skipped, workers=args.workers,
            tensorboard=not args.no_tensorboard, init_from=args.init_from, time_budget=args.time_budget,
            distill_from=args.distill_from, distill_weight=args.distill_weight, distill_keys=tuple(args.distill_keys),
            rewarm_from=args.rewarm_from, rewarm_steps=args.rewarm_steps,
        )  # fmt: skip
        losses = train(cfg, progress=not args.quiet)
    except (ValueError, OSError, FloatingPointError) as exc:
        print(f"error: {flag_wording(str(exc), FLAGGED)}", file=sys.stderr)
        return 2
    if losses and os.environ.get("RANK", "0") == "0":
        print(f"steps {len(losses)}, loss first {losses[0]:.4f}, last {losses[-1]:.4f}; model: {args.out / 'model.pt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
