"""How the scores of a lighting-aware model degrade when the object distance it is told is off.

A user's tape measure is not exact. :func:`distance_sensitivity` scores the model on every scene
of a rendered dataset through the capture path (:func:`network.evaluation.predict_scene`, the
baseline left out) with the scene's distance (the median of its true depth) scaled by ``1 + e``
for each error ``e`` (e.g. -0.2, -0.05, 0, 0.05, 0.2), and reports per error the per-scene mean of
each metric and its paired difference to ``e = 0`` with a 95 % bootstrap interval
(:func:`network.statistics.summarize`). A light-blind model never sees the distance, so its rows
are equal by construction: a check of the plumbing. With ``refine=True`` the scored maps are the
network's after the test-time refinement (:func:`network.refine.refine`), which fits each object's
albedo scale under the display's light at the told distance: then even a light-blind model's rows
move, by what a tape measure's error costs the refined albedo.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from pbrdf.data import dataset as pdataset
from pbrdf.data.splits import dataset_split

from .data import checkpoint_input_scale
from .evaluation import predict_scene, score
from .inputs import checkpoint_inputs
from .statistics import summarize, summary_text

__all__ = ["SENSITIVITY_METRICS", "distance_sensitivity", "sensitivity_markdown"]

#: Metrics reported per distance error (keys of :func:`network.evaluation.score`), with their table headers.
SENSITIVITY_METRICS = {
    "albedo_psnr": "albedo PSNR (dB)",
    "albedo_si_psnr": "albedo si-PSNR (dB)",
    "normal_mae": "normal MAE (deg)",
    "roughness_rmse": "roughness RMSE",
}


def distance_sensitivity(
    model: torch.nn.Module,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    stats: Mapping[str, Any],
    errors: Sequence[float],
    *,
    limit: int | None = None,
    refine: bool = False,
) -> dict[str, Any]:
    """Scores of ``model`` on the scenes of ``root`` with the object distance scaled by ``1 + e`` per error.

    Args:
        model: the loaded model.
        checkpoint: its checkpoint dict (input variant and scale).
        root: a rendered dataset with ground truth (the median true depth is the "measured" distance).
        stats: training statistics (:func:`network.constant.load_statistics`; the constant row of the scenes).
        errors: relative distance errors ``e`` (each > -1); 0 is always added.
        limit: only the first ``limit`` scenes.
        refine: score the refined maps (the ``refined`` row of :func:`network.evaluation.predict_scene`).

    Returns:
        JSON-ready dict: ``data``, ``split``, ``scenes``, ``light_input`` (whether the model sees the
        distance), ``refine``, ``errors`` (sorted), ``rows`` -> ``str(e)`` -> metric -> summary of the values
        and ``"delta_<metric>"`` -> summary of the paired difference to ``e = 0``, ``seconds``.

    Raises:
        ValueError: an error <= -1, no completed samples, or a scaled distance outside the plausible
            range (:func:`network.light_input.check_distance`).
    """
    if any(not e > -1 for e in errors):
        raise ValueError(f"errors must be > -1 (a distance scaled by 1 + e); got {list(errors)}")
    root = Path(root)
    errs = sorted({0.0, *(float(e) for e in errors)})
    indices = sorted(pdataset.completed_indices(root, verify_hash=False))[:limit]
    if not indices:
        raise ValueError(f"{root}: no completed samples")
    variant, scale = checkpoint_inputs(checkpoint), checkpoint_input_scale(checkpoint)
    t0 = time.perf_counter()
    values: dict[float, dict[str, list]] = {e: {k: [] for k in SENSITIVITY_METRICS} for e in errs}
    for i in indices:
        for e in errs:
            scene = predict_scene(model, variant, root, i, stats, input_scale=scale, baseline=False,
                                  distance_scale=1.0 + e, refine=refine)  # fmt: skip
            row = score(scene.preds["refined" if refine else "ours"], scene.gt, scene.region, lpips=False)
            for k in SENSITIVITY_METRICS:
                values[e][k].append(row[k])
    rows = {}
    for e in errs:
        rows[str(e)] = {k: summarize(v) for k, v in values[e].items()}
        for k in SENSITIVITY_METRICS:
            pairs = zip(values[e][k], values[0.0][k], strict=True)
            diff = [None if a is None or b is None else a - b for a, b in pairs]
            rows[str(e)][f"delta_{k}"] = summarize(diff)
    return {
        "data": str(root), "split": dataset_split(root), "scenes": len(indices),
        "light_input": bool(model.config.light_input), "refine": bool(refine), "errors": errs, "rows": rows,
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def sensitivity_markdown(result: Mapping[str, Any]) -> str:
    """A markdown table of :func:`distance_sensitivity`: per error, each metric's mean and paired change."""
    digits = {"albedo_psnr": 2, "albedo_si_psnr": 2, "normal_mae": 2, "roughness_rmse": 4}
    if result.get("refine"):
        seen = ("sees the distance" if result["light_input"] else "is light-blind") + ", + refinement at that distance"
    else:
        seen = "sees the distance" if result["light_input"] else "is light-blind: rows equal by construction"
    lines = [f"### Distance error: {result['split'] or result['data']} ({result['scenes']} scenes; the model {seen})",
             "", "| distance error | " + " | ".join(SENSITIVITY_METRICS.values()) + " |",
             "|---:|" + "---:|" * len(SENSITIVITY_METRICS)]  # fmt: skip
    for e in result["errors"]:
        row = result["rows"][str(e)]
        cells = [
            f"{row[k]['mean']:.{digits[k]}f} (change {summary_text(row['delta_' + k], digits[k], signed=True)})"
            if row[k].get("mean") is not None else "n/a"
            for k in SENSITIVITY_METRICS
        ]  # fmt: skip
        lines.append(f"| {e:+.0%} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
