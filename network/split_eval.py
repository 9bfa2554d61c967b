"""Scoring on the fixed test splits, through the real-capture path, with every row a reviewer asks for.

For each scene of a split the raw HDR brackets stored with the sample are processed exactly as a
user's capture is (:func:`network.infer.load_input` on the capture folder: decode, automatic
foreground mask), then every method predicts from that input:

* ``ours`` - the model (:func:`network.infer.predict`);
* ``baseline`` - calibrated colour photometric stereo (:func:`network.evaluate.baseline_predict`);
* ``constant`` - normal (0, 0, 1) and the training set's mean albedo, roughness and metallic
  (:mod:`network.constant`).

Scores are taken on the object coverage of the ground truth (``object >= 0``: dark pixels the
decoder could not measure count), never on the automatic mask; where the automatic mask missed
object pixels a method's prediction is extended from its nearest predicted pixel (what a user
gets at the border of the asset); an empty automatic mask leaves only the constant answer. The
mask's IoU against the coverage is reported beside. Depth: each method's normals are integrated over the
coverage (:mod:`pbrdf.geometry.normal_integration`, what the relief mesh is built from) and
compared with the true depth up to scale (``depth_si_error``, percent). Per metric: the per-scene mean and the
pixel-weighted mean, each with a 95 % bootstrap interval over scenes (:mod:`network.statistics`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pbrdf.data import dataset as pdataset
from pbrdf.data.sample import sample_intrinsics
from pbrdf.data.splits import SPLITS, dataset_split, require_role
from pbrdf.geometry.normal_integration import integrate_normals
from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.errors import NothingToReconstruct
from pbrdf.io.strict_json import dumps_strict

from . import metrics
from .constant import constant_predict
from .data import checkpoint_input_scale
from .evaluate import baseline_predict
from .infer import DEFAULT_DISTANCE, load_input, predict
from .inputs import apply_inputs, checkpoint_inputs
from .lpips import lpips_status
from .statistics import summarize

__all__ = [
    "METHODS",
    "METRICS",
    "ScenePredictions",
    "predict_scene",
    "score",
    "score_scene",
    "summarize_rows",
    "evaluate_split",
    "split_table",
    "split_markdown",
    "write_split_results",
]

#: Rows of every table: key -> label.
METHODS = {
    "ours": "Ours (shipped model)",
    "baseline": "Photometric stereo (calibrated)",
    "constant": "Constant (normal to camera, train means)",
}
#: Columns: (key, header, higher is better).
METRICS = (
    ("normal_mae", "Normal MAE (deg)", False),
    ("albedo_psnr", "Albedo PSNR (dB)", True),
    ("albedo_si_psnr", "Albedo si-PSNR (dB)", True),
    ("albedo_lpips", "Albedo LPIPS", False),
    ("roughness_rmse", "Roughness RMSE", False),
    ("metallic_rmse", "Metallic RMSE", False),
    ("depth_si_error", "Depth si-error (%)", False),
)
_GT_KEYS = ("normal", "albedo", "roughness", "metallic", "mask")


def _fill_nearest(pred: Mapping[str, np.ndarray], have: np.ndarray, region: np.ndarray) -> dict[str, np.ndarray]:
    """Extend every map from the pixels in ``have`` to ``region`` by nearest-neighbour copy."""
    from scipy import ndimage  # noqa: PLC0415

    out = {}
    missing = region & ~have
    if not missing.any():
        return {k: np.asarray(v) for k, v in pred.items()}
    _, (iy, ix) = ndimage.distance_transform_edt(~have, return_indices=True)
    for k, v in pred.items():
        v = np.asarray(v)
        filled = v.copy()
        filled[missing] = v[iy[missing], ix[missing]]
        out[k] = filled
    return out


def score(
    pred: Mapping[str, np.ndarray],
    gt: Mapping[str, np.ndarray],
    region: np.ndarray,
    *,
    lpips: bool,
    intrinsics: np.ndarray | None = None,
) -> dict:
    """Every :data:`METRICS` value of one prediction on ``region`` (None for maps it does not predict).

    With ``intrinsics`` and a ground-truth ``depth``, the predicted normals are integrated over
    ``region`` (:func:`network.infer.relief_depth`'s integration, what the relief mesh is made of)
    and compared with the true depth up to scale (:func:`network.metrics.si_depth_error`).
    """

    def chan(a: np.ndarray) -> np.ndarray:
        return a[..., None] if a.ndim == 2 else a

    out: dict[str, float | None] = {k: None for k, _, _ in METRICS}
    if "normal" in pred:
        out["normal_mae"] = metrics.normal_mae_deg(pred["normal"], gt["normal"], region)
    if "albedo" in pred:
        out["albedo_psnr"] = metrics.psnr(pred["albedo"], gt["albedo"], region)
        out["albedo_si_psnr"] = metrics.si_psnr(pred["albedo"], gt["albedo"], region)
        if lpips:
            out["albedo_lpips"] = metrics.lpips(pred["albedo"], gt["albedo"], region)
    for k in ("roughness", "metallic"):
        if k in pred:
            out[f"{k}_rmse"] = metrics.rmse(chan(pred[k]), chan(gt[k]), region)
    if intrinsics is not None and "depth" in gt and "normal" in pred and region.any():
        valid = region & (gt["depth"] > 0)
        if valid.any():
            depth = integrate_normals(pred["normal"], region, intrinsics, DEFAULT_DISTANCE)
            out["depth_si_error"] = metrics.si_depth_error(depth, gt["depth"], valid)
    return out


@dataclass
class ScenePredictions:
    """One scene processed through the real-capture path, with every method's prediction.

    Attributes:
        index: sample index in its dataset.
        meta: the sample's sidecar.
        maps: ``(H, W, 9)`` decoded nine maps.
        auto_mask: ``(H, W)`` the automatic foreground mask the methods saw.
        region: ``(H, W)`` object coverage of the ground truth (where scores are taken).
        gt: ground-truth ``normal``, ``albedo``, ``roughness``, ``metallic``.
        preds: method -> maps extended over ``region`` (what is scored).
        ours: the model's prediction as a user gets it (on ``auto_mask``, 0 elsewhere), or None.
        objects: ``(H, W)`` object id per pixel (index into the sidecar's ``objects``, -1 off
            objects), or None for datasets without the channel.
        intrinsics: ``K (3, 3)`` of the maps' grid (the capture's calibration), or None (no depth score).
    """

    index: int
    meta: dict
    maps: np.ndarray
    auto_mask: np.ndarray
    region: np.ndarray
    gt: dict
    preds: dict
    ours: dict | None
    objects: np.ndarray | None = None
    intrinsics: np.ndarray | None = None


def predict_scene(
    model,
    variant: str,
    root: str | Path,
    index: int,
    stats: Mapping[str, Any],
    *,
    input_scale: str = "exposure-invariant",
    baseline: bool = True,
) -> ScenePredictions:
    """Run every method on one sample's raw brackets exactly as on a user's capture folder.

    ``variant`` and ``input_scale`` are the checkpoint's; the display radiance comes from the
    capture's ``capture.json`` (:func:`network.infer.load_input`), as for a user.
    ``baseline=False`` leaves out photometric stereo (``preds["baseline"]`` is empty), for
    diagnostics of the model alone.

    Raises:
        ValueError: the sample has no raw brackets, or its decoded grid differs from the truth.
    """
    root = Path(root)
    stored = _stored(root, index)
    keys = _GT_KEYS + tuple(k for k in ("object", "depth") if k in stored)
    sample, meta = pdataset.read_sample(root, index, keys=keys)
    region = sample["object"] >= 0 if "object" in sample else sample["mask"]
    raw = pdataset.sample_paths(root, index).raw
    if not raw.is_dir():
        raise ValueError(f"{root}: sample {index} has no raw brackets (render splits with headless/render.py --split)")
    inp = load_input(raw)  # the user's path: decode + automatic foreground mask
    maps, auto = inp.maps, inp.mask
    if maps.shape[:2] != region.shape:
        raise ValueError(f"{raw}: decoded grid {maps.shape[:2]} differs from the ground truth {region.shape}")
    auto = np.asarray(auto, dtype=bool)
    constant = constant_predict(stats, region)
    preds: dict[str, Mapping[str, np.ndarray]] = {"constant": constant}
    ours = None
    if auto.any():
        x = apply_inputs(torch.from_numpy(np.ascontiguousarray(maps.transpose(2, 0, 1))), variant)
        try:
            ours = predict(
                model, x.permute(1, 2, 0).contiguous().numpy(), auto, inputs=variant, input_scale=input_scale,
                radiance=inp.radiance,
            )  # fmt: skip
        except NothingToReconstruct:  # a mask that vanishes at the network's grid: nothing was reconstructed
            ours = None
        preds["ours"] = _fill_nearest(ours, auto, region) if ours is not None else constant
        if not baseline or (meta.get("rig") or {}).get("display", {}).get("pattern", "rgb_halves") == "white":
            preds["baseline"] = {}  # not asked for, or n/a: colour photometric stereo needs the colour regions
        else:
            preds["baseline"] = _fill_nearest(baseline_predict(maps, auto, meta), auto, region)
    else:
        preds["ours"] = preds["baseline"] = constant
    gt = {k: sample[k] for k in ("normal", "albedo", "roughness", "metallic")}
    k = None
    if "depth" in sample:
        gt["depth"] = sample["depth"]
        sidecar = pdataset.sample_paths(root, index).sidecar
        k = sample_intrinsics(meta, region.shape, sidecar) if "intrinsics" in meta else None
    objects = np.rint(sample["object"]).astype(np.int64) if "object" in sample else None
    return ScenePredictions(index, meta, maps, auto, region, gt, preds, ours, objects, k)


def score_scene(scene: ScenePredictions, *, lpips: bool) -> dict[str, Any]:
    """The per-scene row: pixels, mask IoU, mesh, material kinds and every method's scores."""
    union = int((scene.auto_mask | scene.region).sum())
    row: dict[str, Any] = {
        "index": scene.index,
        "pixels": int(scene.region.sum()),
        "mask_iou": float((scene.auto_mask & scene.region).sum() / union) if union else None,
        "mesh": (scene.meta.get("objects") or [{}])[0].get("mesh"),
        "materials": sorted({m.get("kind", "?") for m in (scene.meta.get("materials") or {}).values()}),
    }
    for m in METHODS:
        row[m] = score(scene.preds[m], scene.gt, scene.region, lpips=lpips, intrinsics=scene.intrinsics)
    if scene.objects is not None:
        # One row per object seen (multi-object scenes): its mesh, material and scores, no LPIPS.
        specs = scene.meta.get("objects") or []
        mats = scene.meta.get("materials") or {}
        row["objects"] = []
        for i in np.unique(scene.objects[scene.region]).tolist():
            sel = scene.region & (scene.objects == i)
            spec = specs[i] if 0 <= i < len(specs) else {}
            obj = {"id": int(i), "pixels": int(sel.sum()), "mesh": spec.get("mesh"),
                   "material": (mats.get(spec.get("material")) or {}).get("kind")}  # fmt: skip
            for m in METHODS:
                obj[m] = score(scene.preds[m], scene.gt, sel, lpips=False)
            row["objects"].append(obj)
    return row


