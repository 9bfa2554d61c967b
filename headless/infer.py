"""Predict normal, albedo, roughness and metallic maps from a capture or a rendered sample.

    python headless/infer.py --input (capture folder | sample.exr) --out DIR [--checkpoint model.pt] [--blend] [--quiet]

Without --checkpoint the shipped model (models/small/model.pt, see its MODEL_CARD.md) is used,
so a real capture folder gives maps without training anything. A capture folder is raw HDR
brackets plus capture.json (format in pbrdf/data/capture.py and examples/capture/); it is
merged, demosaiced and decoded exactly like the synthetic training data (network.infer).

Writes DIR/<name>_normal.exr, _albedo.exr, _roughness.exr, _metallic.exr, _mask.exr (float32,
full input size, zero outside the mask; normals in the camera frame: x right, y up, z toward
the camera), _depth.exr (metres along the viewing axis: the predicted normals integrated over
the mask, discontinuity-aware, median depth = capture.json's distance_m or 0.75 m; the Blender
import turns it into a relief mesh; --card leaves it out for a flat card) and a PNG preview of
each. With --blend, also DIR/<name>.blend: the maps imported
into Blender as a relightable Principled BSDF asset (headless/relight.py in its own process;
needs the bpy wheel: pip install bpy).

Bad input (an unreadable checkpoint or sample, a capture with nothing usable: all dark, all
saturated, no object found) prints one line "error: <message>" on stderr, exits with status 2
and writes nothing: every map is predicted and checked before the first file is written.
Warnings raised on the way are dropped on an error and printed as "warning: ..." lines after
a successful run.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import warnings
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="infer.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, default=None, help="model.pt (default: the shipped model)")
    parser.add_argument("--input", type=Path, required=True, help="capture folder or sample .exr/.json")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--blend", action="store_true", help="also save a Blender scene with the relightable asset")
    parser.add_argument("--stride", type=int, default=1, choices=[1, 2, 4],
                        help="decode every s-th pixel, interpolate the rest (faster)")  # fmt: skip
    parser.add_argument("--card", action="store_true", help="no depth map (the import makes a flat card)")
    parser.add_argument("--quiet", action="store_true", help="no progress output (the summary line still prints)")
    return parser


def _one_line(e: BaseException | Warning | str, limit: int = 500) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _load_model(path: Path):
    """:func:`network.checkpoint.load_checkpoint`, with any failure of a non-checkpoint file as ValueError."""
    from network.checkpoint import load_checkpoint  # noqa: PLC0415

    try:
        return load_checkpoint(path)
    except (ValueError, OSError):
        raise
    except Exception as exc:  # torch.load on another file: UnpicklingError, EOFError, ...
        first = str(exc).strip().splitlines()[0].split(". ")[0] if str(exc).strip() else ""
        reason = f"{type(exc).__name__}: {first}" if first else type(exc).__name__
        raise ValueError(f"{path}: not a readable model checkpoint ({_one_line(reason, 200)})") from None


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    args = build_parser().parse_args(argv)
    from network.infer import (  # noqa: PLC0415
        DEFAULT_CHECKPOINT,
        input_display_radiance,
        input_geometry,
        load_input,
        predict,
        relief_depth,
        write_predictions,
    )

    ckpt_path = args.checkpoint or DEFAULT_CHECKPOINT
    # Warnings are held back: on an error only the error line prints.
    with warnings.catch_warnings(record=True) as caught:
        try:
            model, ckpt = _load_model(ckpt_path)
            maps, mask = load_input(args.input, require_object=True)
            pred = predict(
                model, maps, mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
                radiance=input_display_radiance(args.input), stride=args.stride,
            )  # fmt: skip
            if not args.card:
                pred["depth"] = relief_depth(pred, *input_geometry(args.input, mask.shape))
            name = args.input.stem if args.input.is_file() else args.input.name
            write_predictions(args.out, name, pred)
        except (ValueError, OSError) as exc:
            print(f"error: {_one_line(exc)}", file=sys.stderr)
            return 2
    for message in dict.fromkeys(_one_line(w.message) for w in caught):
        print(f"warning: {message}", file=sys.stderr)
    print(f"wrote {len(pred)} maps ({name}_*.exr/.png) to {args.out.resolve()}")
    if args.blend:
        script = Path(__file__).resolve().parent / "relight.py"
        cmd = [sys.executable, str(script), "--input", str(args.out), "--name", name, "--out", str(args.out),
               "--frames", "0", "--save-blend", *(["--quiet"] if args.quiet else [])]  # fmt: skip
        proc = subprocess.run(cmd, check=False)  # own process: bpy must not share one with torch/mitsuba
        if proc.returncode:
            print("error: the Blender scene could not be written (see above)", file=sys.stderr)
            return proc.returncode
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
