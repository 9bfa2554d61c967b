"""The evaluation: a model against the ground truth, photometric stereo and a constant answer, with intervals.

Every scene of a rendered dataset (a test split, or any folder of samples with ground truth) is
given to each method as a user would give it:

* a sample that stores its raw HDR brackets (every split, the demo's scenes) goes through the
  real-capture path, :func:`network.infer.load_input` on the capture folder (decode, automatic
  foreground mask), with the display radiance of its ``capture.json``;
* any other sample gives its stored nine maps and mask, with the display radiance of its sidecar.

Methods (:data:`METHODS`): ``ours``, the model (:func:`network.infer.predict`, which applies the
checkpoint's input variant), labelled by the checkpoint (:func:`model_label`); ``baseline``,
calibrated colour photometric stereo (:func:`network.baseline.predict_sample`; n/a under the white
display); ``constant``, normal (0, 0, 1) and the training set's mean albedo, roughness and metallic
(:mod:`network.constant`); ``object_mean``, an oracle that knows each object's mean albedo,
roughness and metallic but nothing of their variation (:func:`object_mean_predict`; n/a on a
scene whose objects are uniform, where it would equal the truth), so a table shows whether a
model recovers the variation within an object. Only an empty mask (:class:`pbrdf.io.errors.NothingToReconstruct`)
leaves a scene to the constant answer; any other failure of the model (a broken checkpoint that
predicts NaN) stops the evaluation.

Scores are taken on the object coverage of the ground truth (``object >= 0``, else the sample's
mask: dark pixels the decoder could not measure count), never on the automatic mask; where the
automatic mask missed object pixels a method's prediction is extended from its nearest predicted
pixel (what a user gets at the border of the asset). The mask's IoU against the coverage is
reported beside. Depth: each method's normals are integrated over the coverage
(:mod:`pbrdf.geometry.normal_integration`, what the relief mesh is built from) and compared with
the true depth up to scale (``depth_si_error``, percent). Per metric: the per-scene mean and the
pixel-weighted mean, each with a 95 % bootstrap interval over scenes (:mod:`network.statistics`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M
from pbrdf.data.sample import sample_intrinsics
from pbrdf.data.splits import SPLITS, dataset_split
from pbrdf.geometry.normal_integration import integrate_normals
from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.errors import NothingToReconstruct
from pbrdf.io.strict_json import dumps_strict

from . import baseline as ps
from . import metrics
from .constant import constant_predict
from .data import checkpoint_input_scale
from .infer import DEFAULT_CHECKPOINT, load_input, predict
from .inputs import checkpoint_inputs
from .light_input import scene_light
from .lpips import lpips_status
from .statistics import correlation, summarize, summary_text

if TYPE_CHECKING:
    from pbrdf.sensor.rig import Rig

__all__ = [
    "METHODS",
    "METRICS",
    "ScenePredictions",
    "model_label",
    "object_mean_predict",
    "predict_scene",
    "score",
    "score_scene",
    "summarize_rows",
    "evaluate_dataset",
    "summary_table",
    "results_markdown",
    "write_results",
]

#: Rows of every table: key -> label (``ours`` is labelled by its checkpoint, :func:`model_label`).
METHODS = {
    "ours": "Ours",
    "baseline": "Photometric stereo (calibrated)",
    "constant": "Constant (normal to camera, train means)",
    "object_mean": "Per-object mean (oracle: each object's mean material, no texture)",
    "refined": "Ours + refinement (network/refine.py)",
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


def model_label(checkpoint_path: str | Path | None) -> str:
    """The ``ours`` row's label: which checkpoint was scored (``shipped model`` for the default one).

    Example:
        >>> model_label("runs/engine-small/best.pt"), model_label(None)
        ('Ours (engine-small/best.pt)', 'Ours')
        >>> model_label(DEFAULT_CHECKPOINT)
        'Ours (shipped model)'
    """
    if checkpoint_path is None:
        return METHODS["ours"]
    path = Path(checkpoint_path)
    if path.resolve() == Path(DEFAULT_CHECKPOINT).resolve():
        return "Ours (shipped model)"
    return f"Ours ({path.parent.name}/{path.name})" if path.parent.name else f"Ours ({path.name})"


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


def object_mean_predict(
    gt: Mapping[str, np.ndarray], region: np.ndarray, objects: np.ndarray | None, *, tol: float = 1e-4
) -> dict[str, np.ndarray]:
    """Each object's mean true albedo, roughness and metallic over its pixels; ``{}`` if no object varies.

    Args:
        gt: true ``albedo (H, W, 3)``, ``roughness (H, W)``, ``metallic (H, W)``.
        region: ``(H, W)`` bool, the object coverage.
        objects: ``(H, W)`` object id per pixel, or None (the whole region is one object).
        tol: a quantity whose standard deviation within every object is at most this is uniform.

    Returns:
        The three maps (0 off the region), or ``{}`` when every object is uniform in all three.

    Example:
        >>> gt = {"albedo": np.zeros((1, 2, 3)), "roughness": np.array([[0.2, 0.6]]), "metallic": np.zeros((1, 2))}
        >>> object_mean_predict(gt, np.ones((1, 2), bool), None)["roughness"].tolist()
        [[0.4, 0.4]]
    """
    ids = np.zeros(region.shape, np.int64) if objects is None else np.asarray(objects)
    out = {k: np.zeros_like(np.asarray(gt[k], dtype=np.float64)) for k in ("albedo", "roughness", "metallic")}
    varies = False
    for i in np.unique(ids[region]):
        sel = region & (ids == i)
        for k, v in out.items():
            values = np.asarray(gt[k], dtype=np.float64)[sel]
            varies |= bool(values.std(axis=0).max() > tol)
            v[sel] = values.mean(axis=0)
    return out if varies else {}


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
            depth = integrate_normals(pred["normal"], region, intrinsics, DEFAULT_DISTANCE_M)
            out["depth_si_error"] = metrics.si_depth_error(depth, gt["depth"], valid)
    return out


@dataclass
class ScenePredictions:
    """One scene given to every method as a user's input (:func:`predict_scene`), with their predictions.

    Attributes:
        index: sample index in its dataset.
        meta: the sample's sidecar.
        maps: ``(H, W, 9)`` nine maps (decoded from the raw brackets, else the stored ones).
        auto_mask: ``(H, W)`` the mask the methods saw (automatic foreground mask, else the stored one).
        region: ``(H, W)`` object coverage of the ground truth (where scores are taken).
        gt: ground-truth ``normal``, ``albedo``, ``roughness``, ``metallic``.
        preds: method -> maps extended over ``region`` (what is scored).
        ours: the model's prediction as a user gets it (on ``auto_mask``, 0 elsewhere), or None.
        objects: ``(H, W)`` object id per pixel (index into the sidecar's ``objects``, -1 off
            objects), or None for datasets without the channel.
        intrinsics: ``K (3, 3)`` of the maps' grid (the capture's calibration), or None (no depth score).
        refine: with the refinement, what it did (``refined``, ``seconds``, ``message``), else None.
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
    refine: dict | None = None