def summarize_rows(rows: list[Mapping[str, Any]]) -> dict[str, Any]:
    """Per method and metric :func:`~network.statistics.summarize` of the rows, and the mask IoU."""
    weights = [r["pixels"] for r in rows]
    methods = {m: {k: summarize([r[m][k] for r in rows], weights) for k, _, _ in METRICS} for m in METHODS}
    out = {"methods": methods, "mask_iou": summarize([r["mask_iou"] for r in rows])}
    objs = [o for r in rows for o in r.get("objects") or ()]
    if objs:  # per-object means: every object counts once, however large it is in the frame
        w = [o["pixels"] for o in objs]
        out["objects"] = len(objs)
        out["per_object"] = {
            m: {k: summarize([o[m][k] for o in objs], w) for k, _, _ in METRICS if k != "albedo_lpips"} for m in METHODS
        }
    return out


def evaluate_split(
    model: torch.nn.Module,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    stats: Mapping[str, Any],
    *,
    limit: int | None = None,
    lpips: bool | None = None,
    require_test: bool = True,
    progress: bool = False,
    jobs: int = 1,
    checkpoint_path: str | Path | None = None,
) -> dict[str, Any]:
    """Score the model, the baseline and the constant predictor on one split through the capture path.

    Args:
        model: the loaded model (:func:`network.checkpoint.load_checkpoint`).
        checkpoint: its checkpoint dict (for the input variant and scale).
        root: the split's dataset folder (rendered with ``headless/render.py --split``).
        stats: training statistics (:func:`network.constant.load_statistics`).
        limit: score only the first ``limit`` scenes.
        lpips: compute albedo LPIPS (default: when its weights are installed).
        require_test: refuse anything but a test split.
        progress: show a progress bar.
        jobs: worker processes (each loads ``checkpoint_path`` onto ``model``'s device and runs one
            torch thread); scenes are independent, so the rows are the same for any ``jobs``.
        checkpoint_path: the checkpoint file (needed with ``jobs > 1``).

    Returns:
        JSON-ready dict: ``split``, ``scenes``, ``methods`` -> metric -> :func:`~network.statistics.summarize`
        output, ``mask_iou`` summary, ``per_scene`` rows and ``seconds``.

    Raises:
        ValueError: not a test split (with ``require_test``), no samples, or samples without raw
            brackets.
    """
    root = Path(root)
    name = require_role(root, ("test",), "the final evaluation") if require_test else dataset_split(root)
    variant = checkpoint_inputs(checkpoint)
    scale = checkpoint_input_scale(checkpoint)
    if lpips is None:
        lpips = lpips_status()[0]
    indices = sorted(pdataset.completed_indices(root, verify_hash=False))[:limit]
    if not indices:
        raise ValueError(f"{root}: no completed samples")
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=len(indices), desc=f"evaluate {name or root.name}", unit="scene")
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    if jobs > 1:
        if checkpoint_path is None:
            raise ValueError("jobs > 1 needs checkpoint_path (every worker loads the model)")
        import multiprocessing  # noqa: PLC0415
        from concurrent.futures import ProcessPoolExecutor  # noqa: PLC0415

        device = str(next(model.parameters()).device)  # every worker puts its copy where the model is
        init = (str(checkpoint_path), variant, str(root), dict(stats), bool(lpips), device)
        ctx = multiprocessing.get_context("spawn")  # never fork a process that has run torch
        with ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_worker_init, initargs=init) as pool:
            for row in pool.map(_worker_row, indices):
                rows.append(row)
                if bar is not None:
                    bar.update()
    else:
        for i in indices:
            scene = predict_scene(model, variant, root, i, stats, input_scale=scale)
            rows.append(score_scene(scene, lpips=lpips))
            if bar is not None:
                bar.update()
    if bar is not None:
        bar.close()
    return {
        "split": name,
        "description": SPLITS[name].description if name in SPLITS else None,
        "data": str(root),
        "scenes": len(rows),
        "input": variant,
        "lpips": bool(lpips),
        **summarize_rows(rows),
        "per_scene": rows,
        "seconds": time.perf_counter() - t0,
    }


