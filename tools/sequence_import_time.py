"""Time the add-on's import of a moving sequence (per-frame relief geometry) with the bpy wheel.

Writes an n-frame sequence of a tilted disc (``<name>_NNNN_{normal,mask,depth}.exr``, camera files,
``<name>_sequence.json``, as ``headless/infer.py`` does) in two variants -- the same mask in every
frame (shape keys on one mesh) and a disc that moves (one object per frame) -- imports each
``--repeats`` times into a fresh file and prints the median seconds and the peak resident memory.

Usage: ``PYTHONPATH=. python tools/sequence_import_time.py --frames 10 --size 192``
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from pbrdf.io.exr import write_exr
from pbrdf.sensor import projection


def _write(folder: Path, frames: int, size: int, moving: bool) -> Path:
    """An n-frame sequence of a disc 2 m away filling about half the frame; ``moving``: its mask moves."""
    folder.mkdir(parents=True)
    k = np.array([[1.2 * size, 0.0, size / 2], [0.0, 1.2 * size, size / 2], [0.0, 0.0, 1.0]])
    rays = projection.pixel_rays(k, size, size)
    for i in range(1, frames + 1):
        t = (i - 1) / max(frames - 1, 1)
        n = np.array([0.3 * np.cos(6 * t), 0.3 * np.sin(6 * t), 1.0])
        n /= np.linalg.norm(n)
        centre = np.array([0.2 * t - 0.1 if moving else 0.0, 0.0, -2.0])
        depth = (n @ centre) / (rays @ n)
        outline = depth if moving else np.full_like(depth, 2.0)  # the same mask every frame: that of a frontal disc
        mask = np.linalg.norm(rays * outline[..., None] - centre, axis=-1) < 0.65
        prefix = f"mov_{i:04d}"
        normal = np.where(mask[..., None], n, 0.0).astype(np.float32)
        write_exr(folder / f"{prefix}_normal.exr", {f"normal.{c}": normal[..., j] for j, c in enumerate("XYZ")})
        write_exr(folder / f"{prefix}_mask.exr", {"mask.Y": mask.astype(np.float32)})
        depth = np.where(mask, depth, np.inf).astype(np.float32)
        write_exr(folder / f"{prefix}_depth.exr", {"depth.Y": depth}, allow_nonfinite=True)
        camera = {"intrinsics": k.tolist(), "width": size, "height": size, "distance_m": 2.0}
        (folder / f"{prefix}_camera.json").write_text(json.dumps(camera))
    doc = {"name": "mov", "frames": [{"frame": i, "prefix": f"mov_{i:04d}"} for i in range(1, frames + 1)]}
    (folder / "mov_sequence.json").write_text(json.dumps(doc))
    return folder


def main(argv: list[str] | None = None) -> None:
    """Print one line per variant: geometry kind, vertices, median import seconds, peak RSS."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--size", type=int, default=192)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    import bpy

    from blender_addon import pbr_import

    with tempfile.TemporaryDirectory() as tmp:
        for moving in (False, True):
            folder = _write(Path(tmp) / f"moving{int(moving)}", args.frames, args.size, moving)
            seconds = []
            for _ in range(args.repeats):
                bpy.ops.wm.read_homefile(use_empty=True)
                start = time.perf_counter()
                obj = pbr_import.import_pbr_maps(bpy.context, folder, pbr_import.ImportOptions(normal_space="OBJECT"))
                seconds.append(time.perf_counter() - start)
            meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
            rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            print(
                f"{args.frames} frames {args.size} px, {obj['pdir_geometry']}: {len(meshes)} object(s), "
                f"{sum(len(o.data.vertices) for o in meshes)} vertices; "
                f"import median {statistics.median(seconds):.2f} s "
                f"(runs {', '.join(f'{s:.2f}' for s in seconds)}); peak RSS of the process so far {rss:.0f} MiB"
            )


if __name__ == "__main__":
    main()
