"""Benchmark evaluation: the paper's Table 1 (ours vs photometric stereo) and Table 3 (input ablations).

:func:`evaluate` runs, on every sample of a rendered dataset, the learned model
(:func:`network.infer.predict`, after :func:`network.inputs.apply_inputs` with the checkpoint's
input variant) and the classical baseline (:mod:`network.baseline`, Lambertian RGB photometric
stereo from the display's three colour regions, calibrated from the sample's rig), and scores
them against the ground truth with :mod:`network.metrics` on the sample's mask:

==========================  ===============================================================
column                      metric
==========================  ===============================================================
Normal MAE (deg)            :func:`~network.metrics.normal_mae_deg`
Albedo PSNR / LPIPS         :func:`~network.metrics.psnr`, :func:`~network.metrics.lpips`
Albedo si-PSNR / si-LPIPS   the same after one global least-squares scale
Roughness / Metallic RMSE   :func:`~network.metrics.rmse`
==========================  ===============================================================

Means over samples are weighted by each sample's number of mask pixels. The baseline predicts
no roughness or metallic (``None``, "n/a" in the tables); LPIPS columns are ``None`` with the
reason when no LPIPS weights are installed (:func:`network.lpips.lpips_status`).

The ``"white"`` variant (uniform white display) must be evaluated on data rendered with the
``white`` display pattern (``white_data``); the others on the RGB-pattern data. With ``real``,
the re-rendering error on real captures (si-PSNR, si-LPIPS, si-RMSE, si-MSE of the re-rendered
unpol and LP maps against the measured ones) uses :mod:`network.rerender` and
:mod:`network.realdata` when they exist.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pbrdf.data import dataset as pdataset
from pbrdf.data.capture import display_radiance
from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.strict_json import dumps_strict

from . import baseline, metrics
from .checkpoint import load_checkpoint
from .infer import predict
from .inputs import INPUT_VARIANTS, apply_inputs, checkpoint_inputs
from .lpips import lpips_status

__all__ = [
    "COLUMNS",
    "VARIANT_LABELS",
    "BASELINE",
    "evaluate",
    "sample_metrics",
    "baseline_predict",
    "table1_markdown",
    "table3_markdown",
    "write_results",
]

#: Table columns: (key, header, True when higher is better).
COLUMNS = (
    ("normal_mae", "Normal MAE (deg)", False),
    ("albedo_psnr", "Albedo PSNR", True),
    ("albedo_lpips", "Albedo LPIPS", False),
    ("albedo_si_psnr", "Albedo si-PSNR", True),
    ("albedo_si_lpips", "Albedo si-LPIPS", False),
    ("roughness_rmse", "Roughness RMSE", False),
    ("metallic_rmse", "Metallic RMSE", False),
)
#: Re-rendering error columns on real data.
REAL_COLUMNS = (
    ("si_psnr", "si-PSNR", True),
    ("si_lpips", "si-LPIPS", False),
    ("si_rmse", "si-RMSE", False),
    ("si_mse", "si-MSE", False),
)
#: Table 3 row labels, in the paper's order.
VARIANT_LABELS = {
    "white": "Uniform white illumination",
    "spectral": "+ spectral multiplexing",
    "polar": "+ polarization decomposition",
    "full": "+ CP (ours)",
}
BASELINE = "baseline"
BASELINE_LABEL = "Photometric stereo (baseline)"
_LPIPS_KEYS = ("albedo_lpips", "albedo_si_lpips")


def _pattern(meta: Mapping) -> str:
    return str(meta.get("rig", {}).get("display", {}).get("pattern", "rgb_halves"))


def baseline_predict(maps: np.ndarray, mask: np.ndarray, meta: Mapping) -> dict[str, np.ndarray]:
    """Photometric-stereo normal and albedo ``(H, W, 3)`` for a sample, calibrated from its sidecar.

    :func:`network.baseline.predict_sample`: the display's colour regions as planar patches
    (the sample's rig) in the camera frame, at each pixel's point (the object's centre depth, then
    the integrated normals), the albedo colour calibrated from the image, normals fitted to the
    horizon-clipped Lambertian model of the ``unpol`` maps (regions whose light is mostly
    polarized, e.g. metals, get a constant normal toward the camera).

    Raises:
        ValueError: the sample shows the white pattern (no colour regions), or its sidecar has no
            objects or intrinsics.
    """
    if _pattern(meta) == "white":
        raise ValueError("photometric stereo needs the display's colour regions, not the white pattern")
    out = baseline.predict_sample(maps, mask, meta)
    return {"normal": out["normal"], "albedo": out["albedo"]}


def sample_metrics(pred: Mapping[str, np.ndarray], gt: Mapping[str, np.ndarray], mask: np.ndarray, *,
                   lpips: bool = True) -> dict[str, float | None]:  # fmt: skip
    """Every :data:`COLUMNS` metric for one sample (``None`` where ``pred`` lacks the map or LPIPS is off).

    Args:
        pred: ``normal``, ``albedo`` ``(H, W, 3)``, ``roughness``, ``metallic`` ``(H, W)`` or ``(H, W, 1)``
            (any subset).
        gt: the same keys, ground truth.
        mask: ``(H, W)`` pixels to score.
        lpips: compute the LPIPS columns.
    """

    def chan(a: np.ndarray) -> np.ndarray:
        return a[..., None] if a.ndim == 2 else a

    out: dict[str, float | None] = {k: None for k, _, _ in COLUMNS}
    if "normal" in pred:
        out["normal_mae"] = metrics.normal_mae_deg(pred["normal"], gt["normal"], mask)
    if "albedo" in pred:
        p, g = pred["albedo"], gt["albedo"]
        out["albedo_psnr"] = metrics.psnr(p, g, mask)
        out["albedo_si_psnr"] = metrics.si_psnr(p, g, mask)
        if lpips:
            out["albedo_lpips"] = metrics.lpips(p, g, mask)
            out["albedo_si_lpips"] = metrics.si_lpips(p, g, mask)
    for k in ("roughness", "metallic"):
        if k in pred:
            out[f"{k}_rmse"] = metrics.rmse(chan(pred[k]), chan(gt[k]), mask)
    return out


def _weighted_mean(rows: list[dict], keys: tuple[str, ...]) -> dict[str, float | None]:
    mean: dict[str, float | None] = {}
    for k in keys:
        vals = [(r[k], r["pixels"]) for r in rows if r.get(k) is not None]
        w = sum(p for _, p in vals)
        mean[k] = float(sum(v * p for v, p in vals) / w) if vals and w > 0 else None
    return mean


def _resolve_checkpoints(checkpoints: Mapping[str, str | Path] | str | Path) -> dict[str, tuple[Path, Any, dict]]:
    if isinstance(checkpoints, (str, Path)):
        model, ckpt = load_checkpoint(checkpoints)
        return {checkpoint_inputs(ckpt): (Path(checkpoints), model, ckpt)}
    if not checkpoints:
        raise ValueError("no checkpoint given")
    out = {}
    for variant, path in checkpoints.items():
        if variant not in INPUT_VARIANTS:
            raise ValueError(f"unknown input variant {variant!r} for {path}; choose one of {INPUT_VARIANTS}")
        model, ckpt = load_checkpoint(path)
        if "inputs" in ckpt and checkpoint_inputs(ckpt) != variant:
            raise ValueError(f"{path}: checkpoint was trained with inputs {ckpt['inputs']!r}, given as {variant!r}")
        out[variant] = (Path(path), model, ckpt)
    return out


def _indices(root: Path, limit: int | None) -> list[int]:
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    done = sorted(pdataset.completed_indices(root, verify_hash=False))
    if not done:
        raise ValueError(f"{root}: no completed samples (render some with headless/render.py)")
    if limit is not None:
        if limit < 1:
            raise ValueError(f"limit must be >= 1, got {limit}")
        done = done[:limit]
    return done


_GT_KEYS = ("maps", "mask", "normal", "albedo", "roughness", "metallic")


def _run_model(
    model, variant: str, maps: np.ndarray, mask: np.ndarray, input_scale: str, radiance: float | None
) -> dict[str, np.ndarray]:
    # apply_inputs keeps unpol + LP per colour, so applying it before predict's normalisation is exact.
    x = apply_inputs(torch.from_numpy(np.ascontiguousarray(maps.transpose(2, 0, 1))), variant)
    return predict(model, x.permute(1, 2, 0).contiguous().numpy(), mask, input_scale=input_scale, radiance=radiance)


def evaluate(
    checkpoints: Mapping[str, str | Path] | str | Path,
    data_dir: str | Path,
    *,
    limit: int | None = None,
    white_data: str | Path | None = None,
    real: str | Path | None = None,
    progress: bool = False,
) -> dict:
    """Score the checkpoints and the photometric-stereo baseline on a rendered dataset.

    Args:
        checkpoints: one checkpoint path (its variant from its ``"inputs"`` key) or
            ``{variant: path}`` for the Table 3 ablation.
        data_dir: rendered dataset (RGB display pattern, e.g. ``rgb_halves``) with ground truth.
        limit: evaluate only the first ``limit`` samples (sorted indices).
        white_data: the same scenes rendered with the ``white`` pattern, for the ``"white"``
            variant (required when it is given).
        real: folder of real captures for the re-rendering error (skipped, with the reason in
            ``result["real"]``, while :mod:`network.rerender` or :mod:`network.realdata` is missing).
        progress: show a progress bar.

    Returns:
        JSON-friendly dict: ``methods`` (per method: ``label``, ``mean``, ``per_sample``, and
        for models ``checkpoint`` and ``inputs``), ``ours`` (which method is "Ours"),
        ``vs_baseline`` (ours minus baseline per column), ``lpips``, ``data``, ``real``.
    """
    data_dir = Path(data_dir)
    models = _resolve_checkpoints(checkpoints)
    if "white" in models and white_data is None:
        raise ValueError("the 'white' variant needs data rendered with the white display pattern: pass white_data")
    lpips_ok, lpips_info = lpips_status()
    sources = {v: (Path(white_data) if v == "white" else data_dir) for v in models}
    sources[BASELINE] = data_dir
    per: dict[str, list[dict]] = {m: [] for m in sources}
    jobs = []
    for root in dict.fromkeys(sources.values()):
        for i in _indices(root, limit):
            jobs.append((root, i))
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=len(jobs), desc="evaluate", unit="sample")
    for root, i in jobs:
        sample, meta = pdataset.read_sample(root, i, keys=_GT_KEYS)
        mask = sample["mask"].astype(bool)
        base = {"index": i, "pixels": int(mask.sum())}
        methods = [m for m, src in sources.items() if src == root]
        for m in methods:
            if m == BASELINE:
                pred = baseline_predict(sample["maps"], mask, meta)
            else:
                if (_pattern(meta) == "white") != (m == "white"):
                    want = "white" if m == "white" else "RGB-pattern"
                    raise ValueError(f"{root}: sample {i} has display pattern {_pattern(meta)!r}; variant {m!r} "
                                     f"needs {want} data")  # fmt: skip
                radiance = display_radiance(meta, str(pdataset.sample_paths(root, i).sidecar))
                pred = _run_model(models[m][1], m, sample["maps"], mask, models[m][2]["input_scale"], radiance)
            per[m].append({**base, **sample_metrics(pred, sample, mask, lpips=lpips_ok)})
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    keys = tuple(k for k, _, _ in COLUMNS)
    result: dict[str, Any] = {
        "data": str(data_dir),
        "white_data": None if white_data is None else str(white_data),
        "lpips": {"available": lpips_ok, ("weights" if lpips_ok else "reason"): lpips_info},
        "methods": {},
    }
    ours = "full" if "full" in models else next(iter(models))
    result["ours"] = ours
    for m, rows in per.items():
        entry: dict[str, Any] = {"label": BASELINE_LABEL if m == BASELINE else VARIANT_LABELS[m]}
        if m != BASELINE:
            entry.update(checkpoint=str(models[m][0]), inputs=m)
        entry.update(count=len(rows), mean=_weighted_mean(rows, keys), per_sample=rows)
        result["methods"][m] = entry
    mo, mb = result["methods"][ours]["mean"], result["methods"][BASELINE]["mean"]
    result["vs_baseline"] = {k: (None if mo[k] is None or mb[k] is None else mo[k] - mb[k]) for k in keys}
    result["real"] = _evaluate_real(models, real, limit=limit) if real is not None else None
    return result


def _evaluate_real(models: dict, real: str | Path, *, limit: int | None) -> dict:
    """Re-rendering error of each model on real captures (:mod:`network.rerender`, :mod:`network.realdata`)."""
    missing = [m for m in ("network.rerender", "network.realdata") if importlib.util.find_spec(m) is None]
    if missing:
        return {"skipped": f"{', '.join(missing)} not available yet: re-rendering error not computed"}
    from .realdata import RealDataset  # noqa: PLC0415
    from .rerender import Patches, rerender_dense  # noqa: PLC0415

    out: dict[str, Any] = {}
    lpips_ok, _ = lpips_status()
    for variant, (_, model, _) in models.items():
        if variant == "white":  # real captures are taken under the RGB pattern: nothing to compare with
            out[variant] = {"skipped": "the white-illumination variant needs captures under a white display"}
            continue
        ds = RealDataset(real, model.config.image_size)
        rows = []
        for j in range(len(ds) if limit is None else min(limit, len(ds))):
            item = ds[j]
            lacking = [k for k in ("maps", "mask", "points", "patches") if k not in item]
            if lacking:
                return {"skipped": f"RealDataset items lack {lacking}: re-rendering error not computed"}
            batch = {k: v[None] for k, v in item.items()}
            with torch.no_grad():
                pred = model(apply_inputs(batch["maps"], variant), batch["mask"])
                rendered = rerender_dense(pred, batch["mask"], batch["points"], Patches.unpack(batch["patches"]))
            measured = batch["maps"][0, :6].permute(1, 2, 0).numpy()
            sim = torch.cat([rendered["unpol"], rendered["lp"]], dim=1)[0].permute(1, 2, 0).numpy()
            mask = batch["mask"][0, 0].numpy() > 0
            peak = float(np.quantile(measured[mask], 0.99)) or 1.0  # PSNR relative to the capture's brightness
            row = {"index": j, "pixels": int(mask.sum()), "peak": peak,
                   "si_psnr": metrics.si_psnr(sim / peak, measured / peak, mask),
                   "si_rmse": metrics.si_rmse(sim, measured, mask), "si_mse": metrics.si_mse(sim, measured, mask),
                   "si_lpips": None}  # fmt: skip
            if lpips_ok:  # LPIPS on the unpol (diffuse) RGB image, brightness-normalised
                row["si_lpips"] = metrics.si_lpips(sim[..., :3], measured[..., :3], mask, peak=peak)
            rows.append(row)
        out[variant] = {"mean": _weighted_mean(rows, tuple(k for k, _, _ in REAL_COLUMNS)), "per_sample": rows}
    return out


# --------------------------------------------------------------------------- tables
def _fmt(key: str, value: float | None) -> str:
    if value is None:
        return "n/a"
    if math.isinf(value):
        return "inf"
    return f"{value:.2f}" if ("psnr" in key or "mae" in key) else f"{value:.4f}"


def _row(label: str, mean: Mapping[str, float | None]) -> str:
    return "| " + " | ".join([label, *(_fmt(k, mean.get(k)) for k, _, _ in COLUMNS)]) + " |"


def _header(first: str) -> list[str]:
    heads = [first, *(h for _, h, _ in COLUMNS)]
    return ["| " + " | ".join(heads) + " |", "|" + "|".join(["---"] + ["---:"] * len(COLUMNS)) + "|"]


def _notes(result: Mapping) -> list[str]:
    notes = []
    if not result["lpips"]["available"]:
        notes.append(f"LPIPS n/a: {result['lpips']['reason']}")
    return notes


def table1_markdown(result: Mapping) -> str:
    """Table 1 (Markdown): photometric stereo vs ours, and the difference."""
    ours = result["methods"][result["ours"]]
    base = result["methods"][BASELINE]
    label = "Ours" if result["ours"] == "full" else f"Ours (inputs: {result['ours']})"
    title = f"Table 1: synthetic benchmark ({base['count']} samples of {result['data']}; means weighted by mask pixels)"
    lines = [title, "", *_header("Method"), _row(BASELINE_LABEL, base["mean"]), _row(label, ours["mean"])]
    cells, verdicts = [], []
    for k, h, higher in COLUMNS:
        d = result["vs_baseline"][k]
        if d is None:
            cells.append("n/a")
            continue
        cells.append(f"{d:+.2f}" if ("psnr" in k or "mae" in k) else f"{d:+.4f}")
        verdict = "equal" if d == 0 else ("better" if (d > 0) == higher else "worse")
        verdicts.append(f"{h} {verdict}" + ("" if d == 0 else f" by {abs(d):.4g}"))
    lines.append("| " + " | ".join(["Ours vs baseline", *cells]) + " |")
    lines += ["", "vs baseline: " + ("; ".join(verdicts) if verdicts else "no common column") + "."]
    lines += [f"{n}." for n in _notes(result)]
    return "\n".join(lines) + "\n"


def table3_markdown(result: Mapping) -> str:
    """Table 3 (Markdown): the four input variants (rows without a checkpoint say so)."""
    lines = ["Table 3: input ablation (means weighted by mask pixels)", "", *_header("Inputs")]
    missing = []
    for v in INPUT_VARIANTS:
        m = result["methods"].get(v)
        if m is None:
            missing.append(v)
            lines.append("| " + " | ".join([VARIANT_LABELS[v], *("—" for _ in COLUMNS)]) + " |")
        else:
            lines.append(_row(VARIANT_LABELS[v], m["mean"]))
    lines.append("")
    if missing:
        lines.append(f"No checkpoint for: {', '.join(missing)} (give one per variant as VARIANT=PATH).")
    if "white" in result["methods"]:
        lines.append(f"'{VARIANT_LABELS['white']}' is evaluated on {result['white_data']} (white display pattern).")
    lines += [f"{n}." for n in _notes(result)]
    return "\n".join(lines) + "\n"


def real_markdown(result: Mapping) -> str:
    """Re-rendering error on real captures (Markdown), or why it was skipped."""
    real = result.get("real")
    if not real:
        return ""
    if "skipped" in real:
        return f"Re-rendering error on real data: skipped ({real['skipped']}).\n"
    lines = ["Re-rendering error on real data (unpol + LP maps)", "",
             "| Inputs | " + " | ".join(h for _, h, _ in REAL_COLUMNS) + " |",
             "|---|" + "|".join("---:" for _ in REAL_COLUMNS) + "|"]  # fmt: skip
    for v, r in real.items():
        if "skipped" in r:
            lines.append("| " + " | ".join([VARIANT_LABELS[v], *("—" for _ in REAL_COLUMNS)]) + " |")
            continue
        cells = [_fmt(k, r["mean"].get(k)) for k, _, _ in REAL_COLUMNS]
        lines.append("| " + " | ".join([VARIANT_LABELS[v], *cells]) + " |")
    return "\n".join(lines) + "\n"


def write_results(result: Mapping, out_dir: str | Path) -> list[Path]:
    """Write ``metrics.json``, ``table1.md``, ``table3.md`` (and ``real.md`` with real data) atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "metrics.json": dumps_strict(result) + "\n",
        "table1.md": table1_markdown(result),
        "table3.md": table3_markdown(result),
    }
    if result.get("real"):
        files["real.md"] = real_markdown(result)
    return [atomic_write_text(out / name, text) for name, text in files.items()]
