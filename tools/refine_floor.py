"""The re-renderer's floor: the TRUE maps re-rendered under the display against the decoded unpol and LP.

    PYTHONPATH=. python tools/refine_floor.py out/splits/test-procedural [more splits] [--limit N] [--png DIR]

For every sample the ground-truth normal, albedo, roughness, metallic and depth go through
:func:`network.rerender.rerender_dense` (with the chosen diffuse model) and are compared, per
object, with the sample's stored (decoded) unpol and LP maps: the gain ``sum(decoded) /
sum(rendered)`` of each map, and the relative L2 error of both maps together. This is what a
test-time refinement through the re-renderer cannot go below. ``--png`` writes, per split, the
per-pixel log ratio of decoded to rendered unpol of the worst scenes.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network.rerender import display_patches, points_from_depth, rerender_dense  # noqa: E402
from pbrdf.data import sample as psample  # noqa: E402
from pbrdf.data.sample import sample_intrinsics  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402


def scene_floor(root: Path, index: int, diffuse: str) -> tuple[list[dict], np.ndarray, np.ndarray]:
    """Per-object rows and the per-pixel log ratio ``log(decoded / rendered)`` of unpol (grey), with the mask."""
    s, meta = psample.read_sample(root, index, keys=("maps", "mask", "normal", "albedo", "roughness", "metallic",
                                                     "depth", "object"))  # fmt: skip
    region = (s["object"] >= 0) & (s["depth"] > 0)
    k = sample_intrinsics(meta, region.shape, psample.sample_paths(root, index).sidecar)
    rig = Rig.from_dict(meta["rig"])
    t = {n: torch.from_numpy(np.ascontiguousarray(np.atleast_3d(s[n]).transpose(2, 0, 1)))[None].float()
         for n in ("normal", "albedo", "roughness", "metallic", "depth")}  # fmt: skip
    mask = torch.from_numpy(region.astype(np.float32))[None, None]
    with torch.no_grad():
        pts = points_from_depth(t["depth"], k)
        out = rerender_dense(t, mask, pts, display_patches(rig), diffuse=diffuse)
    ren = torch.cat([out["unpol"], out["lp"]], 1)[0].permute(1, 2, 0).numpy()
    dec = s["maps"][..., :6].astype(np.float64)
    rows = []
    ids = np.rint(s["object"]).astype(int)
    for i in np.unique(ids[region]):
        sel = region & (ids == i)
        spec = meta["objects"][i]
        kind = meta["materials"][spec["material"]]["kind"]
        d, r = dec[sel], ren[sel]
        # A conductor renders no unpol: its gain is undefined, not huge.
        gain_u = d[:, :3].sum() / r[:, :3].sum() if r[:, :3].sum() > 1e-3 * d[:, :3].sum() else np.nan
        gain_l = d[:, 3:].sum() / max(r[:, 3:].sum(), 1e-12)
        rel = np.linalg.norm(d - r) / max(np.linalg.norm(d), 1e-12)
        rows.append({"scene": index, "object": int(i), "kind": kind, "objects": len(meta["objects"]),
                     "pixels": int(sel.sum()), "gain_unpol": gain_u, "gain_lp": gain_l, "rel_l2": rel,
                     "metallic": float(np.mean(s["metallic"][sel]))})  # fmt: skip
    du, ru = dec[..., :3].sum(-1), ren[..., :3].sum(-1)
    lr = np.where(region, np.log((np.maximum(du, 0) + 1e-4) / (ru + 1e-4)), 0.0)
    return rows, lr, region


def _summary(rows: list[dict]) -> str:
    by = defaultdict(list)
    for r in rows:
        by[(r["kind"], "single" if r["objects"] == 1 else "multi")].append(r)
    lines = ["| kind | scenes | objects | unpol gain median [p25, p75] | LP gain median [p25, p75] | rel. L2 median |",
             "|---|---|---:|---|---|---:|"]  # fmt: skip
    for (kind, multi), rs in sorted(by.items()):
        gu = np.array([r["gain_unpol"] for r in rs])
        gl = np.array([r["gain_lp"] for r in rs])
        rel = np.array([r["rel_l2"] for r in rs])

        def q(x):
            x = x[np.isfinite(x)]
            return f"{np.median(x):.2f} [{np.percentile(x, 25):.2f}, {np.percentile(x, 75):.2f}]" if x.size else "n/a"

        lines.append(f"| {kind} | {multi} | {len(rs)} | {q(gu)} | {q(gl)} | {np.median(rel):.2f} |")
    return "\n".join(lines)


def _png(path: Path, maps: list[tuple[int, np.ndarray, np.ndarray]]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, len(maps), figsize=(3 * len(maps), 3.2), squeeze=False)
    for ax, (idx, lr, region) in zip(axes[0], maps, strict=True):
        im = ax.imshow(np.where(region, lr, np.nan), cmap="RdBu_r", vmin=-1, vmax=1)
        ax.set_title(f"scene {idx}", fontsize=9)
        ax.axis("off")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="log(decoded / re-rendered) unpol")
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    """Print the per-kind floor of each split (markdown) and optionally write the figures."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("splits", nargs="+", type=Path)
    p.add_argument("--limit", type=int)
    p.add_argument("--diffuse", default="burley", choices=["burley", "fresnel"])
    p.add_argument("--png", type=Path)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    torch.set_num_threads(1)
    everything = {}
    for root in args.splits:
        n = len(list((root / "samples").glob("*.json")))
        rows, maps = [], []
        for i in range(min(n, args.limit or n)):
            r, lr, region = scene_floor(root, i, args.diffuse)
            rows += r
            maps.append((i, lr, region, max(x["rel_l2"] for x in r)))
        print(f"\n### {root.name} ({len(maps)} scenes, diffuse {args.diffuse})\n\n{_summary(rows)}")
        everything[root.name] = rows
        if args.png:
            args.png.mkdir(parents=True, exist_ok=True)
            worst = sorted(maps, key=lambda m: -m[3])[:5]
            _png(args.png / f"floor_{root.name}.png", [m[:3] for m in worst])
    if args.json:
        args.json.write_text(json.dumps(everything, indent=1, default=float))


if __name__ == "__main__":
    main()
