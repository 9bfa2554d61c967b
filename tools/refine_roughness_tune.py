"""Choose the roughness refinement's weights on a validation split (network/refine_roughness.py).

    PYTHONPATH=. python tools/refine_roughness_tune.py features out/splits/val-next --limit 22 --out DIR
    PYTHONPATH=. python tools/refine_roughness_tune.py tune DIR

``features``: each scene through the capture path (:func:`network.evaluation.predict_scene`, the
shipped model), then per sampled mask pixel (at most 1200) what the refinement sees: the angle to
the integrated surface's normal, the distance to the mask's edge, the pixel weight, the decoded maps
and the LP re-rendered at every roughness of :data:`network.refine_roughness.ROUGHNESS_GRID`
(one ``.npz`` and one ``.pkl`` per scene). ``tune``: per object the fit profile at each trust angle,
then a grid over the angle, the broadening, ``T sigma^2`` (only the product matters) and the residual
gate; per setting the per-object roughness correlation over dielectric objects and the per-scene
RMSE (the refined map is the network's shifted per component; clipping to [0, 1] is ignored here).
"""

from __future__ import annotations

import argparse
import itertools
import pickle
import sys
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network import refine_roughness as rr  # noqa: E402
from network.checkpoint import load_checkpoint  # noqa: E402
from network.constant import STATS_FILE, load_statistics  # noqa: E402
from network.evaluation import _fill_nearest, predict_scene  # noqa: E402
from network.infer import DEFAULT_CHECKPOINT  # noqa: E402
from network.statistics import correlation  # noqa: E402
from pbrdf.sensor import projection  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402


def features(root: Path, limit: int, out: Path) -> None:
    """Write the per-scene features (module docs)."""
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    stats = load_statistics(DEFAULT_CHECKPOINT.parent / STATS_FILE)
    out.mkdir(parents=True, exist_ok=True)
    for i in range(limit):
        s = predict_scene(model, ckpt["inputs"], root, i, stats, input_scale=ckpt["input_scale"], baseline=False)
        pred = s.ours
        if pred is None or "depth" not in s.gt:
            continue
        from network.infer import load_input  # noqa: PLC0415

        inp = load_input(root / "samples" / f"{i:06d}.json")
        mask, k, rig = pred["mask"][..., 0] > 0, inp.intrinsics, inp.rig or Rig()
        dist = float(np.median(s.gt["depth"][s.region & (s.gt["depth"] > 0)]))
        labels, _ = ndimage.label(mask)
        angle, depth = rr.normal_trust(pred["normal"], mask, k, dist)
        idx = np.flatnonzero(mask)
        if idx.size > 1200:
            idx = np.sort(np.random.default_rng(0).choice(idx, 1200, replace=False))
        h, w = mask.shape
        z = depth.reshape(-1)[idx]
        pts = projection.pixel_rays(k, h, w).reshape(-1, 3)[idx] * np.where(z > 0, z, dist)[:, None]
        nrm = pred["normal"].reshape(-1, 3)[idx].astype(np.float64)
        vc = -np.sum(nrm * pts, 1) / np.maximum(np.linalg.norm(pts, axis=1) * np.linalg.norm(nrm, axis=1), 1e-12)
        obs = s.maps.reshape(h * w, -1)[idx].astype(np.float64) * (rig.display.radiance / (inp.radiance or 1.0))
        np.savez(out / f"{i:04d}.npz", idx=idx, angle=angle.reshape(-1)[idx],
                 edge=ndimage.distance_transform_edt(mask).reshape(-1)[idx],
                 weight=rr._pixel_weight(obs, pred["metallic"].reshape(-1)[idx], vc), obs=obs,
                 model=rr.lp_profiles(nrm, pts, rig), lab=labels.reshape(-1)[idx], labels=labels)  # fmt: skip
        keep = {"ours": pred, "auto": s.auto_mask, "region": s.region, "gt": s.gt, "objects": s.objects,
                "constant": float(stats["roughness"])}  # fmt: skip
        (out / f"{i:04d}.pkl").write_bytes(pickle.dumps(keep))
        print(i, flush=True)