def predict_scene(
    model,
    variant: str,
    root: str | Path,
    index: int,
    stats: Mapping[str, Any],
    *,
    input_scale: str = "exposure-invariant",
    baseline: bool = True,
    distance_scale: float = 1.0,
    refine: bool = False,
    capture: str | Path | None = None,
    rig: Rig | None = None,
) -> ScenePredictions:
    """Run every method on one sample as on a user's input (its capture folder when it has raw brackets).

    ``variant`` and ``input_scale`` are the checkpoint's; the display radiance comes from the
    capture's ``capture.json`` or the sample's sidecar (:func:`network.infer.load_input`), as for a
    user. ``baseline=False`` leaves out photometric stereo (``preds["baseline"]`` is empty), for
    diagnostics of the model alone. A ``light_input`` model is given the scene's one distance
    (:func:`network.light_input.scene_light`) times ``distance_scale``. ``refine=True`` adds the
    ``refined`` row: the model's maps through :func:`network.refine.refine` with the sample's rig
    and one distance, the median true depth of the object times ``distance_scale`` (what a
    capture's ``distance_m`` gives, a tape measure's error included; never the per-pixel depth).
    ``capture``: a capture folder of this scene to decode instead of its own raw brackets
    (:mod:`network.robustness`: the same scene through another rig), decoded with
    ``rig`` when given (a calibrated rig file's, as ``headless/infer.py --rig``).

    Raises:
        ValueError: the decoded grid differs from the truth, or the model fails on a non-empty
            mask (e.g. it predicts NaN: a broken checkpoint).
    """
    root = Path(root)
    stored = _stored(root, index)
    keys = _GT_KEYS + tuple(k for k in ("object", "depth") if k in stored)
    sample, meta = psample.read_sample(root, index, keys=keys)
    region = sample["object"] >= 0 if "object" in sample else sample["mask"].astype(bool)
    paths = psample.sample_paths(root, index)
    source = paths.raw if paths.raw.is_dir() else paths.sidecar  # the raw brackets: the user's capture path
    source = Path(capture) if capture is not None else source
    inp = load_input(source, rig=rig)
    maps, auto = inp.maps, inp.mask
    if maps.shape[:2] != region.shape:
        raise ValueError(f"{source}: decoded grid {maps.shape[:2]} differs from the ground truth {region.shape}")
    auto = np.asarray(auto, dtype=bool)
    constant = constant_predict(stats, region)
    preds: dict[str, Mapping[str, np.ndarray]] = {"constant": constant}
    ours = None
    # Colour photometric stereo needs the colour regions: n/a under a white display, or when not asked for.
    with_ps = baseline and (meta.get("rig") or {}).get("display", {}).get("pattern", "rgb_halves") != "white"
    if auto.any():
        try:
            light = scene_light(model, inp, sample.get("depth"), region, distance_scale)
            ours = predict(model, maps, auto, inputs=variant, input_scale=input_scale, radiance=inp.radiance,
                           light=light)  # fmt: skip
        except NothingToReconstruct:  # a mask that vanishes at the network's grid: nothing was reconstructed
            ours = None
        preds["ours"] = _fill_nearest(ours, auto, region) if ours is not None else constant
        if not with_ps:
            preds["baseline"] = {}
        else:
            found = ps.predict_sample(maps, auto, meta)
            preds["baseline"] = _fill_nearest({k: found[k] for k in ("normal", "albedo")}, auto, region)
    else:  # nothing detected: every method falls back to the constant, photometric stereo on its own maps only
        preds["ours"] = constant
        preds["baseline"] = {k: constant[k] for k in ("normal", "albedo")} if with_ps else {}
    gt = {k: sample[k] for k in ("normal", "albedo", "roughness", "metallic")}
    k = None
    if "depth" in sample:
        gt["depth"] = sample["depth"]
        sidecar = psample.sample_paths(root, index).sidecar
        k = sample_intrinsics(meta, region.shape, sidecar) if "intrinsics" in meta else None
    objects = np.rint(sample["object"]).astype(np.int64) if "object" in sample else None
    preds["object_mean"] = object_mean_predict(gt, region, objects)
    preds["refined"], info = {}, None
    if refine:
        preds["refined"], info = _refined(ours, preds["ours"], inp, gt, region, auto, distance_scale)
    return ScenePredictions(index, meta, maps, auto, region, gt, preds, ours, objects, k, info)


