"""Index the real-mesh training corpus: its usable, deduplicated meshes, cached in the folder's index.json.

    python headless/mesh_corpus.py [--input FOLDER] [--quiet]

FOLDER (default corpora/meshes, where `make setup` unpacks Debian's libcgal-demo and
openscad-testing-data meshes) is indexed by blender_addon.core.mesh_corpus: meshes that cannot
be read, have too few faces, repeat another's geometry or resemble a test split's are left out
(each named with the reason on stderr unless --quiet), and FOLDER/index.json caches the result,
so renders with --corpus-fraction start at once. A fresh index is reused. Prints how many meshes
are usable. A missing folder, or one without a usable mesh, prints one line "error: <message>"
on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402
from pbrdf.data.splits import MESH_CORPUS_DIR  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="mesh_corpus.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, default=MESH_CORPUS_DIR, metavar="FOLDER",
                        help=f"the corpus folder (default {MESH_CORPUS_DIR})")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="do not name the meshes left out")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on bad input)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, format="%(message)s")

    def work() -> int:
        from blender_addon.core.mesh_corpus import corpus_files  # noqa: PLC0415

        files = corpus_files(args.input)
        print(f"{args.input}: {len(files)} usable meshes")
        return 0

    return held_warnings(work)


if __name__ == "__main__":
    raise SystemExit(main())
