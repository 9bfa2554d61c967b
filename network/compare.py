"""Paired comparison of two evaluations of the same scenes: did a change help, hurt, or do nothing?

Two reports of :func:`network.evaluation.evaluate_dataset` (two checkpoints, or a model before
and after a change) scored on the same scenes differ scene by scene; the per-scene differences
are paired, so their mean comes with a bootstrap interval over scenes that is much tighter than
the two unpaired intervals side by side. :func:`paired_gain` is that difference for one metric;
:func:`compare_results` makes it for every split both reports share and every metric, with a
verdict per cell (better / worse / no difference at 95 %); :func:`compare_markdown` is its table.
This is the gate a new model passes before it replaces the shipped one.

Example:
    >>> def r(vals):
    ...     return {"split": "s", "per_scene": [{"index": i, "ours": {"normal_mae": v}} for i, v in enumerate(vals)],
    ...             "methods": {"ours": {"normal_mae": {"mean": sum(vals) / len(vals)}}}}
    >>> row = compare_results([r([10.0, 12.0, 14.0, 16.0])], [r([9.0, 11.2, 12.9, 15.1])])[0]
    >>> row["split"], row["metric"], row["verdict"]
    ('s', 'normal_mae', 'better')
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from .statistics import bootstrap_ci, summary_text

__all__ = ["COMPARED", "compare_markdown", "compare_results", "paired_gain", "worse_cells"]

#: Metrics compared: (key, header, higher is better, digits).
COMPARED = (
    ("normal_mae", "Normal MAE (deg)", False, 2),
    ("albedo_psnr", "Albedo PSNR (dB)", True, 2),
    ("albedo_si_psnr", "Albedo si-PSNR (dB)", True, 2),
    ("roughness_rmse", "Roughness RMSE", False, 4),
    ("metallic_rmse", "Metallic RMSE", False, 4),
)


def _per_scene(results: Mapping[str, Any], run: str, key: str) -> dict[int, float]:
    r = results.get(run) or {}
    out = {}
    for row in r.get("per_scene", ()):
        v = (row.get("ours") or {}).get(key)
        if v is not None and math.isfinite(v):
            out[int(row["index"])] = float(v)
    return out


def _mean(results: Mapping[str, Any], run: str, key: str) -> float | None:
    r = results.get(run)
    v = (((r or {}).get("methods") or {}).get("ours") or {}).get(key, {}).get("mean")
    return v if v is not None and math.isfinite(v) else None


def paired_gain(
    results: Mapping[str, Any], before: str, after: str, key: str
) -> tuple[float, tuple[float, float] | None] | None:
    """How much run ``after`` lowers a metric against run ``before``, with a paired 95 % interval.

    The runs are scored on the same scenes (an ablation's ``white`` twin split has the same scene
    indices), so the per-scene differences are paired: the interval is the bootstrap over scenes
    of their mean. Without per-scene rows the difference of the means is returned with no interval.

    Args:
        results: ``run -> evaluate_dataset`` dict.
        before: the run without the change.
        after: the run with it.
        key: metric key of ``methods.ours`` (read as lower is better).

    Returns:
        ``(gain, (low, high))``, gain = before - after (positive: ``after`` is lower); None when a
        run or the metric is missing.

    Example:
        >>> def r(vals):
        ...     return {"per_scene": [{"index": i, "ours": {"m": v}} for i, v in enumerate(vals)],
        ...             "methods": {"ours": {"m": {"mean": sum(vals) / len(vals)}}}}
        >>> gain, (lo, hi) = paired_gain({"a": r([3.0, 5.0, 7.0, 9.0]), "b": r([2.0, 4.1, 5.9, 8.0])}, "a", "b", "m")
        >>> round(gain, 2), bool(0.8 < lo < hi < 1.2)
        (1.0, True)
    """
    a, b = _per_scene(results, before, key), _per_scene(results, after, key)
    common = sorted(a.keys() & b.keys())
    if common:
        diffs = [a[i] - b[i] for i in common]
        return sum(diffs) / len(diffs), bootstrap_ci(diffs, seed=0)
    va, vb = _mean(results, before, key), _mean(results, after, key)
    return None if va is None or vb is None else (va - vb, None)


def _name(result: Mapping[str, Any]) -> str:
    return str(result.get("split") or result.get("data") or "?")


def compare_results(before: Sequence[Mapping[str, Any]], after: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (split both reports scored, metric): means, the paired improvement and a verdict.

    Args:
        before: the reference's results (e.g. the shipped model's ``test_splits.json`` ``results``).
        after: the candidate's results on the same splits and scenes.

    Returns:
        rows with ``split``, ``metric``, ``before``, ``after`` (per-scene means), ``gain`` (the
        paired mean improvement, positive = ``after`` better whichever way the metric points),
        ``ci`` (its 95 % interval, None without per-scene rows), ``scenes`` and ``verdict``:
        ``"better"``/``"worse"`` when the interval excludes 0, else ``"no difference"``.
    """
    ref = {_name(r): r for r in before}
    rows = []
    for cand in after:
        split = _name(cand)
        if split not in ref:
            continue
        pair = {"before": ref[split], "after": cand}
        for key, _, higher, _ in COMPARED:
            g = paired_gain(pair, "before", "after", key)
            if g is None:
                continue
            sign = -1.0 if higher else 1.0  # paired_gain is "how much lower"
            gain = sign * g[0]
            ci = None if g[1] is None else tuple(sorted((sign * g[1][0], sign * g[1][1])))
            verdict = "no difference"
            if ci is not None and ci[0] > 0:
                verdict = "better"
            elif ci is not None and ci[1] < 0:
                verdict = "worse"
            scenes = len(_per_scene(pair, "before", key).keys() & _per_scene(pair, "after", key).keys())
            rows.append({"split": split, "metric": key, "before": _mean(pair, "before", key),
                         "after": _mean(pair, "after", key), "gain": gain, "ci": ci, "scenes": scenes,
                         "verdict": verdict})  # fmt: skip
    return rows


def worse_cells(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """``"split metric"`` of every row whose verdict is ``"worse"`` (a candidate to ship has none)."""
    return [f"{r['split']} {r['metric']}" for r in rows if r["verdict"] == "worse"]


def compare_markdown(rows: Sequence[Mapping[str, Any]], before: str, after: str) -> str:
    """A markdown table of :func:`compare_results`' rows, one line per split and metric."""
    digits = {k: d for k, _, _, d in COMPARED}
    header = {k: h for k, h, _, _ in COMPARED}
    lines = [f"Paired comparison, `{after}` against `{before}` (gain > 0: `{after}` is better; 95 % bootstrap "
             "interval over the scenes both scored)", "",
             "| split | metric | before | after | gain [95 % CI] | scenes | verdict |",
             "|---|---|---:|---:|---:|---:|---|"]  # fmt: skip
    for r in rows:
        d = digits[r["metric"]]

        def num(v: float | None, d: int = d) -> str:
            return "n/a" if v is None else f"{v:.{d}f}"

        lines.append(f"| {r['split']} | {header[r['metric']]} | {num(r['before'])} | {num(r['after'])} | "
                     f"{summary_text(r, d, key='gain', signed=True)} | {r['scenes']} | {r['verdict']} |")  # fmt: skip
    worse = worse_cells(rows)
    lines += ["", f"Worse at 95 %: {', '.join(worse)}." if worse else "Worse at 95 %: none.", ""]
    return "\n".join(lines)