def _refined(ours, fallback, inp, gt: dict, region: np.ndarray, auto: np.ndarray,
             distance_scale: float = 1.0) -> tuple[dict, dict]:  # fmt: skip
    """The ``refined`` row's maps (extended over ``region``) and what the refinement did."""
    from pbrdf.sensor.rig import Rig  # noqa: PLC0415

    from .refine import REFINE_ROUGHNESS, refine  # noqa: PLC0415

    if ours is None:
        return fallback, {"refined": False, "seconds": 0.0, "message": "no prediction"}
    depth = gt.get("depth")
    valid = region & (depth > 0) if depth is not None else None
    distance = float(np.median(depth[valid])) if valid is not None and valid.any() else inp.distance_m
    distance = None if distance is None else distance * distance_scale
    res = refine(ours, inp.maps, inp.intrinsics, inp.rig or Rig(), inp.radiance, distance, roughness=REFINE_ROUGHNESS)
    info = {"refined": res.refined, "seconds": res.seconds, "message": res.message,
            "roughness": {str(k): v for k, v in res.roughness.items()},
            "guard": {str(k): v for k, v in res.guard.items()}}  # fmt: skip
    return _fill_nearest(res.pred, auto, region), info


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
    scored = [m for m in METHODS if m != "refined" or scene.refine is not None]  # refined: only when asked
    for m in scored:
        row[m] = score(scene.preds[m], scene.gt, scene.region, lpips=lpips, intrinsics=scene.intrinsics)
    if scene.refine is not None:
        row["refine"] = scene.refine
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
            for m in scored:
                obj[m] = score(scene.preds[m], scene.gt, sel, lpips=False)
            # mean roughness of the truth and of each method, and the true metallic: the per-object
            # roughness correlation over dielectric objects (summarize_rows)
            means = {m: scene.preds[m] for m in scored if "roughness" in scene.preds[m]} | {"truth": scene.gt}
            obj["roughness_mean"] = {m: float(np.mean(p["roughness"][sel], dtype=np.float64)) for m, p in means.items()}
            obj["metallic_truth"] = float(np.mean(scene.gt["metallic"][sel], dtype=np.float64))
            row["objects"].append(obj)
    return row


