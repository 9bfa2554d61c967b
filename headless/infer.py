"""Predict normal, albedo, roughness and metallic maps from a capture or a rendered sample.

    python headless/infer.py --checkpoint runs/toy/model.pt --input (sample.exr | capture folder) --out DIR

Writes DIR/<name>_normal.exr, _albedo.exr, _roughness.exr, _metallic.exr, _mask.exr (float32,
full input size, zero outside the mask) and PNG previews of each (normals mapped from [-1, 1]
to [0, 1]). A capture folder is raw HDR brackets plus capture.json (see pbrdf/capture.py); it
is decoded exactly like the synthetic training data.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _png(img) -> bytes:
    import numpy as np  # noqa: PLC0415
    from PIL import Image  # noqa: PLC0415

    a = np.clip(img, 0, 1)
    a = (a[..., 0] if a.shape[-1] == 1 else a) * 255
    buf = io.BytesIO()
    Image.fromarray(np.rint(a).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="infer.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, required=True, help="model.pt written by headless/train.py")
    parser.add_argument("--input", type=Path, required=True, help="sample .exr/.json or a capture folder")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    args = parser.parse_args(argv)
    from network.infer import load_input, predict  # noqa: PLC0415
    from network.train import load_checkpoint  # noqa: PLC0415
    from pbrdf.atomic import atomic_write_bytes  # noqa: PLC0415
    from pbrdf.exr import write_exr  # noqa: PLC0415

    try:
        model, _ = load_checkpoint(args.checkpoint)
        maps, mask = load_input(args.input)
        pred = predict(model, maps, mask)
        name = args.input.stem if args.input.is_file() else args.input.name
        args.out.mkdir(parents=True, exist_ok=True)
        for key, img in pred.items():
            chans = "XYZ" if key == "normal" else ("RGB" if img.shape[-1] == 3 else "Y")
            write_exr(args.out / f"{name}_{key}.exr", {f"{key}.{c}": img[..., i] for i, c in enumerate(chans)})
            preview = img * 0.5 + 0.5 if key == "normal" else img
            atomic_write_bytes(args.out / f"{name}_{key}.png", _png(preview * mask[..., None]))
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(pred)} maps to {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
