"""Give the raw captures of a rendered dataset their dark frames (display off: ambient light, offset, noise).

    python headless/dark_frames.py --input DATASET_DIR [--overwrite] [--quiet]

DATASET_DIR is a dataset from headless/render.py whose samples kept their raw brackets
(--keep-raw, or a split that keeps them: the test splits, train-pseudo-real, test-pseudo-real).
For each sample's capture folder DATASET_DIR/samples/NNNNNN_raw the same bracket is simulated
with the display off, through the camera of the rig the scene was rendered with (a --rig-jitter
sample's drawn rig, with its room light), and written as the capture's dark_files, which the
decoder subtracts (pbrdf.data.dark_frames). The frames are a pure function of the sample's
seed. Resumable: a capture that has dark frames is skipped unless --overwrite is given. Prints
how many captures were written. A folder without raw captures, or a sidecar without the rendered
rig, prints one line "error: <message>" on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="dark_frames.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, required=True, metavar="DATASET_DIR",
                        help="rendered dataset with raw captures (written in place)")  # fmt: skip
    parser.add_argument("--overwrite", action="store_true", help="also replace dark frames a capture already has")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on bad input)."""
    args = build_parser().parse_args(argv)

    def work() -> int:
        from tqdm import tqdm  # noqa: PLC0415

        from pbrdf.data.dark_frames import add_dark_frames  # noqa: PLC0415

        with tqdm(desc="dark frames", unit="capture", disable=args.quiet) as bar:

            def progress(done: int, total: int) -> None:
                bar.total = total
                bar.update(done - bar.n)

            written = add_dark_frames(args.input, overwrite=args.overwrite, progress=progress)
        print(f"{args.input}: dark frames written for {written} captures")
        return 0

    return held_warnings(work)


if __name__ == "__main__":
    raise SystemExit(main())
