"""Diagnose absolute albedo: how predicted albedo follows the truth, the object distance and the input level.

    python tools/albedo_scale.py [--input out/splits/test-procedural out/splits/test-meshes] [--limit 24]
        [--checkpoint models/small/model.pt]

For each scene (the real-capture path: raw brackets, decode, automatic mask; dielectric pixels
of the objects only) the mean predicted and true albedo and the median depth are collected. Prints
the least-squares fit log(pred) = a log(truth) + b (a = 1 for a calibrated model, 0 for a constant),
the fit log(pred / truth) = c log(truth) + d log(depth) + e, and the mean predicted albedo of a few
scenes with their radiance maps scaled by 1/4 ... 4 (a calibrated model scales with them up to the
[0, 1] clip).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tools._capture_scenes import add_arguments, capture_scenes, load  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Run the diagnosis; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser, [Path("out/splits/test-procedural"), Path("out/splits/test-meshes")], 24)
    args = parser.parse_args(argv)

    from network.data import checkpoint_input_scale
    from network.infer import predict
    from network.inputs import checkpoint_inputs
    from pbrdf.data import sample as psample
    from pbrdf.data.capture import read_capture_meta

    net, ckpt, stats = load(args.checkpoint)
    how = {"inputs": checkpoint_inputs(ckpt), "input_scale": checkpoint_input_scale(ckpt)}
    rows, probes = [], []
    for root in args.input:
        for scene in capture_scenes(net, ckpt, stats, root, args.limit):
            region = scene.auto_mask & scene.region & (scene.gt["metallic"] < 0.5)
            if scene.ours is None or region.sum() < 100:
                continue
            truth = scene.gt["albedo"][region].mean()
            rows.append((scene.ours["albedo"][region].mean(), truth, np.median(scene.gt["depth"][region])))
            if len(probes) < 3:
                radiance = read_capture_meta(psample.sample_paths(root, scene.index).raw).radiance
                levels = []
                for k in (0.25, 0.5, 1.0, 2.0, 4.0):
                    scaled = scene.maps.copy()
                    scaled[..., :6] *= k
                    pred = predict(net, scaled, scene.auto_mask, radiance=radiance, **how)
                    levels.append(float(pred["albedo"][scene.auto_mask].mean()))
                probes.append((f"{root.name}/{scene.index}", levels))
    pred, truth, depth = np.array(rows).T
    a, b = np.polyfit(np.log(truth), np.log(pred), 1)
    x = np.c_[np.log(truth), np.log(depth), np.ones(len(truth))]
    c, d, e = np.linalg.lstsq(x, np.log(pred / truth), rcond=None)[0]
    print(f"{len(truth)} scenes; depth {depth.min():.2f}-{depth.max():.2f} m")
    print(f"log(pred) = {a:.2f} log(truth) {b:+.2f}   (1 = calibrated, 0 = constant)")
    print(f"log(pred/truth) = {c:.2f} log(truth) {d:+.2f} log(depth) {e:+.2f}")
    for name, levels in probes:
        print(f"{name}: mean predicted albedo with radiance maps x0.25 .. x4: " + " ".join(f"{v:.3f}" for v in levels))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