def _prep(d: dict, z: dict, angles: tuple) -> dict:
    """Per component: the network's mean and the fit profile per trust angle; per object: the truth and shares."""
    pred, labels, region, ob = d["ours"], z["labels"], d["region"], d["objects"]
    rough = pred["roughness"][..., 0].astype(np.float64)
    g = d["gt"]["roughness"].reshape(region.shape).astype(np.float64)
    comp = _fill_nearest({"c": labels * (pred["metallic"][..., 0] < 0.5)}, d["auto"], region)["c"][region]
    net = _fill_nearest({"r": rough}, d["auto"], region)["r"]
    e = (net - g)[region]
    comps = {}
    for k in range(1, int(labels.max()) + 1):
        prof = {}
        for a in angles:
            sel = (z["lab"] == k) & (z["weight"] > 0) & (z["edge"] > 2) & (z["angle"] < a)
            if sel.sum() >= 24:
                prof[a] = rr.object_profile(z["obs"][sel, 3:6], z["model"][:, sel], np.ones(int(sel.sum())))
        comps[k] = {"mean": rough[labels == k].mean(), "prof": prof, "n": (comp == k).sum(), "se": e[comp == k].sum()}
    objs = []
    for i in np.unique(ob[region]):
        sel = region & (ob == i)
        if d["gt"]["metallic"].reshape(region.shape)[sel].mean() < 0.5:
            share = {k: float(np.mean(comp[sel[region]] == k)) for k in comps}
            objs.append({"truth": g[sel].mean(), "net": net[sel].mean(), "share": share})
    const = float(np.sqrt(np.mean((d["constant"] - g[region]) ** 2)))
    return {"comps": comps, "objs": objs, "sse": float(np.sum(e**2)), "n": e.size, "const": const}


def _score(scenes: list[dict], angle: float, params: rr.RoughnessParams) -> dict:
    truth, net, ref, rm_n, rm_r = [], [], [], [], []
    for s in scenes:
        shift = {}
        for k, c in s["comps"].items():
            prof = c["prof"].get(angle)
            if prof is None or prof.min() > params.max_residual:
                continue
            r, lc, ln = rr.map_roughness(prof, c["mean"], params)
            if lc < ln * (1.0 - 1e-3):
                shift[k] = r - c["mean"]
        sse = s["sse"] + sum(2 * v * s["comps"][k]["se"] + s["comps"][k]["n"] * v * v for k, v in shift.items())
        rm_n.append(np.sqrt(s["sse"] / s["n"]))
        rm_r.append(np.sqrt(max(sse, 0.0) / s["n"]))
        for o in s["objs"]:
            truth.append(o["truth"])
            net.append(o["net"])
            ref.append(o["net"] + sum(o["share"][k] * v for k, v in shift.items()))
    return {"r_net": correlation(truth, net)["r"], "r_refined": correlation(truth, ref)["r"],
            "rmse_net": float(np.mean(rm_n)), "rmse_refined": float(np.mean(rm_r)),
            "worse_scenes": int(np.sum(np.array(rm_r) > np.array(rm_n) + 1e-4)), "objects": len(truth)}  # fmt: skip


def tune(folder: Path) -> None:
    """Print the best settings by r (an RMSE above the network's is penalised)."""
    angles = (6, 10, 15, 25, 180)
    scenes = []
    for f in sorted(folder.glob("*.npz")):
        scenes.append(_prep(pickle.loads(f.with_suffix(".pkl").read_bytes()), dict(np.load(f)), angles))
    rows = []
    for a, b, ts, mr in itertools.product(angles, (0, 0.05, 0.1, 0.15), (0.05, 0.1, 0.2, 0.4, 0.8, 1.6),
                                          (0.5, 0.6, 0.7, 0.8, 0.9, 1.0)):  # fmt: skip
        p = rr.RoughnessParams(max_angle_deg=a, broadening=b, temperature=ts / 0.01, sigma=0.1, max_residual=mr)
        rows.append(((a, b, ts, mr), _score(scenes, a, p)))
    rows.sort(key=lambda x: -(x[1]["r_refined"] or 0) + 5 * max(0.0, x[1]["rmse_refined"] - x[1]["rmse_net"]))
    print(f"{len(scenes)} scenes; (angle, broadening, T sigma^2, max residual) -> scores")
    for p, r in rows[:15]:
        print(p, {k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()})


def main() -> None:
    """Run ``features`` or ``tune``."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("features")
    f.add_argument("split", type=Path)
    f.add_argument("--limit", type=int, default=22)
    f.add_argument("--out", type=Path, required=True)
    t = sub.add_parser("tune")
    t.add_argument("folder", type=Path)
    args = p.parse_args()
    torch.set_num_threads(2)
    if args.cmd == "features":
        features(args.split, args.limit, args.out)
    else:
        tune(args.folder)


if __name__ == "__main__":
    main()
