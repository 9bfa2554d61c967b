"""Choose the refinement's guard (network/refine_guard.py) and roughness grid on validation splits.

    PYTHONPATH=. python tools/refine_guard_tune.py features out/splits/val-light --limit 16 --out DIR
    PYTHONPATH=. python tools/refine_guard_tune.py tune DIR [DIR ...]

``features``: each scene through the capture path (:func:`network.evaluation.predict_scene`, the
shipped model, no refinement), then what the refinement sees: the albedo fit's terms
(:func:`network.refine.albedo_terms`) and the roughness fit's trusted pixels with their LP
re-rendered at every roughness of the full 14-value grid (one ``.pkl`` per scene). ``tune``: per
setting of the guard's LP-gain window and of the roughness grid (a subset of the 14 values,
interpolated as :func:`network.refine_roughness.map_roughness` does), the refined albedo and
roughness maps exactly as :func:`network.refine.refine` makes them, scored per scene (albedo PSNR,
roughness RMSE, paired against the network) and per object (roughness r), by material kind.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network import metrics  # noqa: E402
from network import refine as rf  # noqa: E402
from network import refine_roughness as rr  # noqa: E402
from network.checkpoint import load_checkpoint  # noqa: E402
from network.constant import STATS_FILE, load_statistics  # noqa: E402
from network.evaluation import _fill_nearest, predict_scene  # noqa: E402
from network.infer import DEFAULT_CHECKPOINT, load_input  # noqa: E402
from network.refine_guard import GuardParams  # noqa: E402
from network.statistics import correlation, summarize, summary_text  # noqa: E402
from pbrdf.data import sample as psample  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402

FULL = np.array([0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
GRIDS = {
    "14": FULL,
    "8": np.array([0.05, 0.1, 0.2, 0.3, 0.4, 0.6, 0.8, 1.0]),
    "7": np.array([0.05, 0.15, 0.25, 0.4, 0.6, 0.8, 1.0]),
    "6": np.array([0.05, 0.15, 0.3, 0.5, 0.7, 1.0]),
}


def features(root: Path, limit: int, out: Path) -> None:
    """Write the per-scene features (module docs)."""
    torch.set_num_threads(1)
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    stats = load_statistics(DEFAULT_CHECKPOINT.parent / STATS_FILE)
    out.mkdir(parents=True, exist_ok=True)
    for i in range(limit):
        if (out / f"{i:04d}.pkl").exists():
            continue
        s = predict_scene(model, ckpt["inputs"], root, i, stats, input_scale=ckpt["input_scale"], baseline=False)
        if s.ours is None or "depth" not in s.gt:
            continue
        inp = load_input(psample.sample_paths(root, i).sidecar)
        rig = inp.rig or Rig()
        dist = float(np.median(s.gt["depth"][s.region & (s.gt["depth"] > 0)]))
        terms = rf.albedo_terms(s.ours, inp.maps, inp.intrinsics, rig, inp.radiance, dist)
        idx, normal, points, obs = rr._samples(s.ours, inp.maps, inp.intrinsics, dist, rr.RoughnessParams(), 0)
        model_lp = rr.lp_profiles(normal, points, rig, FULL) if idx.size else np.zeros((len(FULL), 0, 3))
        kinds = {j: s.meta["materials"][o["material"]].get("kind", "?") for j, o in enumerate(s.meta["objects"])}
        keep = {"ours": s.ours, "auto": s.auto_mask, "region": s.region, "gt": s.gt, "objects": s.objects,
                "kinds": kinds, "terms": terms, "r_idx": idx, "r_obs": obs[:, 3:6], "r_model": model_lp,
                "constant": float(stats["roughness"])}  # fmt: skip
        (out / f"{i:04d}.pkl").write_bytes(pickle.dumps(keep))
        print(root.name, i, flush=True)


def _refined_roughness(d: dict, guard: dict, grid_key: str) -> np.ndarray:
    """The refined ``(H, W, 1)`` roughness as :func:`network.refine_roughness.refine_roughness` makes it."""
    pred, t = d["ours"], d["terms"]
    labels, params, grid = t["labels"], rr.RoughnessParams(), GRIDS[grid_key]
    cols = np.searchsorted(FULL, grid)
    w = labels.shape[1]
    rough = pred["roughness"][..., 0].astype(np.float64)
    out = rough.copy()
    lab = labels.reshape(-1)[d["r_idx"]]
    for k in range(1, int(labels.max()) + 1):
        sel = lab == k
        if sel.sum() < params.min_pixels or (guard.get(k) or {}).get("roughness"):
            continue
        prof = rr.object_profile(d["r_obs"][sel], d["r_model"][cols][:, sel], np.ones(int(sel.sum())))
        r_net_obj = float(rough[labels == k].mean())
        chosen, lc, ln = rr.map_roughness(prof, float(rough[d["r_idx"][sel] // w, d["r_idx"][sel] % w].mean()),
                                          params, grid)  # fmt: skip
        if prof.min() > params.max_residual or not lc < ln * (1.0 - 1e-3):
            continue
        diel = (labels == k) & (pred["metallic"][..., 0] < 0.5)
        out[diel] += chosen - r_net_obj
    mask = pred["mask"][..., 0] > 0
    return np.where(mask, np.clip(out, 0.0, 1.0), 0.0)[..., None].astype(np.float32)


def _score(d: dict, params: GuardParams, grid_key: str) -> dict:
    """Per scene: albedo PSNR and roughness RMSE of network and refinement; per GT object the roughness means."""
    res = rf.albedo_from_terms(d["ours"], d["terms"], params)
    rough = _refined_roughness(d, res.guard, grid_key)
    region, gt, auto = d["region"], d["gt"], d["auto"]
    ours = _fill_nearest(d["ours"], auto, region)
    ref = _fill_nearest({**res.pred, "roughness": rough}, auto, region)
    g = gt["roughness"].reshape(region.shape)[..., None]
    row = {"net_psnr": metrics.psnr(ours["albedo"], gt["albedo"], region),
           "ref_psnr": metrics.psnr(ref["albedo"], gt["albedo"], region),
           "net_rmse": metrics.rmse(ours["roughness"].reshape(g.shape), g, region),
           "ref_rmse": metrics.rmse(ref["roughness"].reshape(g.shape), g, region),
           "kinds": sorted(set(d["kinds"].values())), "objects": []}  # fmt: skip
    for i in np.unique(d["objects"][region]).tolist():
        sel = region & (d["objects"] == i)
        if float(np.mean(gt["metallic"].reshape(region.shape)[sel])) >= 0.5:
            continue
        row["objects"].append({"kind": d["kinds"].get(i, "?"), "truth": float(np.mean(g[sel])),
                               "net": float(np.mean(ours["roughness"].reshape(g.shape)[sel])),
                               "ref": float(np.mean(ref["roughness"].reshape(g.shape)[sel]))})  # fmt: skip
    return row


def _components(d: dict) -> list[dict]:
    """Per mask component: its majority GT kind, the LP gain and share, the unguarded scale and the true one."""
    res = rf.albedo_from_terms(d["ours"], d["terms"], rf.refine_guard.OFF)
    labels, region = d["terms"]["labels"], d["region"]
    out = []
    for k, g in res.guard.items():
        sel = (labels == k) & region & (d["objects"] >= 0)
        if not sel.any():
            continue
        obj = int(np.bincount(d["objects"][sel]).argmax())
        a, t = d["ours"]["albedo"][sel], d["gt"]["albedo"].reshape(*region.shape, 3)[sel]
        true = float(np.sum(a * t) / max(np.sum(a * a), 1e-12))
        out.append({"kind": d["kinds"].get(obj, "?"), "lp_gain": g.get("lp_gain", np.nan),
                    "scale": res.scales.get(k, float("nan")), "true": true})  # fmt: skip
    return out


def tune(dirs: list[Path]) -> None:
    """Print the per-object cue by kind, then the scores per guard setting and roughness grid."""
    data = {p.name: [pickle.loads(f.read_bytes()) for f in sorted(p.glob("*.pkl"))] for p in dirs}
    comps = [c for ds in data.values() for d in ds for c in _components(d)]
    for kind in sorted({c["kind"] for c in comps}):
        cs = [c for c in comps if c["kind"] == kind]
        gains = np.array([c["lp_gain"] for c in cs], float)
        err = np.array([abs(np.log(c["scale"] / c["true"])) - abs(np.log(1 / c["true"])) for c in cs])
        print(f"{kind}: {len(cs)} components, LP gain p10/25/50/75/90 "
              f"{np.round(np.nanpercentile(gains, [10, 25, 50, 75, 90]), 2)}, "
              f"scale better than network in {np.nansum(err < 0)} of {np.isfinite(err).sum()}")  # fmt: skip
    inf = float("inf")
    _report("guard off, grid 14", data, rf.refine_guard.OFF, "14")
    chosen = rf.refine_guard.GUARD
    variants = {
        "chosen": chosen,
        "scale floor only": replace(rf.refine_guard.OFF, scale=chosen.scale),
        "albedo LP floor only": replace(rf.refine_guard.OFF, albedo_lp_gain=chosen.albedo_lp_gain),
        "roughness LP floor only": replace(rf.refine_guard.OFF, lp_gain=chosen.lp_gain),
    }
    for low in (0.5, 0.7):
        variants[f"scale floor {low}"] = replace(chosen, scale=(low, chosen.scale[1]))
    for low in (0.1, 0.3):
        variants[f"albedo LP floor {low}"] = replace(chosen, albedo_lp_gain=(low, inf))
    for low in (0.3, 0.6):
        variants[f"roughness LP floor {low}"] = replace(chosen, lp_gain=(low, inf))
    for shrink in (0.75, 0.5):
        variants[f"shrink {shrink}"] = replace(chosen, shrink=shrink)
    for name, params in variants.items():
        _report(f"{name}: scale {params.scale}, albedo LP {params.albedo_lp_gain}, roughness LP {params.lp_gain}, "
                f"shrink {params.shrink}, grid 14", data, params, "14")  # fmt: skip
    for grid_key in ("8", "7", "6"):
        _report(f"chosen, grid {grid_key}", data, chosen, grid_key)


def _report(title: str, data: dict, params: GuardParams, grid_key: str) -> None:
    print(f"## {title}")
    for split, ds in data.items():
        rows = [_score(d, params, grid_key) for d in ds]
        da = summarize([r["ref_psnr"] - r["net_psnr"] for r in rows])
        dr = summarize([r["ref_rmse"] - r["net_rmse"] for r in rows])
        objs = [o for r in rows for o in r["objects"]]
        cr = {m: correlation([o["truth"] for o in objs], [o[m] for o in objs]) for m in ("net", "ref")}
        kinds = []
        for kind in ("pplastic", "measured"):
            ks = [r for r in rows if r["kinds"] == [kind]]
            if ks:
                kinds.append(f"{kind} {len(ks)}: {np.mean([r['ref_psnr'] - r['net_psnr'] for r in ks]):+.2f} dB")
        print(f"  {split} ({len(rows)}): albedo {np.mean([r['net_psnr'] for r in rows]):.2f} -> "
              f"{np.mean([r['ref_psnr'] for r in rows]):.2f} dB, delta {summary_text(da, 2, signed=True)}, worse "
              f"{sum(r['ref_psnr'] < r['net_psnr'] - 0.01 for r in rows)}; {'; '.join(kinds)} | rough RMSE "
              f"{np.mean([r['net_rmse'] for r in rows]):.3f} -> {np.mean([r['ref_rmse'] for r in rows]):.3f} "
              f"delta {summary_text(dr, 3, signed=True)} | r {summary_text(cr['net'], 2, key='r')} -> "
              f"{summary_text(cr['ref'], 2, key='r')}", flush=True)  # fmt: skip


def main() -> None:
    """Run ``features`` or ``tune``."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("features")
    f.add_argument("root", type=Path)
    f.add_argument("--limit", type=int, default=16)
    f.add_argument("--out", type=Path, required=True)
    t = sub.add_parser("tune")
    t.add_argument("dirs", nargs="+", type=Path)
    args = p.parse_args()
    if args.cmd == "features":
        features(args.root, args.limit, args.out)
    else:
        tune(args.dirs)


if __name__ == "__main__":
    main()
