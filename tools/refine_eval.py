"""Network alone against network + refinement on the test splits, albedo and roughness, with paired intervals.

    PYTHONPATH=. python tools/refine_eval.py out/splits/test-procedural [...] [--limit N] [--roughness]
        [--png FIG] [--json F]

The refinement (network/refine.py) changes the albedo and, with ``--roughness``, the roughness, so
only those are scored here (the full evaluation, ``headless/evaluate.py --split test --refine``,
scores every map but integrates depth for every method, minutes per split). Each scene goes through the capture path of
:func:`network.evaluation.predict_scene` (raw brackets -> decode -> automatic mask -> model ->
refinement with the median true depth as the capture's one distance). Per split: albedo PSNR and
si-PSNR of both, the paired per-scene difference with its 95 % bootstrap interval
(:func:`network.statistics.summarize`), the refinement's time per capture, and the per-kind split
(``pplastic``, ``conductor``, ``measured``). Roughness (network/refine_roughness.py): per-scene RMSE of
the network, the refinement and the constant, the paired difference, and the per-object correlation
with the truth over dielectric objects (:func:`network.statistics.correlation`, as ``evaluate.py``'s
report); ``--roughness`` turns the roughness refinement on (:data:`network.refine.REFINE_ROUGHNESS`, off
by default). ``--png`` draws the per-scene albedo deltas.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network import metrics  # noqa: E402
from network import refine as refine_module  # noqa: E402
from network.checkpoint import load_checkpoint  # noqa: E402
from network.constant import STATS_FILE, load_statistics  # noqa: E402
from network.evaluation import predict_scene  # noqa: E402
from network.infer import DEFAULT_CHECKPOINT  # noqa: E402
from network.statistics import correlation, summarize, summary_text  # noqa: E402


def _row(scene) -> dict:
    region, gt = scene.region, scene.gt
    kinds = sorted({m.get("kind", "?") for m in scene.meta["materials"].values()})
    row = {"index": scene.index, "kinds": kinds, "objects": len(scene.meta["objects"]), **scene.refine}
    for m in ("ours", "refined"):
        row[f"{m}_psnr"] = metrics.psnr(scene.preds[m]["albedo"], gt["albedo"], region)
        row[f"{m}_si_psnr"] = metrics.si_psnr(scene.preds[m]["albedo"], gt["albedo"], region)
    row["true_over_pred"] = metrics.ls_scale(scene.preds["ours"]["albedo"], gt["albedo"], region)
    preds = {"ours": scene.preds["ours"], "refined": scene.preds["refined"], "constant": scene.preds["constant"]}
    g = gt["roughness"].reshape(region.shape)[..., None]
    for m, p in preds.items():
        row[f"{m}_rough_rmse"] = metrics.rmse(p["roughness"].reshape(g.shape), g, region)
    row["objects_rough"] = []
    if scene.objects is not None:
        for i in np.unique(scene.objects[region]).tolist():
            sel = region & (scene.objects == i)
            if float(np.mean(gt["metallic"].reshape(region.shape)[sel])) < 0.5:  # dielectric objects only
                row["objects_rough"].append({m: float(np.mean(p["roughness"].reshape(region.shape)[sel]))
                                             for m, p in {**preds, "truth": gt}.items()})  # fmt: skip
    return row


def _rough_table(name: str, rows: list[dict]) -> str:
    """Roughness: per-scene RMSE (paired delta) and per-object correlation, network vs refinement."""
    objs = [o for r in rows for o in r["objects_rough"]]
    corr = {m: correlation([o["truth"] for o in objs], [o[m] for o in objs]) for m in ("ours", "refined")}
    rm = {m: [r[f"{m}_rough_rmse"] for r in rows] for m in ("ours", "refined", "constant")}
    d = summarize([b - a for a, b in zip(rm["ours"], rm["refined"], strict=True)])
    changed = sum(1 for r in rows for o in (r.get("roughness") or {}).values() if not o.get("kept", True))
    ci = {m: summary_text(c, 2, key="r") for m, c in corr.items()}
    return "\n".join([
        f"roughness, {name}: {len(objs)} dielectric objects, {changed} objects refined",
        "| r network | r refined | RMSE network | RMSE refined | delta [95 % CI] | RMSE constant |",
        "|---|---|---:|---:|---:|---:|",
        f"| {ci['ours']} | {ci['refined']} | {np.mean(rm['ours']):.3f} | {np.mean(rm['refined']):.3f} | "
        f"{summary_text(d, 3, signed=True)} | {np.mean(rm['constant']):.3f} |",
    ])  # fmt: skip


def _table(name: str, rows: list[dict]) -> str:
    lines = [f"### {name} ({len(rows)} scenes)", "",
             "| scenes | n | network PSNR | + refinement PSNR | delta [95 % CI] | si-PSNR | refined | s median / max |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    groups = {"all": rows}
    for kind in ("pplastic", "conductor", "measured"):
        groups[f"only {kind}"] = [r for r in rows if r["kinds"] == [kind]]
    groups["mixed"] = [r for r in rows if len(r["kinds"]) > 1]
    for label, rs in groups.items():
        if not rs:
            continue
        a, b = [r["ours_psnr"] for r in rs], [r["refined_psnr"] for r in rs]
        d = summarize([y - x for x, y in zip(a, b, strict=True)])
        sec = [r["seconds"] for r in rs]
        lines.append(f"| {label} | {len(rs)} | {np.mean(a):.2f} | {np.mean(b):.2f} | {summary_text(d, 2)} | "
                     f"{np.mean([r['ours_si_psnr'] for r in rs]):.2f} | {sum(r['refined'] for r in rs)} | "
                     f"{np.median(sec):.1f} / {np.max(sec):.1f} |")  # fmt: skip
    return "\n".join(lines)


def _png(path: Path, results: dict) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, len(results), figsize=(4 * len(results), 3.4), squeeze=False, sharey=True)
    colours = {"pplastic": "tab:blue", "conductor": "tab:orange", "measured": "tab:green"}
    for ax, (name, rows) in zip(axes[0], results.items(), strict=True):
        x = np.array([r["ours_psnr"] for r in rows])
        d = np.array([r["refined_psnr"] - r["ours_psnr"] for r in rows])
        c = [colours.get(r["kinds"][0], "tab:grey") if len(r["kinds"]) == 1 else "tab:grey" for r in rows]
        ax.scatter(x, d, c=c, s=14)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_title(f"{name}: mean {d.mean():+.2f} dB", fontsize=9)
        ax.set_xlabel("network albedo PSNR (dB)")
    axes[0][0].set_ylabel("refinement - network (dB)")
    fig.suptitle("per-scene albedo PSNR change (blue pplastic, orange conductor, green table pBRDF, grey mixed)",
                 fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    """Print the tables; optionally write the per-scene rows and the figure."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("splits", nargs="+", type=Path)
    p.add_argument("--limit", type=int)
    p.add_argument("--png", type=Path)
    p.add_argument("--json", type=Path)
    p.add_argument("--roughness", action="store_true", help="also refine the roughness (network/refine_roughness.py)")
    args = p.parse_args()
    if args.roughness:
        refine_module.REFINE_ROUGHNESS = True  # read by network.evaluation at each refinement
    torch.set_num_threads(2)
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    stats = load_statistics(DEFAULT_CHECKPOINT.parent / STATS_FILE)
    results = {}
    for root in args.splits:
        n = len(list((root / "samples").glob("*.json")))
        rows = []
        for i in range(min(n, args.limit or n)):
            scene = predict_scene(model, ckpt["inputs"], root, i, stats, input_scale=ckpt["input_scale"],
                                  baseline=False, refine=True)  # fmt: skip
            rows.append(_row(scene))
            print(json.dumps({"split": root.name, **rows[-1]}, default=float), flush=True)
        results[root.name] = rows
        print(_table(root.name, rows), flush=True)
        print(_rough_table(root.name, rows), flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=float))
    if args.png:
        _png(args.png, results)


if __name__ == "__main__":
    main()
