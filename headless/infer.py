"""Predict normal, albedo, roughness and metallic maps from a capture or a rendered sample.

    python headless/infer.py --input (capture folder | sample.exr | folder of capture folders) --out DIR
        [--checkpoint model.pt] [--resolution full|network] [--distance M] [--refine | --no-refine] [--blend]
        [--gltf] [--quiet]

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
pip install bpy). With --gltf, also DIR/<name>.glb (a sequence: DIR/<name>_NNNN.glb per frame):
one glTF 2.0 binary that Blender, Unreal, Unity, three.js and Substance open, holding the relief
mesh (a flat card with --card) with UVs, a base-colour texture (sRGB albedo, the mask as alpha,
cut at 0.5), a metallic-roughness texture (roughness in G, metallic in B), a tangent-space normal
map baked from the predicted normals against the file's own vertex tangents, and the capture
camera (pbrdf/data/gltf_asset.py says how an off-centre principal point is kept).

Maps are predicted at the input's own resolution (--resolution full: the encoder sees the object
resized to the network's input size, and the per-pixel decoder reads every pixel of the capture);
--resolution network decodes at the input size and upsamples (faster on large captures, blurrier).
--stride auto (the default) decodes every 4th pixel of a capture-sized object (150,000 masked
pixels or more) and interpolates the rest where it is smooth, decoding edges exactly.

Cost: a full sensor frame (2448 x 2048 raw, object on half of it) takes about 10 s and 1.2 GB on an
idle 2-core machine (maps and depth; --gltf +3 s; --blend about 11-13 s in all, Blender starting
while the maps are predicted; 2026-11-27, docs/measurements/fullframe.md); the refinement (the default
where a distance is known) adds about 0.5 CPU s to it, 1-3 s wall on a loaded machine (2026-11-28,
docs/measurements/refine.md). Every step prints
"[elapsed s] stage" on stderr unless --quiet.

The test-time refinement (network/refine.py) checks the prediction against the capture: the maps
are re-rendered under the display at the object's distance and each object's albedo scale is
fitted so that the re-rendered unpol matches the decoded one. It is on by default where it can
work: a capture with calibrated radiometry AND a known distance (--distance, else capture.json's
distance_m); otherwise it is skipped with one line saying why ("<name>: no refinement (...)",
stdout, not --quiet). --refine forces it (without a distance at an assumed 0.75 m, with a warning),
--no-refine turns it off. Where the fit cannot be trusted (metal, too few lit pixels, no lower
re-rendering error, an LP the re-renderer's material cannot explain, as on measured pBRDFs) it
keeps the network's maps and says why; a trusted scale is applied half-way in log (a prior on the
network's albedo). With the guard it is better than the network alone on every test split's
per-scene mean (+0.2 to +2.4 dB albedo PSNR, true distance): docs/measurements/refine.md.

Sequences: a folder whose sub-folders are capture folders (frames, in name order) gives
DIR/<name>_NNNN_<map>.exr per frame (NNNN from 0001; Blender reads each map as an image
sequence) and DIR/<name>_sequence.json (frames, their capture folders, and the frames per
second of decode + prediction). The model is loaded once; each frame's files are written whole.

Bad input (an unreadable checkpoint or sample, a capture with nothing usable: all dark, all
saturated, no object found; raws larger than the sensor; sequence frames whose exposures or raw
sizes differ) prints one line "error: <message>" on stderr (after the stage lines that came
before it, unless --quiet), exits with status 2 and writes nothing: every map is predicted and
checked before the first file is written, and a sequence's frames are checked before the first.
Warnings raised on the way are dropped on an error and printed as "warning: ..." lines after
a successful run.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import sys
import time
from concurrent.futures import Future
from pathlib import Path
from typing import NamedTuple

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402
from headless._overlap import decode_while_loading, relief_later  # noqa: E402
from pbrdf.data.capture import CAPTURE_JSON  # noqa: E402
from pbrdf.data.predictions import (  # noqa: E402
    SEQUENCE_SUFFIX,
    CameraRecord,
    SequenceRecord,
    write_predictions,
    write_sequence,
)
from pbrdf.io.errors import one_line  # noqa: E402

_REFINE_HELP = (
    "test-time refinement (network/refine.py): fit each object's albedo scale so that the maps re-rendered "
    "under the display match the capture; about 1 s per capture on 2 CPU cores. Default: on where a distance is "
    "known (--distance or capture.json's distance_m) and the radiometry is calibrated, else skipped with a line "
    "saying why; --refine forces it (no distance: 0.75 m, with a warning), --no-refine turns it off"
)


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="infer.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, default=None, help="model.pt (default: the shipped model)")
    parser.add_argument("--input", type=Path, required=True, help="capture folder or sample .exr/.json")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--blend", action="store_true", help="also save a Blender scene with the relightable asset")
    parser.add_argument("--stride", default="auto", choices=["auto", "1", "2", "4"],
                        help="decode every s-th pixel, interpolate the rest where smooth (faster); auto: 4 for "
                        "capture-sized objects, else 1 (network.model.dense.auto_stride)")  # fmt: skip
    parser.add_argument("--resolution", choices=["full", "network"], default="full",
                        help="decode at the capture's resolution (default) or at the network's input size")  # fmt: skip
    parser.add_argument("--gltf", action="store_true",
                        help="also write <name>.glb (a sequence: one per frame), the asset for any engine")  # fmt: skip
    parser.add_argument("--card", action="store_true", help="no depth map (the import makes a flat card)")
    parser.add_argument("--distance", type=float, metavar="M",
                        help="object distance in metres along the viewing axis (a tape measure; overrides "
                        "capture.json's distance_m; 0.2-3 m). A light-input model needs one: without it 0.75 m is "
                        "assumed and albedo is relative; the distance used goes to <name>_light.json")  # fmt: skip
    parser.add_argument("--rig", type=Path, metavar="RIG_JSON",
                        help="decode the capture with a calibrated rig (headless/calibrate.py's rig.json: optics and "
                        "geometry; bracket, sensor: capture.json's); record dark_files for ambient light")  # fmt: skip
    parser.add_argument("--refine", action=argparse.BooleanOptionalAction, default=None, help=_REFINE_HELP)
    parser.add_argument("--quiet", action="store_true", help="no progress output (the summary line still prints)")
    parser.add_argument("--progress-lines", action="store_true",
                        help="print 'progress: FRACTION STAGE' lines on stdout (for the Blender add-on)")  # fmt: skip
    return parser


def sequence_frames(path: Path) -> list[Path] | None:
    """The frames of a sequence folder (sub-folders that are capture folders, in name order), or None.

    A capture folder, a file or a folder without capture sub-folders is not a sequence (None);
    a sequence folder that also holds other sub-folders is refused on one line naming one.
    """
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
        raise ValueError(f"{path}: not a readable model checkpoint ({one_line(reason, 200)})") from None


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    args = build_parser().parse_args(argv)

    started = time.perf_counter()

    def progress(fraction: float, stage: str) -> None:
        if args.progress_lines:
            print(f"progress: {fraction:.3f} {stage}", flush=True)
        elif not args.quiet:  # a stage line with the elapsed time (tqdm.write keeps a sequence's bar intact)
            from tqdm import tqdm  # noqa: PLC0415

            tqdm.write(f"[{time.perf_counter() - started:6.1f} s] {stage}", file=sys.stderr)

    progress(0.0, "starting Python and torch")
    summary: list[str] = []
    blend = _start_blend(args) if args.blend else None  # Blender starts while the maps are predicted
    try:
        code = held_warnings(lambda: _infer(args, progress, summary))
    finally:
        if blend is not None and not summary:  # an error, returned or raised: no .blend
            blend.cancel()
    if code:
        return code
    print("\n".join(summary))  # the refinement's lines (not --quiet), then the summary line
    if blend is None:
        return 0
    progress(0.97, "saving the .blend (Blender in its own process)")
    code = blend.finish()
    if code:
        print("error: the Blender scene could not be written (see above)", file=sys.stderr)
    return code


class RefineNote(NamedTuple):
    """What the test-time refinement did to one input, for the line(s) printed after a run (not ``--quiet``)."""

    text: str  # "no refinement (why)", or the fit's message
    seconds: float | None  # the refinement's time; None: skipped
    refined: bool  # the maps changed
    warned: bool  # a warning already says it (forced --refine that kept the maps)


def auto_refine_skip(distance_m: float | None, radiance: float | None) -> str | None:
    """Why the default (neither ``--refine`` nor ``--no-refine``) skips the refinement; None: it refines.

    The fit is of an absolute albedo scale, so it needs the display radiance in the maps' units (a calibrated
    capture) and the light at the object, i.e. its distance: at an assumed 0.75 m the display's irradiance is off
    by about 1.5x for an object at 0.5 or 1.0 m (on axis, :mod:`pbrdf.sensor.irradiance`), 2.1x at 0.35 m.

    Args:
        distance_m: the measured distance (``--distance``, else capture.json's ``distance_m``), or None.
        radiance: :attr:`network.infer.InferenceInput.radiance` (None: relative radiometry).

    Returns:
        None, or the reason in a few words with how to turn it on.

    Example:
        >>> auto_refine_skip(0.8, 1.0) is None, auto_refine_skip(None, 1.0)
        (True, 'no distance_m; --distance M refines the albedo scale')
    """
    if radiance is None or not radiance > 0:
        return "relative radiometry: the albedo scale fit needs a calibrated capture"
    if not distance_m:
        return "no distance_m; --distance M refines the albedo scale"
    return None


def _refine(pred: dict, inp, distance: float | None, flag: bool | None, announce) -> tuple[dict, RefineNote | None]:
    """The maps after the refinement ``--refine`` / ``--no-refine`` / the default (auto) asks for, and its note.

    ``announce()`` is called (the progress line) when the refinement runs.
    """
    if flag is False:
        return pred, None
    why = auto_refine_skip(distance, inp.radiance) if flag is None else None
    if why is not None:
        return pred, RefineNote(f"no refinement ({why})", None, False, False)
    from dataclasses import replace  # noqa: PLC0415

    from network.refine import refine_input  # noqa: PLC0415

    announce()
    # forced: refine_input warns (the 0.75 m guess, a kept fit); auto: a kept fit is a normal outcome, said plainly
    res = refine_input(pred, replace(inp, distance_m=distance), warn=flag is True)  # --distance, else capture.json's
    text = f"{res.message} in {res.seconds:.1f} s" if res.refined else f"{res.message}; the network's maps are kept"
    return res.pred, RefineNote(text, res.seconds, res.refined, flag is True and not res.refined)


def _sequence_notes(name: str, notes: list[RefineNote], frames: int) -> list[str]:
    """A sequence's refinement in a line or two (not one per frame): each reason for skipping, then what ran."""
    lines = []
    skipped = [n.text for n in notes if n.seconds is None]
    for text in dict.fromkeys(skipped):
        count = skipped.count(text)
        lines.append(f"{name}: {text}" + ("" if count == frames else f" in {count} of {frames} frames"))
    ran = [n for n in notes if n.seconds is not None]
    if ran:
        median = statistics.median(n.seconds for n in ran)
        lines.append(f"{name}: refinement on {len(ran)} of {frames} frames, the albedo refined on "
                     f"{sum(n.refined for n in ran)} ({median:.1f} s median per frame)")  # fmt: skip
    return lines


def _reconstruct(model, ckpt: dict, source: Path, args: argparse.Namespace, progress, start: float = 0.3,
                 span: float = 0.65, inp=None, notes: list[RefineNote] | None = None,
                 ) -> tuple[dict, CameraRecord, dict | None, Future | None]:  # fmt: skip
    """The maps, the camera, a light model's distance record and the relief depth integrating (None with ``--card``).

    ``inp``: the decoded input (:func:`headless._overlap.decode_while_loading`), else it is read here.
    ``notes``: the refinement's :class:`RefineNote` is appended here.
    """
    from network.infer import auto_refine_deg, load_input, predict  # noqa: PLC0415
    from network.model.dense import REFINE_DEG, auto_stride  # noqa: PLC0415
    from pbrdf.data.capture_rig import read_rig  # noqa: PLC0415

    if inp is None:
        progress(start, "decoding the capture")
        inp = load_input(source, require_object=True, rig=None if args.rig is None else read_rig(args.rig))
    distance, light = _light(model, inp, args.distance, source)
    stride = auto_stride(int(inp.mask.sum())) if args.stride == "auto" else int(args.stride)
    refine = auto_refine_deg(int(inp.mask.sum())) if args.stride == "auto" else REFINE_DEG
    progress(start + 0.05 * span, f"predicting the maps ({int(inp.mask.sum())} pixels, stride {stride})")
    pred = predict(
        model, inp.maps, inp.mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
        radiance=inp.radiance, stride=stride, resolution=args.resolution, light=light, refine_deg=refine,
    )  # fmt: skip
    announce = functools.partial(progress, start + 0.5 * span, "refining against the capture")
    pred, note = _refine(pred, inp, distance, args.refine, announce)
    if note is not None and notes is not None:
        notes.append(note)
    relief = None
    if not args.card:  # on its own thread, while the maps are written (headless._overlap)
        progress(start + 0.6 * span, "integrating the relief")
        relief = relief_later(pred, inp.intrinsics, distance)
    record = None if light is None else light.to_dict()
    return pred, CameraRecord.of_maps(inp.intrinsics, inp.mask.shape, distance), record, relief


def _light(model, inp, flag: float | None, source: Path):
    """The measured distance (``--distance``, else capture.json's, else None) and a light model's LightGeometry."""
    from network.light_input import LightGeometry, check_distance  # noqa: PLC0415

    distance = inp.distance_m if flag is None else check_distance(flag, "--distance")
    if not model.config.light_input:
        return distance, None
    origin = "--distance" if flag is not None else CAPTURE_JSON
    return distance, LightGeometry.resolve(inp.rig, inp.intrinsics, distance, origin, str(source))


def _write(args: argparse.Namespace, prefix: str, pred: dict, camera: CameraRecord, light: dict | None,
           relief: Future | None) -> int:  # fmt: skip
    """The maps and camera, the relief depth as it is ready, ``--gltf``'s binary and a light model's record.

    Returns the number of maps written. Everything is checked before the first file is written.
    """
    if args.gltf and relief is not None:  # the asset needs the depth before any file is written
        pred, relief = dict(pred, depth=relief.result()["depth"]), None
    asset = _gltf_asset(args, pred, camera)
    out = args.out
    write_predictions(out, prefix, pred, camera, pending=relief)
    _write_gltf(args, prefix, asset)
    if light is not None:
        import json  # noqa: PLC0415

        from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

        atomic_write_text(out / f"{prefix}_light.json", json.dumps(light, indent=2) + "\n")
    return len(pred) + (relief is not None)


def _infer(args: argparse.Namespace, progress, summary: list[str]) -> int:
    """Predict and write one input's or one sequence's maps; appends the summary line."""
    from tqdm import tqdm  # noqa: PLC0415

    name = args.input.stem if args.input.is_file() else args.input.name
    frames = sequence_frames(args.input)
    if frames is not None and args.blend:
        raise ValueError("--blend saves one capture's asset; import a sequence with the add-on's Import PBR maps")
    if frames is not None:  # frames that do not belong together are refused before any is written
        from pbrdf.data.capture_decode import check_sequence  # noqa: PLC0415

        check_sequence(frames)

    def load():  # torch's import (network.infer) is most of the start-up: on a thread while a capture decodes
        from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415

        return _load_model(args.checkpoint or DEFAULT_CHECKPOINT)

    notes: list[RefineNote] = []
    if frames is None:  # the model loads while a capture decodes (headless._overlap)
        progress(0.25, "loading the model and decoding the input")
        (model, ckpt), inp = decode_while_loading(args.input, args.rig, load)
        pred, camera, light, relief = _reconstruct(model, ckpt, args.input, args, progress, inp=inp, notes=notes)
        progress(0.95, "writing the maps" + (" and the glTF binary" if args.gltf else ""))
        count = _write(args, name, pred, camera, light, relief)
        glb = f", {name}.glb" if args.gltf else ""
        if not args.quiet:  # printed before the summary line, after a successful run only
            summary += [f"{args.input.name}: {n.text}" for n in notes if not n.warned]
        summary.append(f"wrote {count} maps ({name}_*.exr/.png{glb}) to {args.out.resolve()}")
        return 0
    progress(0.25, "loading the model")
    model, ckpt = load()
    seconds = []
    for i, frame in enumerate(tqdm(frames, desc="frames", unit="frame", disable=args.quiet), start=1):
        start = time.perf_counter()
        try:
            at = 0.3 + 0.7 * (i - 1) / len(frames)
            pred, camera, light, relief = _reconstruct(model, ckpt, frame, args, progress, at, 0.7 / len(frames),
                                                       notes=notes)  # fmt: skip
            if relief is not None:  # a frame's time and errors include its relief
                pred["depth"], relief = relief.result()["depth"], None
        except (ValueError, OSError) as exc:
            raise ValueError(f"frame {i} ({frame.name}): {exc}") from None
        seconds.append(time.perf_counter() - start)
        _write(args, f"{name}_{i:04d}", pred, camera, light, relief)
    record = SequenceRecord.of_frames(name, frames, seconds)
    write_sequence(args.out, record)
    if not args.quiet:
        summary += _sequence_notes(name, notes, len(frames))
    summary.append(
        f"wrote {len(frames)} frames ({name}_NNNN_*.exr/.png, {name}{SEQUENCE_SUFFIX}) to {args.out.resolve()}; "
        f"{record.to_dict()['frames_per_second']:.2f} frames/s (decode + prediction)"
    )
    return 0


def _gltf_asset(args: argparse.Namespace, pred: dict, camera: CameraRecord):
    """``--gltf``: the asset (:mod:`pbrdf.data.gltf_asset`), built and checked before any file is written; else None."""
    if not args.gltf:
        return None
    from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M  # noqa: PLC0415
    from pbrdf.data.gltf_asset import build_asset  # noqa: PLC0415

    return build_asset(pred, camera.intrinsics, distance=camera.distance_m or DEFAULT_DISTANCE_M)


def _write_gltf(args: argparse.Namespace, prefix: str, asset) -> None:
    if asset is not None:
        from pbrdf.data.gltf_asset import write_asset  # noqa: PLC0415

        write_asset(args.out / f"{prefix}.glb", asset, name=prefix)


def _start_blend(args: argparse.Namespace):
    """``--blend``: headless/relight.py started now, saving the .blend once the maps are written (PendingBlend)."""
    from headless.relight import PendingBlend  # noqa: PLC0415

    name = args.input.stem if args.input.is_file() else args.input.name
    return PendingBlend(args.out, name, args.out, quiet=args.quiet)


if __name__ == "__main__":
    raise SystemExit(main())