_WORKER: dict[str, Any] = {}


def _worker_init(checkpoint_path: str, variant: str, root: str, stats: dict, lpips: bool, device: str) -> None:
    """Load the model once per worker process on ``device``, with one torch thread (the workers share the cores)."""
    from .checkpoint import load_checkpoint  # noqa: PLC0415

    torch.set_num_threads(1)
    model, ckpt = load_checkpoint(checkpoint_path)
    model.to(device)
    _WORKER.update(model=model, variant=variant, scale=ckpt["input_scale"], root=Path(root), stats=stats, lpips=lpips)


def _worker_row(index: int) -> dict[str, Any]:
    w = _WORKER
    scene = predict_scene(w["model"], w["variant"], w["root"], index, w["stats"], input_scale=w["scale"])
    return score_scene(scene, lpips=w["lpips"])


def _stored(root: Path, index: int) -> set[str]:
    """The optional maps a sample stores (``object``: not in datasets rendered before it existed)."""
    meta = pdataset.check_complete(root, index, verify_hash=False)
    return {c.split(".")[0] for c in meta.get("channels", [])}


def _cell(s: Mapping[str, Any], key: str, digits: int) -> str:
    mean, ci = s.get(key), s.get("ci" if key == "mean" else "weighted_ci")
    if mean is None:
        return "n/a"
    if not ci or ci[0] is None:
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def split_table(result: Mapping[str, Any], key: str = "mean") -> tuple[list[str], list[list[str]]]:
    """Header and rows (one per method) of a summary; ``key`` ``"mean"`` or ``"weighted_mean"``.

    Each cell is ``mean [low, high]`` (95 % bootstrap interval) or ``n/a``.
    """
    cols = [(k, h) for k, h, _ in METRICS if result.get("lpips") or k != "albedo_lpips"]
    digits = {"normal_mae": 1, "albedo_psnr": 1, "albedo_si_psnr": 1}
    header = ["method"] + [h for _, h in cols]
    rows = [[label] + [_cell(result["methods"][m][k], key, digits.get(k, 3)) for k, _ in cols]
            for m, label in METHODS.items()]  # fmt: skip
    return header, rows