def summarize_rows(rows: list[Mapping[str, Any]]) -> dict[str, Any]:
    """Per method and metric :func:`~network.statistics.summarize` of the rows, and the mask IoU."""
    weights = [r["pixels"] for r in rows]
    scored = [m for m in METHODS if all(m in r for r in rows)]  # the refined row only where it ran
    methods = {m: {k: summarize([r[m][k] for r in rows], weights) for k, _, _ in METRICS} for m in scored}
    out = {"methods": methods, "mask_iou": summarize([r["mask_iou"] for r in rows])}
    if any(r.get("refine") for r in rows):  # paired per-scene differences, refinement minus network
        out["paired"] = {
            k: summarize([None if r["refined"][k] is None or r["ours"][k] is None else r["refined"][k] - r["ours"][k]
                          for r in rows], weights)
            for k, _, _ in METRICS
        }  # fmt: skip
        info = [r["refine"] for r in rows if r.get("refine")]
        seconds = [i["seconds"] for i in info]
        out["refine_seconds"] = {"median": float(np.median(seconds)), "max": float(np.max(seconds)),
                                 "refined": sum(bool(i["refined"]) for i in info)}  # fmt: skip
    objs = [o for r in rows for o in r.get("objects") or ()]
    if objs:  # per-object means: every object counts once, however large it is in the frame
        w = [o["pixels"] for o in objs]
        out["objects"] = len(objs)
        out["per_object"] = {
            m: {k: summarize([o[m][k] for o in objs], w) for k, _, _ in METRICS if k != "albedo_lpips"} for m in scored
        }
        # Does the predicted roughness follow the truth across dielectric objects (a constant has r = None)?
        diel = [o for o in objs if "roughness_mean" in o and o["metallic_truth"] < 0.5]
        out["roughness_correlation"] = {
            m: correlation([o["roughness_mean"]["truth"] for o in diel], [o["roughness_mean"].get(m) for o in diel])
            for m in scored
            if any(m in o["roughness_mean"] for o in diel)
        }
    return out


