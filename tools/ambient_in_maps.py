"""The room light a jittered split's stored maps carry, and what removing it does to a model's scores.

    python tools/ambient_in_maps.py [--input out/splits/val-next] [--limit 32]
        [--checkpoint models/small/model.pt runs/next/state.pt]

The data engine decodes a ``rig_jitter`` scene without dark frames, so each camera channel's unpol
map holds the drawn ambient ``a_c`` times the drawn vignetting ``V`` (docs/rig_imperfections.md,
"Ambient light: the engine against the capture path"). Prints its share of the object's unpol,
then scores each checkpoint on the first ``--limit`` scenes twice, paired: on the maps as stored
and with ``V a_c`` removed from unpol (CP undiluted to match), which is what the dark frames of the
capture path do to the mean (their own noise aside). Read-only on the split.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pbrdf.data import sample as psample  # noqa: E402
from pbrdf.sensor.imperfections import vignetting_map  # noqa: E402

_GT = ("normal", "albedo", "roughness", "metallic")


def without_ambient(maps: np.ndarray, mask: np.ndarray, ambient: np.ndarray, poly: tuple) -> np.ndarray:
    """``maps`` (H, W, 9) with ``V a_c`` taken out of each channel's unpol and CP rescaled to the smaller s0."""
    h, w = maps.shape[:2]
    amb = vignetting_map((2 * h, 2 * w), np.inf, poly, grid="half")[..., None] * ambient  # raw = 2x the maps' grid
    out = maps.astype(np.float64)
    s0 = out[..., 0:3] + out[..., 3:6]  # unpol + LP
    out[..., 0:3] -= amb
    out[..., 6:9] = np.clip(out[..., 6:9] * (s0 + 1e-6) / np.maximum(s0 - amb + 1e-6, 1e-6), -1.0, 1.0)
    return np.where(mask[..., None], out, 0.0).astype(np.float32)


def _share(root: Path, indices: list[int]) -> None:
    shares, over = [], []
    for i in indices:
        sample, meta = psample.read_sample(root, i, keys=("maps", "mask"))
        a = np.asarray(meta["rig_jitter"]["ambient"], np.float64)
        unpol = sample["maps"][..., :3][sample["mask"] > 0]
        shares.append(float(np.median(a / np.maximum(np.median(unpol, axis=0), 1e-9))))
        over.append(float((a / np.maximum(unpol, 1e-9) > 0.1).mean()))
    print(f"{root.name}, {len(indices)} scenes: ambient / median unpol per scene, median {np.median(shares):.3f} "
          f"(90th percentile {np.percentile(shares, 90):.3f}); object pixel-channels where it is > 10 % of unpol: "
          f"{np.mean(over):.3f}")  # fmt: skip


def _paired(root: Path, indices: list[int], checkpoint: Path) -> None:
    import torch  # noqa: PLC0415

    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.evaluation import score  # noqa: PLC0415
    from network.infer import load_input, predict  # noqa: PLC0415
    from network.light_input import scene_light  # noqa: PLC0415
    from network.statistics import summarize, summary_text  # noqa: PLC0415

    torch.set_num_threads(1)
    model, ckpt = load_checkpoint(checkpoint)
    rows = []
    for i in indices:
        sample, meta = psample.read_sample(root, i, keys=(*_GT, "object", "depth"))
        region = sample["object"] >= 0
        inp = load_input(psample.sample_paths(root, i).sidecar)
        drawn = meta["rig_jitter"]
        clean = without_ambient(inp.maps, inp.mask, np.asarray(drawn["ambient"]), tuple(drawn["vignetting_poly"]))
        light = scene_light(model, inp, sample["depth"], region, 1.0)
        row = []
        for maps in (inp.maps, clean):
            pred = predict(model, maps, inp.mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
                           radiance=inp.radiance, light=light)  # fmt: skip
            s = score(pred, {k: sample[k] for k in _GT}, inp.mask & region, lpips=False)
            row += [s["normal_mae"], s["albedo_psnr"], s["albedo_si_psnr"]]
        rows.append(row)
    r = np.array(rows)
    print(f"{checkpoint}, {len(indices)} scenes: as stored / ambient removed / removed - stored [95 % bootstrap CI]")
    for j, name in enumerate(("normal MAE deg", "albedo PSNR dB", "albedo si-PSNR dB")):
        change = summary_text(summarize(r[:, j + 3] - r[:, j]), 3, signed=True)
        print(f"  {name}: {r[:, j].mean():.2f} / {r[:, j + 3].mean():.2f} / {change}")


def main(argv: list[str] | None = None) -> int:
    """Run the measurement; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, default=Path("out/splits/val-next"), help="a split with rig_jitter")
    parser.add_argument("--limit", type=int, default=32, help="first N scenes (default 32)")
    parser.add_argument("--checkpoint", type=Path, nargs="*", default=[Path("models/small/model.pt")])
    args = parser.parse_args(argv)
    indices = list(range(args.limit))
    _share(args.input, indices)
    for checkpoint in args.checkpoint:
        _paired(args.input, indices, checkpoint)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
