"""Train the feed-forward network on rendered samples.

    python headless/train.py --data DIR --config toy|small|paper --out DIR [--steps N] [--resume]

Writes OUT/checkpoint.pt (model, optimizer, step, RNG state; resumable), OUT/model.pt (state
dict plus config, what infer.py loads) and OUT/log.csv (loss per step and per term). --resume
continues a killed run exactly where its last checkpoint was.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="train.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, required=True, help="dataset folder from headless/render.py")
    parser.add_argument("--config", default="toy", choices=["toy", "small", "paper"], help="model size (default toy)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--steps", type=int, default=100, help="total steps (default 100)")
    parser.add_argument("--batch-size", type=int, default=1, help="samples per step (default 1)")
    parser.add_argument("--lr", type=float, default=8e-5, help="AdamW learning rate (default 8e-5)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument("--checkpoint-every", type=int, default=50, help="steps between checkpoints (default 50)")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    from network.train import TrainConfig, train  # noqa: PLC0415

    try:
        losses = train(
            TrainConfig(
                data=args.data, out=args.out, config=args.config, steps=args.steps, batch_size=args.batch_size,
                lr=args.lr, seed=args.seed, resume=args.resume, checkpoint_every=args.checkpoint_every,
            ),
            progress=not args.quiet,
        )  # fmt: skip
    except (ValueError, OSError, FloatingPointError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if losses:
        print(f"steps {len(losses)}, loss first {losses[0]:.4f}, last {losses[-1]:.4f}; model: {args.out / 'model.pt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
