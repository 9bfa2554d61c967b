"""Predict normal, albedo, roughness and metallic maps from a capture or a rendered sample.

    python headless/infer.py --input (capture folder | sample.exr | folder of capture folders) --out DIR
        [--checkpoint model.pt] [--resolution full|network] [--blend] [--quiet]

Without --checkpoint the shipped model (models/small/model.pt, see its MODEL_CARD.md) is used,
so a real capture folder gives maps without training anything. A capture folder is raw HDR
brackets plus capture.json (format in pbrdf/data/capture.py and examples/capture/); it is
merged, demosaiced and decoded exactly like the synthetic training data (network.infer).

Writes DIR/<name>_normal.exr, _albedo.exr, _roughness.exr, _metallic.exr, _mask.exr (float32,
full input size, zero outside the mask; normals in the camera frame: x right, y up, z toward
the camera), _depth.exr (metres along the viewing axis: the predicted normals integrated over
the mask, discontinuity-aware, median depth = capture.json's distance_m or 0.75 m; the Blender
import turns it into a relief mesh; --card leaves it out for a flat card), a PNG preview of
each, and _camera.json (the maps' intrinsics and distance, so the Blender camera matches the
capture's). With --blend, also DIR/<name>.blend: the maps imported into Blender as a
relightable Principled BSDF asset (headless/relight.py in its own process; needs the bpy wheel:
pip install bpy).

Maps are predicted at the input's own resolution (--resolution full: the encoder sees the object
resized to the network's input size, and the per-pixel decoder reads every pixel of the capture);
--resolution network decodes at the input size and upsamples (faster on large captures, blurrier).

Sequences: a folder whose sub-folders are capture folders (frames, in name order) gives
DIR/<name>_NNNN_<map>.exr per frame (NNNN from 0001; Blender reads each map as an image
sequence) and DIR/<name>_sequence.json (frames, their capture folders, and the frames per
second of decode + prediction). The model is loaded once; each frame's files are written whole.

Bad input (an unreadable checkpoint or sample, a capture with nothing usable: all dark, all
saturated, no object found) prints one line "error: <message>" on stderr, exits with status 2
and writes nothing: every map is predicted and checked before the first file is written.
Warnings raised on the way are dropped on an error and printed as "warning: ..." lines after
a successful run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
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
                        help="decode every s-th pixel, interpolate the rest where smooth (faster)")  # fmt: skip
    parser.add_argument("--resolution", choices=["full", "network"], default="full",
                        help="decode at the capture's resolution (default) or at the network's input size")  # fmt: skip
    parser.add_argument("--card", action="store_true", help="no depth map (the import makes a flat card)")
    parser.add_argument("--quiet", action="store_true", help="no progress output (the summary line still prints)")
    parser.add_argument("--progress-lines", action="store_true",
                        help="print 'progress: FRACTION STAGE' lines on stdout (for the Blender add-on)")  # fmt: skip
    return parser


def sequence_frames(path: Path) -> list[Path] | None:
    """The frames of a sequence folder (sub-folders that are capture folders, in name order), or None.

    A capture folder, a file or a folder without capture sub-folders is not a sequence (None);
    a sequence folder that also holds other sub-folders is refused on one line naming one.
    """
    from pbrdf.data.capture import CAPTURE_JSON  # noqa: PLC0415

    if not path.is_dir() or (path / CAPTURE_JSON).exists():
        return None
    subs = sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))
    frames = [p for p in subs if (p / CAPTURE_JSON).is_file()]
    if not frames:
        return None
    stray = [p for p in subs if p not in frames]
    if stray:
        raise ValueError(f"{path}: a sequence folder holds only capture folders; {stray[0].name} has no {CAPTURE_JSON}")
    return frames


def write_sequence_json(path: Path, name: str, frames: list[Path], seconds: list[float]) -> None:
    """``<name>_sequence.json``: the frames, their capture folders and the prediction speed."""
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    doc = {
        "name": name,
        "frames": [
            {"frame": i, "prefix": f"{name}_{i:04d}", "capture": str(f.resolve()), "seconds": round(t, 4)}
            for i, (f, t) in enumerate(zip(frames, seconds, strict=True), start=1)
        ],  # fmt: skip
        "frames_per_second": round(len(seconds) / sum(seconds), 4),
        "timed": "decode + prediction (+ depth integration) per frame, model loaded once",
    }
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")


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

    def progress(fraction: float, stage: str) -> None:
        if args.progress_lines:
            print(f"progress: {fraction:.3f} {stage}", flush=True)

    progress(0.0, "starting Python and torch")
    from tqdm import tqdm  # noqa: PLC0415

    from network.infer import (  # noqa: PLC0415
        DEFAULT_CHECKPOINT,
        camera_record,
        input_display_radiance,
        input_geometry,
        load_input,
        predict,
        relief_depth,
        write_predictions,
    )

    ckpt_path = args.checkpoint or DEFAULT_CHECKPOINT
    name = args.input.stem if args.input.is_file() else args.input.name

    def reconstruct(source: Path, start: float = 0.3, span: float = 0.65) -> tuple[dict, dict]:
        progress(start, "decoding the capture")
        maps, mask = load_input(source, require_object=True)
        progress(start + 0.05 * span, "predicting the maps")
        pred = predict(
            model, maps, mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
            radiance=input_display_radiance(source), stride=args.stride, resolution=args.resolution,
        )  # fmt: skip
        intrinsics, distance = input_geometry(source, mask.shape)
        if not args.card:
            progress(start + 0.6 * span, "integrating the relief")
            pred["depth"] = relief_depth(pred, intrinsics, distance)
        return pred, camera_record(intrinsics, mask.shape, distance)

    # Warnings are held back: on an error only the error line prints.
    with warnings.catch_warnings(record=True) as caught:
        try:
            frames = sequence_frames(args.input)
            if frames is not None and args.blend:
                raise ValueError(
                    "--blend saves one capture's asset; import a sequence with the add-on's Import PBR maps"
                )  # noqa: E501
            progress(0.25, "loading the model")
            model, ckpt = _load_model(ckpt_path)
            if frames is None:
                pred, camera = reconstruct(args.input)
                progress(0.95, "writing the maps")
                write_predictions(args.out, name, pred, camera)
            else:
                seconds = []
                for i, frame in enumerate(tqdm(frames, desc="frames", unit="frame", disable=args.quiet), start=1):
                    start = time.perf_counter()
                    try:
                        pred, camera = reconstruct(frame, 0.3 + 0.7 * (i - 1) / len(frames), 0.7 / len(frames))
                    except (ValueError, OSError) as exc:
                        raise ValueError(f"frame {i} ({frame.name}): {exc}") from None
                    seconds.append(time.perf_counter() - start)
                    write_predictions(args.out, f"{name}_{i:04d}", pred, camera)
                fps = len(seconds) / sum(seconds)
                write_sequence_json(args.out / f"{name}_sequence.json", name, frames, seconds)
        except (ValueError, OSError) as exc:
            print(f"error: {_one_line(exc)}", file=sys.stderr)
            return 2
    for message in dict.fromkeys(_one_line(w.message) for w in caught):
        print(f"warning: {message}", file=sys.stderr)
    if frames is not None:
        print(f"wrote {len(frames)} frames ({name}_NNNN_*.exr/.png, {name}_sequence.json) to {args.out.resolve()}; "
              f"{fps:.2f} frames/s (decode + prediction)")  # fmt: skip
        return 0
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
