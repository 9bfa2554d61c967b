"""Photometric stereo on single-object textured scenes: calibrated albedo, the true mean albedo, constant.

    python tools/ps_textured_diag.py [--input out/splits/test-textured] [--limit 16]

Prints per single-object scene: index, material kind, the spread of the true albedo's
chromaticity, and the normal MAE (deg) of the calibrated baseline, of the baseline given the
object's true mean albedo, and of the constant normal, on the automatic mask within the object
coverage (the evaluation's capture path, :func:`network.evaluation.predict_scene`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # run as a file: the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, default=Path("out/splits/test-textured"), help="rendered split")
    parser.add_argument("--limit", type=int, default=16, help="first N scenes (default 16)")
    args = parser.parse_args(argv)

    from network import baseline as ps  # noqa: PLC0415
    from network import metrics  # noqa: PLC0415
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.constant import load_statistics  # noqa: PLC0415
    from network.evaluation import predict_scene  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415
    from pbrdf.data import dataset  # noqa: PLC0415

    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    stats = load_statistics(Path(DEFAULT_CHECKPOINT).parent / "train_stats.json")
    rows = []
    for i in sorted(dataset.completed_indices(args.input, verify_hash=False))[: args.limit]:
        sc = predict_scene(model, ckpt.get("inputs", "full"), args.input, i, stats,
                           input_scale=ckpt["input_scale"], baseline=False)  # fmt: skip
        if sc.objects is None or len(np.unique(sc.objects[sc.region])) != 1:
            continue
        sel, gt = sc.auto_mask & sc.region, sc.gt
        albedo = gt["albedo"][sc.region]
        spread = float(np.std(albedo / np.maximum(albedo.sum(-1, keepdims=True), 1e-6), axis=0).max())
        cal = ps.predict_sample(sc.maps, sc.auto_mask, sc.meta)["normal"]
        known = ps.predict_sample(sc.maps, sc.auto_mask, sc.meta, albedo=tuple(albedo.mean(0)))["normal"]
        const = np.broadcast_to([0.0, 0.0, 1.0], gt["normal"].shape)
        errors = [metrics.normal_mae_deg(n, gt["normal"], sel) for n in (cal, known, const)]
        kind = next(iter(sc.meta["materials"].values()))["kind"]
        rows.append(errors)
        print(i, kind, f"chromaticity spread {spread:.3f}", "calibrated, true mean albedo, constant:",
              " ".join(f"{e:.1f}" for e in errors), flush=True)  # fmt: skip
    if rows:
        print("mean:", " ".join(f"{e:.1f}" for e in np.mean(rows, axis=0)), f"(n = {len(rows)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
