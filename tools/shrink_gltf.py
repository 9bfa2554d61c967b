"""Copy a glTF 2.0 model (.gltf with external files) with every image reduced to at most N pixels a side.

The project ships small copies of CC0 artist-made models (``examples/gltf/``) to render textured
scenes with; this is how they were made::

    python tools/shrink_gltf.py --input ../shared/assets/gltf-samples/Suzanne --out examples/gltf/Suzanne --size 256

The .gltf, its buffers and the licence files are copied as they are; each image the .gltf
references is resized (Lanczos, same mode and format) when larger than ``--size``. Images the
.gltf does not reference are left out.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

if not __package__:  # run as a file: the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from PIL import Image  # noqa: E402

from pbrdf.io.atomic import atomic_folder  # noqa: E402

KEEP = ("LICENSE.md", "README.md", "metadata.json")


def shrink(src: Path, out: Path, size: int) -> list[str]:
    """Write the reduced copy of the model folder ``src`` to ``out``; returns the files written."""
    (gltf_path,) = sorted(src.glob("*.gltf"))
    doc = json.loads(gltf_path.read_text())
    buffers = [b["uri"] for b in doc.get("buffers", []) if "uri" in b and not b["uri"].startswith("data:")]
    images = [i["uri"] for i in doc.get("images", []) if "uri" in i and not i["uri"].startswith("data:")]
    with atomic_folder(out) as tmp:
        for name in [gltf_path.name, *buffers, *(k for k in KEEP if (src / k).is_file())]:
            shutil.copyfile(src / name, tmp / name)
        for name in images:
            with Image.open(src / name) as im:
                im.load()
                if max(im.size) > size:
                    scale = size / max(im.size)
                    im = im.resize((max(1, round(im.width * scale)), max(1, round(im.height * scale))),
                                   Image.Resampling.LANCZOS)  # fmt: skip
                im.save(tmp / name, optimize=True)
        return sorted(p.name for p in tmp.iterdir())


def main(argv: list[str] | None = None) -> int:
    """Command line: --input, --out, --size; status 2 with one error line on bad input."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, required=True, help="model folder holding one .gltf")
    parser.add_argument("--out", type=Path, required=True, help="folder to write (replaced)")
    parser.add_argument("--size", type=int, default=256, help="largest image side in pixels (default 256)")
    args = parser.parse_args(argv)
    try:
        files = shrink(args.input, args.out, args.size)
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{args.out}: {len(files)} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
