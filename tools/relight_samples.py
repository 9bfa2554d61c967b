"""Relit PSNR against Cycles samples, denoising and frame size: what the demo's relight needs.

Imports one prediction folder's maps as ``headless/relight.py`` does (:func:`blender_addon.relight_job.relit_scene`:
the same asset, orbit light and sky), renders one orbit frame and the sky frame at ``--reference`` samples
(no denoising), then at each of ``--samples`` with and without Cycles' denoiser, and scores every frame
against its reference as the demo scores a relit prediction against the relit truth
(:func:`network.demo.relight_compare.frame_scores`: PSNR of the 8-bit PNGs over the covered pixels).
Prints one JSON object per render (size, frame, samples, denoise, seconds, PSNR) and writes them all to
``OUT/relight_samples.json``. Runs with the bpy wheel (its own process: no torch).

Usage: ``PYTHONPATH=. nice python tools/relight_samples.py --input demo/truth/analytic_000000 --name analytic_000000
--out /tmp/rs --sizes 128 256 --samples 4 8 16 32 64``
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from PIL import Image

from blender_addon import relight_job, relight_operator
from network.demo.relight_compare import frame_scores


def _rgba(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGBA"), dtype=np.float64) / 255.0


def _render(scene, out: Path, frame: int, prefix: str, samples: int, denoise: bool) -> tuple[Path, float]:
    start = time.perf_counter()
    (path,) = relight_operator.render_relit(scene, out, samples=samples, denoise=denoise, frames=[frame], prefix=prefix)
    return path, time.perf_counter() - start


def measure(args: argparse.Namespace, size: int) -> list[dict]:
    """Every render of one frame size: the point-light frame, then the sky frame."""
    scene, _, light = relight_job.relit_scene(args.input, name=args.name, frames=args.frames, size=size)
    out, rows = args.out / str(size), []
    for kind in ("point", "env"):
        if kind == "env":  # as relight_maps: the light off, the procedural sky on, the orbit's first frame
            light.hide_render = True
            relight_operator.add_environment(scene, strength=0.3)
        frame = scene.frame_start + (args.point_frame if kind == "point" else 0)
        ref, seconds = _render(scene, out, frame, f"{kind}_ref_", args.reference, False)
        rows.append({"size": size, "frame": kind, "samples": args.reference, "denoise": False, "seconds": seconds,
                     "psnr": None})  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
        for samples in args.samples:
            for denoise in (False, True):
                path, seconds = _render(scene, out, frame, f"{kind}_s{samples}_{int(denoise)}_", samples, denoise)
                psnr = frame_scores(_rgba(path), _rgba(ref), lpips=False)["psnr"]
                rows.append({"size": size, "frame": kind, "samples": samples, "denoise": denoise, "seconds": seconds,
                             "psnr": psnr})  # fmt: skip
                print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    """Parse the flags, render, print and write the rows."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, required=True, help="folder with <name>_*.exr maps")
    parser.add_argument("--name", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sizes", type=int, nargs="+", default=[relight_job.SIZE])
    parser.add_argument("--samples", type=int, nargs="+", default=[4, 8, 16, 32, 64])
    parser.add_argument("--reference", type=int, default=1024)
    parser.add_argument("--frames", type=int, default=6, help="orbit frames, as the demo (default 6)")
    parser.add_argument("--point-frame", type=int, default=1, help="which orbit frame (0-based, default 1)")
    args = parser.parse_args()
    rows = [row for size in args.sizes for row in measure(args, size)]
    (args.out / "relight_samples.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
