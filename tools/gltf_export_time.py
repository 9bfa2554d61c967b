"""Time the glTF export (`infer.py --gltf`, `headless/export_gltf.py`) of a written prediction, stage by stage.

Reads ``<name>_{normal,albedo,roughness,metallic,mask,depth}.exr`` and ``<name>_camera.json`` from a
prediction folder (``headless/infer.py --out``), then builds the asset (:func:`pbrdf.data.gltf_asset.build_asset`)
and writes ``<out>`` (:func:`pbrdf.data.gltf_asset.write_asset`) ``--repeats`` times and prints one line:
the mesh and file sizes and the median seconds of the build, of its main stages (the maps extended past the
mask, the vertex frames, the PNG encoding) and of the write (the .glb assembled and written atomically).

Usage: ``PYTHONPATH=. python tools/gltf_export_time.py --input pred/ --name capture --out /tmp/x.glb --repeats 5``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from pbrdf.data import gltf_asset
from pbrdf.data.predictions import CameraRecord
from pbrdf.io.exr import read_exr

_ORDER = "XYZRGB"  # channel order of the EXRs infer.py writes (normal.X.., albedo.R.., else .Y)


def read_prediction(folder: Path, name: str) -> tuple[dict, np.ndarray]:
    """``(pred, K)``: the maps ``{key: (H, W, C) float32}`` and the camera's intrinsics."""
    pred = {}
    for key in ("normal", "albedo", "roughness", "metallic", "mask", "depth"):
        ch = read_exr(folder / f"{name}_{key}.exr")
        pred[key] = np.stack([ch[c] for c in sorted(ch, key=lambda c: _ORDER.find(c[-1]))], -1).astype(np.float32)
    return pred, np.asarray(CameraRecord.read(folder / f"{name}_camera.json").intrinsics)


def _timed(store: dict, key: str, fn):
    """``fn`` wrapped so that each call adds its seconds to ``store[key]``."""

    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            store[key][-1] += time.perf_counter() - start

    return wrapper


def main() -> None:
    """Parse the flags, time the export, print the line."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, required=True, help="prediction folder (infer.py --out)")
    parser.add_argument("--name", required=True, help="the maps' name prefix")
    parser.add_argument("--out", type=Path, required=True, help="the .glb to write")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    pred, k = read_prediction(args.input, args.name)
    stages: dict[str, list[float]] = defaultdict(list)
    for name in ("extend_maps", "vertex_frames", "encode_png"):  # the module's own names, so its calls are timed
        setattr(gltf_asset, name, _timed(stages, name, getattr(gltf_asset, name)))
    for _ in range(args.repeats):
        for key in ("build", "write", "extend_maps", "vertex_frames", "encode_png"):
            stages[key].append(0.0)
        start = time.perf_counter()
        asset = gltf_asset.build_asset(pred, k)
        stages["build"][-1] = time.perf_counter() - start
        start = time.perf_counter()
        path = gltf_asset.write_asset(args.out, asset, name=args.name)
        stages["write"][-1] = time.perf_counter() - start
    m = asset.material
    pngs = " + ".join(f"{len(p) / 1e3:.0f}" for p in (m.base_color_png, m.metallic_roughness_png, m.normal_png))
    medians = ", ".join(f"{key} {statistics.median(v):.3f}" for key, v in stages.items())
    print(
        f"maps {pred['mask'].shape[1]} x {pred['mask'].shape[0]}, mask {int((pred['mask'] > 0).sum())} px; "
        f"{len(asset.mesh.positions)} vertices, {len(asset.mesh.indices)} triangles, textures "
        f"{asset.box[3] - asset.box[1]} x {asset.box[2] - asset.box[0]}; file {path.stat().st_size / 1e6:.2f} MB "
        f"(PNGs {pngs} kB); median s of {args.repeats}: {medians}; load average {os.getloadavg()[0]:.1f}"
    )


if __name__ == "__main__":
    main()
