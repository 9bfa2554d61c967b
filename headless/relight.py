"""Import predicted PBR maps into Blender as a Principled BSDF asset and relight it with Cycles.

    python headless/relight.py --input DIR [--name NAME] --out DIR [--frames 8] [--size 160]
        [--samples 4] [--[no-]denoise] [--hdr FILE] [--sun] [--device CPU|GPU] [--save-blend] [--quiet]
    python headless/relight.py --jobs JOBS.json [the same settings]

Reads DIR/<NAME>_normal/_albedo/_roughness/_metallic/_mask.exr (what headless/infer.py writes;
any names the add-on's "Import PBR maps" recognises), builds the camera-parented asset, then
renders OUT/point_NNNN.png: a point light orbiting the asset (--frames frames) and
OUT/env_NNNN.png: a procedural sky (without its sun disc unless --sun) or --hdr environment map.
With --save-blend the scene is saved as OUT/<NAME>.blend for artists (blender_addon.relight_job):
Cycles with denoising, the world, the orbit light, the capture camera with the asset, packed
images. Runs with the bpy wheel (`pip install bpy`) or inside Blender 4.2+:
`blender -b --python-exit-code 1 -P headless/relight.py -- <args>` (an older Blender is refused
with one line and status 2; inside the binary an uncaught error is one "error: ..." line with
status 1).

--jobs relights many assets in this one process (the demo's route: bpy starts once): JOBS.json is a
list of {"input": DIR, "name": NAME, "out": DIR, "save_blend": true|false} ("name" and "save_blend"
optional, "save_blend" defaulting to --save-blend); each asset is relit as its own run would relight
it, and a line "wrote N files to OUT" is printed as each finishes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import refuse_old_blender, require, run_main, script_args  # noqa: E402

if __name__ == "__main__":
    refuse_old_blender("relight.py")  # inside the Blender binary: an old Blender is refused first

#: Frame defaults: the cheapest measured setting scoring 35 dB or more against a 1024-sample reference
#: (docs/measurements/relight.md); equal to blender_addon.relight_job's and the demo's (tested).
SAMPLES, SIZE, DENOISE = 4, 160, True


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="relight.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, metavar="DIR",
                        help="folder with the predicted maps, or one map file (required)")  # fmt: skip
    parser.add_argument("--name", default="", help="map name prefix NAME in NAME_normal.exr (default: all maps)")
    parser.add_argument("--out", type=Path, help="output folder for frames and the .blend (required)")
    parser.add_argument("--jobs", type=Path, metavar="JOBS.json",
                        help="relight every asset listed in this file in one process (for --input, --out)")  # fmt: skip
    parser.add_argument("--frames", type=int, default=8, help="point-light orbit frames; 0 = no rendering")
    parser.add_argument("--size", type=int, default=SIZE, help=f"longest side of the rendered frames (default {SIZE})")
    parser.add_argument("--samples", type=int, default=SAMPLES, help=f"Cycles samples per pixel (default {SAMPLES})")
    parser.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=DENOISE,
                        help="Cycles' denoiser on the frames (default: %(default)s)")  # fmt: skip
    parser.add_argument("--distance", type=float, default=1.0, help="asset plane distance from the camera, m")
    parser.add_argument("--exposure", type=float, default=1.0, help="point-light power scale (default 1)")
    parser.add_argument("--hdr", type=Path, default=None, help="environment map (.hdr/.exr); default procedural sky")
    parser.add_argument("--env-strength", type=float, default=0.3, help="environment strength (default 0.3)")
    parser.add_argument("--sun", action="store_true",
                        help="give the procedural sky its sun disc (~10x the sky: lower --env-strength)")  # fmt: skip
    parser.add_argument("--device", default="CPU", choices=["CPU", "GPU"], help="Cycles device (default CPU)")
    parser.add_argument("--save-blend", action="store_true", help="save OUT/<NAME>.blend")
    parser.add_argument("--quiet", action="store_true", help="no progress output (the summary line still prints)")
    parser.add_argument("--wait-for-go", action="store_true",
                        help="start Blender, then wait for a line 'go' on stdin before reading the maps (infer.py "
                        "--blend, while it predicts them); end of input instead: exit 0, nothing written")  # fmt: skip
    return parser


class PendingBlend:
    """``relight.py --frames 0 --save-blend --wait-for-go`` started now: Blender starts while the caller works.

    :meth:`finish` once ``maps/<name>_*`` are written saves ``out/<name>.blend``; :meth:`cancel`
    ends the process with nothing written.

    Args:
        maps: the folder the maps will be in.
        name: their name prefix.
        out: the folder of the ``.blend``.
        quiet: no progress output.
    """

    def __init__(self, maps: Path, name: str, out: Path, *, quiet: bool) -> None:
        import subprocess  # noqa: PLC0415

        cmd = [sys.executable, str(Path(__file__).resolve()), "--input", str(maps), "--name", name, "--out",
               str(out), "--frames", "0", "--save-blend", "--wait-for-go", *(["--quiet"] if quiet else [])]  # fmt: skip
        self.process = subprocess.Popen(cmd, stdin=subprocess.PIPE, text=True)  # own process: no torch beside bpy

    def finish(self) -> int:
        """Let Blender read the maps and save the ``.blend``; returns its exit status."""
        self.process.communicate("go\n")
        return self.process.returncode

    def cancel(self) -> None:
        """End the process without writing anything."""
        self.process.communicate("")


def read_jobs(path: Path, save_blend: bool) -> list[dict]:
    """The assets of a ``--jobs`` file: ``{"maps", "out", "name", "save_blend"}`` per entry, checked.

    Args:
        path: the JSON file (the module docstring gives its form).
        save_blend: an entry's ``save_blend`` when it gives none (``--save-blend``).

    Returns:
        One dict per entry, in order, as :class:`blender_addon.relight_job.RelightJob` takes them.

    Raises:
        ValueError: not a JSON list of objects with the fields above (one line naming the file and entry).
        OSError: the file cannot be read.
    """
    import json  # noqa: PLC0415

    try:
        entries = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: expected a non-empty JSON list of jobs")
    jobs = []
    for i, entry in enumerate(entries):
        fields = set(entry) if isinstance(entry, dict) else set()
        if not {"input", "out"} <= fields or fields - {"input", "out", "name", "save_blend"}:
            raise ValueError(f"{path}: job {i}: expected an object with input, out (and name, save_blend)")
        if not isinstance(entry.get("save_blend", save_blend), bool):
            raise ValueError(f"{path}: job {i}: save_blend must be true or false")
        jobs.append({"maps": Path(entry["input"]), "out": Path(entry["out"]), "name": str(entry.get("name", "")),
                     "save_blend": entry.get("save_blend", save_blend)})  # fmt: skip
    return jobs


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error or without bpy)."""
    parser = build_parser()
    args = parser.parse_args(script_args(sys.argv) if argv is None else argv)
    if args.jobs is None:
        require(parser, args, "--input", "--out")
    elif args.input is not None or args.out is not None:
        parser.error("--jobs lists each asset's input and out: give neither --input nor --out with it")
    if args.frames < 0 or args.size < 8 or args.samples < 1:
        parser.error("--frames >= 0, --size >= 8 and --samples >= 1 are required")
    try:
        from blender_addon.relight_job import RelightJob, relight_batch  # noqa: PLC0415 - imports bpy
    except ImportError as exc:
        print(f"error: bpy is not importable ({exc}): `pip install bpy` (Python 3.11) or run inside Blender",
              file=sys.stderr)  # fmt: skip
        return 2
    from blender_addon.compat import blender_refusal, running_blender  # noqa: PLC0415

    problem = blender_refusal(running_blender())
    if problem:  # the bpy wheel's route (the binary's was refused at start-up)
        print(f"error: relight.py {problem}", file=sys.stderr)
        return 2
    if args.wait_for_go and sys.stdin.readline().strip() != "go":
        return 0  # the caller gave up (its own error is the message)
    settings = {
        "frames": args.frames, "size": args.size, "samples": args.samples, "distance": args.distance,
        "exposure": args.exposure, "hdr": args.hdr, "env_strength": args.env_strength, "sun": args.sun,
        "device": args.device, "denoise": args.denoise,
    }  # fmt: skip
    try:
        if args.jobs is None:
            jobs = [RelightJob(args.input, args.out, args.name, args.save_blend)]
        else:
            jobs = [RelightJob(**job) for job in read_jobs(args.jobs, args.save_blend)]
        for job, written in zip(jobs, relight_batch(jobs, **settings), strict=False):
            print(f"wrote {len(written)} files to {job.out.resolve()}", flush=True)
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    run_main(main)  # inside `blender -b -P` too: the exit status reaches the shell, any failure is one line
