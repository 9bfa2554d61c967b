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
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tools._capture_scenes import add_arguments, capture_scenes, load  # noqa: E402

SPLITS = ("test-procedural", "test-meshes", "test-pbrdf", "test-scenes")


def _summary(rows: list[tuple[float, float]]) -> str:
    if len(rows) < 3:
        return f"{len(rows)} objects (too few)"
    pred, truth = np.array(rows).T
    r = float(np.corrcoef(pred, truth)[0, 1]) if pred.std() > 0 and truth.std() > 0 else float("nan")
    rmse = float(np.sqrt(np.mean((pred - truth) ** 2)))
    const = float(np.sqrt(np.mean((truth.mean() - truth) ** 2)))
    return f"{len(rows):4d} objects  r = {r:+.2f}  RMSE {rmse:.3f}  (constant {const:.3f})"


def object_rows(scenes: Iterable[Any]) -> list[dict]:
    """One row per object with at least 100 pixels in the automatic mask: scene, object, kind, means.

    Args:
        scenes: :class:`network.evaluation.ScenePredictions` (``tools/_capture_scenes.py``).

    Returns:
        dicts with ``scene`` (index), ``object`` (id in the sidecar's object list), ``kind``
        (``"metal"`` where the object's mean true metallic is >= 0.5, else ``"dielectric"``), and
        ``pred`` and ``truth``, the mean predicted and true roughness over those pixels.
    """
    rows = []
    for scene in scenes:
        if scene.ours is None or scene.objects is None:
            continue
        for obj in np.unique(scene.objects[scene.objects >= 0]):
            region = scene.auto_mask & (scene.objects == obj)
            if region.sum() < 100:
                continue
            kind = "metal" if scene.gt["metallic"][region].mean() >= 0.5 else "dielectric"
            rows.append({"scene": scene.index, "object": int(obj), "kind": kind,
                         "pred": float(scene.ours["roughness"][..., 0][region].mean()),
                         "truth": float(scene.gt["roughness"][region].mean())})  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the diagnosis; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser, [Path("out/splits") / s for s in SPLITS], 48)
    args = parser.parse_args(argv)
    model, ckpt, stats = load(args.checkpoint)
    pooled: dict[str, list[tuple[float, float]]] = {"dielectric": [], "metal": []}
    for root in args.input:
        rows = object_rows(capture_scenes(model, ckpt, stats, root, args.limit))
        for kind in pooled:
            found = [(r["pred"], r["truth"]) for r in rows if r["kind"] == kind]
            print(f"{root.name:16s} {kind:10s} {_summary(found)}")
            pooled[kind] += found
    for kind, found in pooled.items():
        print(f"{'all':16s} {kind:10s} {_summary(found)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