def evaluate_dataset(
    model: torch.nn.Module,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    stats: Mapping[str, Any],
    *,
    limit: int | None = None,
    lpips: bool | None = None,
    progress: bool = False,
    jobs: int = 1,
    checkpoint_path: str | Path | None = None,
    refine: bool = False,
) -> dict[str, Any]:
    """Score the model, the baseline and the constant predictor on every scene of a rendered dataset.

    Any dataset with ground truth is accepted; a caller that must score a test split only checks
    its role first (:func:`pbrdf.data.splits.require_role`).

    Args:
        model: the loaded model (:func:`network.checkpoint.load_checkpoint`).
        checkpoint: its checkpoint dict (for the input variant and scale).
        root: the dataset folder (``headless/render.py``; a split keeps its raw brackets).
        stats: training statistics (:func:`network.constant.load_statistics`).
        limit: score only the first ``limit`` scenes (>= 1).
        lpips: compute albedo LPIPS (default: when its weights are installed).
        progress: show a progress bar.
        jobs: worker processes (each loads ``checkpoint_path`` onto ``model``'s device and runs one
            torch thread); scenes are independent, so the rows are the same for any ``jobs``.
        checkpoint_path: the checkpoint file (needed with ``jobs > 1``; names the model's row).
        refine: add the ``refined`` row and its paired differences (:func:`predict_scene`).

    Returns:
        JSON-ready dict: ``split`` (None for an unlabelled dataset), ``model`` (the ``ours`` row's
        label), ``checkpoint``, ``scenes``, ``methods`` -> metric ->
        :func:`~network.statistics.summarize` output, ``mask_iou`` summary, ``per_scene`` rows and
        ``seconds``.

    Raises:
        FileNotFoundError: no dataset folder.
        ValueError: ``limit`` < 1, no completed samples, ``jobs > 1`` without ``checkpoint_path``,
            or a model that fails on a scene (:func:`predict_scene`).
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be >= 1, got {limit}")
    if jobs > 1 and checkpoint_path is None:
        raise ValueError("jobs > 1 needs checkpoint_path (every worker loads the model)")
    name = dataset_split(root)
    variant = checkpoint_inputs(checkpoint)
    if lpips is None:
        lpips = lpips_status()[0]
    indices = sorted(pdataset.completed_indices(root, verify_hash=False))[:limit]
    if not indices:
        raise ValueError(f"{root}: no completed samples")
    t0 = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=len(indices), desc=f"evaluate {name or root.name}", unit="scene")
    try:
        if jobs > 1:
            device = str(next(model.parameters()).device)  # every worker puts its copy where the model is
            init = (str(checkpoint_path), variant, str(root), dict(stats), bool(lpips), device, refine)
            rows = _pool_rows(indices, jobs, init, bar)
        else:
            scale = checkpoint_input_scale(checkpoint)
            rows = []
            for i in indices:
                scene = predict_scene(model, variant, root, i, stats, input_scale=scale, refine=refine)
                rows.append(score_scene(scene, lpips=lpips))
                if bar is not None:
                    bar.update()
    finally:
        if bar is not None:
            bar.close()
    return {
        "split": name,
        "description": SPLITS[name].description if name in SPLITS else None,
        "data": str(root),
        "model": model_label(checkpoint_path),
        "checkpoint": None if checkpoint_path is None else str(checkpoint_path),
        "scenes": len(rows),
        "input": variant,
        "lpips": bool(lpips),
        **summarize_rows(rows),
        "per_scene": rows,
        "seconds": time.perf_counter() - t0,
    }


def _pool_rows(indices: list[int], jobs: int, init: tuple, bar) -> list[dict[str, Any]]:
    """:func:`score_scene` rows of ``indices`` from ``jobs`` spawned worker processes, in order."""
    import multiprocessing  # noqa: PLC0415
    from concurrent.futures import ProcessPoolExecutor  # noqa: PLC0415

    rows = []
    ctx = multiprocessing.get_context("spawn")  # never fork a process that has run torch
    with ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_worker_init, initargs=init) as pool:
        for row in pool.map(_worker_row, indices):
            rows.append(row)
            if bar is not None:
                bar.update()
    return rows


_WORKER: dict[str, Any] = {}


def _worker_init(
    checkpoint_path: str, variant: str, root: str, stats: dict, lpips: bool, device: str, refine: bool = False
) -> None:
    """Load the model once per worker process on ``device``, with one torch thread (the workers share the cores)."""
    from .checkpoint import load_checkpoint  # noqa: PLC0415

    torch.set_num_threads(1)
    model, ckpt = load_checkpoint(checkpoint_path)
    model.to(device)
    _WORKER.update(model=model, variant=variant, scale=ckpt["input_scale"], root=Path(root), stats=stats, lpips=lpips,
                   refine=refine)  # fmt: skip


def _worker_row(index: int) -> dict[str, Any]:
    w = _WORKER
    scene = predict_scene(w["model"], w["variant"], w["root"], index, w["stats"], input_scale=w["scale"],
                          refine=w["refine"])  # fmt: skip
    return score_scene(scene, lpips=w["lpips"])


def _stored(root: Path, index: int) -> set[str]:
    """The optional maps a sample stores (``object``: not in datasets rendered before it existed)."""
    meta = psample.check_complete(root, index, verify_hash=False)
    return {c.split(".")[0] for c in meta.get("channels", [])}


def summary_table(result: Mapping[str, Any], key: str = "mean") -> tuple[list[str], list[list[str]]]:
    """Header and rows (one per method) of a summary; ``key`` ``"mean"`` or ``"weighted_mean"``.

    Each cell is ``mean [low, high]`` (95 % bootstrap interval) or ``n/a``; the model's row is
    labelled ``result["model"]`` (:func:`model_label`). The per-object oracle's row is left out
    where it scored no scene (every object uniform); elsewhere its label says on how many.
    """
    cols = [(k, h) for k, h, _ in METRICS if result.get("lpips") or k != "albedo_lpips"]
    digits = {"normal_mae": 1, "albedo_psnr": 1, "albedo_si_psnr": 1}
    labels = {**METHODS, "ours": result.get("model") or METHODS["ours"]}
    scored = result["methods"]["object_mean"]["roughness_rmse"].get("count") or 0
    if scored and scored < (result["methods"]["constant"]["roughness_rmse"].get("count") or 0):
        labels["object_mean"] += f" ({scored} textured scenes)"
    header = ["method"] + [h for _, h in cols]
    refined = result["methods"].get("refined", {}).get("normal_mae", {}).get("count") or 0
    shown = [m for m in METHODS if (m != "object_mean" or scored) and (m != "refined" or refined)]
    methods = result["methods"]
    rows = [[labels[m]] + [summary_text(methods[m][k], digits.get(k, 3), key=key) for k, _ in cols] for m in shown]
    return header, rows


def _markdown_table(title: str, header: list[str], rows: list[list[str]]) -> list[str]:
    lines = [f"{title}:", "", "| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    return lines + ["| " + " | ".join(r) + " |" for r in rows] + [""]


def results_markdown(result: Mapping[str, Any]) -> str:
    """Markdown tables (per-scene means, pixel-weighted means) of one :func:`evaluate_dataset` result."""
    lines = [f"### {result.get('split') or result['data']} ({result['scenes']} scenes)", ""]
    if result.get("description"):
        lines += [result["description"] + ".", ""]
    for title, key in (("Per-scene mean [95 % CI]", "mean"), ("Pixel-weighted mean [95 % CI]", "weighted_mean")):
        lines += _markdown_table(title, *summary_table(result, key))
    if result.get("per_object") and result.get("objects", 0) > result["scenes"]:
        per = {"methods": result["per_object"], "lpips": False, "model": result.get("model")}
        lines += _markdown_table(f"Per-object mean [95 % CI] ({result['objects']} objects)", *summary_table(per))
    corr = {m: c for m, c in (result.get("roughness_correlation") or {}).items() if c.get("count")}
    if corr:
        cells = [f"{m} {summary_text(c, 2, key='r')}" if c["r"] is not None else f"{m} none (constant)"
                 for m, c in corr.items()]  # fmt: skip
        n = max(c["count"] for c in corr.values())
        lines += [f"Per-object roughness correlation with the truth, dielectric objects (Pearson r [95 % CI], "
                  f"{n} objects): " + "; ".join(cells) + ".", ""]  # fmt: skip
    if result.get("paired"):
        cols = [(k, h) for k, h, _ in METRICS if k in ("normal_mae", "albedo_psnr", "albedo_si_psnr", "roughness_rmse")]
        cells = [summary_text(result["paired"][k], 2) for k, _ in cols]
        t = result.get("refine_seconds") or {}
        title = (f"Refinement minus network, paired per-scene mean [95 % CI] (refined {t.get('refined')} of "
                 f"{result['scenes']} scenes; {t.get('median', 0):.1f} s median, "
                 f"{t.get('max', 0):.1f} s max)")  # fmt: skip
        lines += _markdown_table(title, [h for _, h in cols], [cells])
    iou = result["mask_iou"]
    lines.append(f"Automatic foreground mask vs object coverage: IoU {summary_text(iou, 3)} (per-scene mean).")
    lines.append("")
    return "\n".join(lines)


def write_results(results: list[Mapping[str, Any]], out_dir: str | Path, stem: str) -> list[Path]:
    """Write ``STEM.json`` (strict JSON, ``{"results": [...]}``) and ``STEM.md`` atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = "\n".join(results_markdown(r) for r in results)
    return [
        atomic_write_text(out / f"{stem}.json", dumps_strict({"results": list(results)}) + "\n"),
        atomic_write_text(out / f"{stem}.md", md),
    ]