def split_markdown(result: Mapping[str, Any]) -> str:
    """Markdown tables (per-scene means, pixel-weighted means) of one :func:`evaluate_split` result."""
    lines = [f"### {result.get('split') or result['data']} ({result['scenes']} scenes)", ""]
    if result.get("description"):
        lines += [result["description"] + ".", ""]
    for title, key in (("Per-scene mean [95 % CI]", "mean"), ("Pixel-weighted mean [95 % CI]", "weighted_mean")):
        header, rows = split_table(result, key)
        lines += [f"{title}:", "", "| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        lines.append("")
    if result.get("per_object") and result.get("objects", 0) > result["scenes"]:
        per = {"methods": result["per_object"], "lpips": False}
        header, rows = split_table(per, "mean")
        lines += [f"Per-object mean [95 % CI] ({result['objects']} objects):", ""]
        lines += ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        lines.append("")
    iou = result["mask_iou"]
    lines.append(f"Automatic foreground mask vs object coverage: IoU {_cell(iou, 'mean', 3)} (per-scene mean).")
    lines.append("")
    return "\n".join(lines)


def write_split_results(results: list[Mapping[str, Any]], out_dir: str | Path) -> list[Path]:
    """Write ``test_splits.json`` (strict JSON) and ``test_splits.md`` atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = "\n".join(split_markdown(r) for r in results)
    return [
        atomic_write_text(out / "test_splits.json", dumps_strict({"splits": list(results)}) + "\n"),
        atomic_write_text(out / "test_splits.md", md),
    ]
