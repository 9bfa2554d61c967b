"""Pack a rendered split into memory-mapped shards for fast training (network.packed).

    python headless/pack.py --input SPLIT_DIR --out PACK_DIR [--shard-samples 64] [--size PX]
                            [--dtype float16|float32] [--resume] [--quiet]

Reads every completed sample of SPLIT_DIR once (each checked as training checks it) and writes
PACK_DIR/shard-NNNNN.bin (--shard-samples samples each; maps and targets in --dtype, float16 by
default, the mask as uint8), PACK_DIR/index.json (the layout, and a sha256 per completed shard)
and PACK_DIR/manifest.json (the source split's name, so training refuses a packed test split as
it refuses the split). --size resizes every sample first, as training at that size does, so the
loader does not resize again. headless/train.py --input PACK_DIR trains on it (--workers N loader
processes); every shard is hashed when the pack is opened. A killed pack continues with --resume:
whole shards are kept, a killed writer's temporaries removed, and the samples not yet packed
(also samples rendered since) go into new shards.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import flag_wording, held_warnings  # noqa: E402

#: The pack_split parameters that are flags of this script (named in its errors).
FLAGGED = ("resume", "shard_samples", "size", "dtype")


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="pack.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, required=True, metavar="SPLIT_DIR",
                        help="dataset folder from headless/render.py")  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, metavar="PACK_DIR", help="pack folder")
    parser.add_argument("--shard-samples", type=int, default=64, metavar="N", help="samples per shard (default 64)")
    parser.add_argument("--size", type=int, metavar="PX", help="resize every sample to PX x PX (default: as rendered)")
    parser.add_argument("--dtype", default="float16", choices=("float16", "float32"),
                        help="maps and targets (default float16; float32 is exact)")  # fmt: skip
    parser.add_argument("--resume", action="store_true", help="continue a pack in --out")
    parser.add_argument("--quiet", action="store_true", help="no progress line per shard")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on bad input)."""
    args = build_parser().parse_args(argv)

    def work() -> int:
        from network.packed import pack_split  # noqa: PLC0415

        def progress(done: int, total: int) -> None:
            print(f"packed {done}/{total} samples", file=sys.stderr, flush=True)

        try:
            report = pack_split(
                args.input, args.out, shard_samples=args.shard_samples, size=args.size, dtype=args.dtype,
                resume=args.resume, progress=None if args.quiet else progress,
            )  # fmt: skip
        except (ValueError, FileExistsError) as exc:
            raise type(exc)(flag_wording(str(exc), FLAGGED)) from None
        print(f"{report['samples']} samples in {report['shards']} shards ({report['samples_written']} written now): "
              f"{args.out / 'index.json'}")  # fmt: skip
        return 0

    return held_warnings(work)


if __name__ == "__main__":
    raise SystemExit(main())
