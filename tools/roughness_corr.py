"""Diagnose roughness: does predicted roughness follow the truth, for dielectrics and metals apart?

    python tools/roughness_corr.py [--input out/splits/test-procedural ...] [--limit 48]
        [--checkpoint models/small/model.pt]

For each object of each scene (the real-capture path: raw brackets, decode, automatic mask; the
object's pixels inside the automatic mask, at least 100) the mean predicted and true roughness
are collected, split by the true metallic (< 0.5: dielectric). Prints, per split and pooled, the
Pearson correlation of the per-object means (the issue's "dielectric roughness correlated with the
truth", target r >= 0.7), the RMSE of the object means, and the RMSE of the constant answer (the
mean true roughness of the rows) for comparison.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SPLITS = ("test-procedural", "test-meshes", "test-pbrdf", "test-scenes")


def _summary(rows: list[tuple[float, float]]) -> str:
    if len(rows) < 3:
        return f"{len(rows)} objects (too few)"
    pred, truth = np.array(rows).T
    r = float(np.corrcoef(pred, truth)[0, 1]) if pred.std() > 0 and truth.std() > 0 else float("nan")
    rmse = float(np.sqrt(np.mean((pred - truth) ** 2)))
    const = float(np.sqrt(np.mean((truth.mean() - truth) ** 2)))
    return f"{len(rows):4d} objects  r = {r:+.2f}  RMSE {rmse:.3f}  (constant {const:.3f})"


def object_rows(root: Path, limit: int, net: object, how: dict) -> list[dict]:
    """One row per object with at least 100 pixels in the automatic mask: scene, object, kind, means.

    Returns:
        dicts with ``scene`` (index), ``object`` (id in the sidecar's object list), ``kind``
        (``"metal"`` where the object's mean true metallic is >= 0.5, else ``"dielectric"``), and
        ``pred`` and ``truth``, the mean predicted and true roughness over those pixels.
    """
    from network.infer import input_display_radiance, load_input, predict
    from pbrdf.data import dataset as pdataset

    rows = []
    for i in sorted(pdataset.completed_indices(root, verify_hash=False))[:limit]:
        sample, _ = pdataset.read_sample(root, i)
        raw = pdataset.sample_paths(root, i).raw
        maps, auto = load_input(raw)
        pred = predict(net, maps, auto, radiance=input_display_radiance(raw), **how)
        for obj in np.unique(sample["object"][sample["object"] >= 0]):
            region = auto & (sample["object"] == obj)
            if region.sum() < 100:
                continue
            kind = "metal" if sample["metallic"][region].mean() >= 0.5 else "dielectric"
            rows.append({"scene": i, "object": int(obj), "kind": kind,
                         "pred": float(pred["roughness"][..., 0][region].mean()),
                         "truth": float(sample["roughness"][region].mean())})  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the diagnosis; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, nargs="+", default=[Path("out/splits") / s for s in SPLITS])
    parser.add_argument("--limit", type=int, default=48, help="scenes per split (default 48)")
    parser.add_argument("--checkpoint", type=Path, help="default: the shipped model")
    args = parser.parse_args(argv)

    import torch

    from network.checkpoint import load_checkpoint
    from network.infer import DEFAULT_CHECKPOINT

    torch.set_num_threads(2)
    net, ckpt = load_checkpoint(args.checkpoint or DEFAULT_CHECKPOINT)
    how = {"inputs": ckpt.get("inputs", "full"), "input_scale": ckpt.get("input_scale", "exposure-invariant")}
    pooled: dict[str, list[tuple[float, float]]] = {"dielectric": [], "metal": []}
    for root in args.input:
        rows = object_rows(root, args.limit, net, how)
        for kind in pooled:
            found = [(r["pred"], r["truth"]) for r in rows if r["kind"] == kind]
            print(f"{root.name:16s} {kind:10s} {_summary(found)}")
            pooled[kind] += found
    for kind, found in pooled.items():
        print(f"{'all':16s} {kind:10s} {_summary(found)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
