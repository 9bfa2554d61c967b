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


def main(argv: list[str] | None = None) -> int:
    """Run the diagnosis; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, nargs="+",
                        default=[Path("out/splits/test-procedural"), Path("out/splits/test-meshes")])  # fmt: skip
    parser.add_argument("--limit", type=int, default=24, help="scenes per split (default 24)")
    parser.add_argument("--checkpoint", type=Path, help="default: the shipped model")
    args = parser.parse_args(argv)

    import torch

    from network.checkpoint import load_checkpoint
    from network.infer import DEFAULT_CHECKPOINT, input_display_radiance, load_input, predict
    from pbrdf.data import dataset as pdataset

    torch.set_num_threads(2)
    net, ckpt = load_checkpoint(args.checkpoint or DEFAULT_CHECKPOINT)
    how = {"inputs": ckpt.get("inputs", "full"), "input_scale": ckpt.get("input_scale", "exposure-invariant")}
    rows, probes = [], []
    for root in args.input:
        for i in sorted(pdataset.completed_indices(root, verify_hash=False))[: args.limit]:
            sample, _ = pdataset.read_sample(root, i)
            raw = pdataset.sample_paths(root, i).raw
            maps, auto = load_input(raw)
            radiance = input_display_radiance(raw)
            pred = predict(net, maps, auto, radiance=radiance, **how)
            region = auto & (sample["object"] >= 0) & (sample["metallic"] < 0.5)
            if region.sum() < 100:
                continue
            rows.append(
                (pred["albedo"][region].mean(), sample["albedo"][region].mean(), np.median(sample["depth"][region]))
            )
            if len(probes) < 3:
                levels = []
                for k in (0.25, 0.5, 1.0, 2.0, 4.0):
                    scaled = maps.copy()
                    scaled[..., :6] *= k
                    levels.append(float(predict(net, scaled, auto, radiance=radiance, **how)["albedo"][auto].mean()))
                probes.append((f"{root.name}/{i}", levels))
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
