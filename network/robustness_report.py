"""The robustness sweep's table, tolerances and figure (:mod:`network.robustness` cells).

One markdown table: per term, level and decoder, each metric's per-scene mean with its 95 %
bootstrap interval, and the normal error's paired per-scene difference to the nominal rig (the same
scenes and noise, so the interval of the difference is much tighter than those of the means). The
tolerances: per term and decoder, the level at which each paired score first worsens by a limit
(linear between levels). The figure: one column per term, one row per metric, the paired change
from the nominal rig per level, a line per decoder with its 95 % interval.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .robustness import DECODERS, SWEEP_METRICS, TERMS, cell_key
from .statistics import summarize, summary_text

__all__ = [
    "paired_difference",
    "tolerance",
    "sweep_table",
    "tolerance_table",
    "plot_sweep",
    "pool_cells",
    "calibration_table",
    "calibration_verdicts",
]


def paired_difference(cell: Mapping[str, Any], nominal: Mapping[str, Any], metric: str) -> dict[str, Any]:
    """Per-scene ``cell - nominal`` of ``metric``, summarised (:func:`network.statistics.summarize`).

    Raises:
        ValueError: the two cells scored different scenes.
    """
    if cell["scenes"] != nominal["scenes"]:
        raise ValueError(f"cells scored different scenes: {cell['scenes']} vs {nominal['scenes']}")

    def diff(a, b):
        return None if a is None or b is None else a - b

    rows = zip(cell["rows"], nominal["rows"], strict=True)
    return summarize([diff(r["ours"][metric], n["ours"][metric]) for r, n in rows])


def tolerance(levels: Sequence[float], increase: Sequence[float | None], limit: float) -> float | None:
    """The level where ``increase`` (0 at ``levels[0]``) first reaches ``limit``, linear between levels.

    Returns:
        That level, or None when no level reaches ``limit`` (tolerated up to the worst case).

    >>> tolerance([0, 1, 2, 4], [0.0, 0.2, 0.6, 1.4], 1.0)
    3.0
    >>> tolerance([100, 50], [0.0, 0.5], 1.0) is None
    True
    """
    for k in range(1, len(levels)):
        lo, hi = increase[k - 1], increase[k]
        if lo is None or hi is None or hi < limit:
            continue
        t = 1.0 if hi == lo else (limit - lo) / (hi - lo)
        t = min(max(t, 0.0), 1.0)
        return float(levels[k - 1] + t * (levels[k] - levels[k - 1]))
    return None


def _cells_of(cells: Mapping[str, Any], term, decoder: str) -> list[Mapping[str, Any] | None]:
    """The cells of one term and decoder in level order (level 0: the nominal cell)."""
    return [cells.get(cell_key(term.name, i, decoder)) for i in range(len(term.levels))]


def sweep_table(cells: Mapping[str, Any]) -> str:
    """The markdown table of a sweep (module docs); terms without cells are left out."""
    nominal = cells["nominal"]
    head = ["imperfection", "level", "decoder", *(h for h, _, _ in SWEEP_METRICS.values()), "normal MAE - nominal",
            "mask IoU"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|---|---:|---|" + "---:|" * (len(head) - 3)]

    def row(label: str, level: str, decoder: str, cell: Mapping[str, Any]) -> str:
        s = cell["summary"]
        vals = [summary_text(s[k], d) for k, (_, d, _) in SWEEP_METRICS.items()]
        delta = summary_text(paired_difference(cell, nominal, "normal_mae"), 2, signed=True)
        return "| " + " | ".join([label, level, decoder, *vals, delta, summary_text(s["mask_iou"], 3)]) + " |"

    lines.append(row("none (nominal rig)", "-", "-", nominal))
    for term in TERMS:
        for i, level in enumerate(term.levels[1:], 1):
            for decoder in DECODERS if term.invertible else DECODERS[:1]:
                cell = cells.get(cell_key(term.name, i, decoder))
                if cell is not None:
                    lines.append(row(term.label, f"{level:g}", decoder, cell))
    return "\n".join(lines) + "\n"


def tolerance_table(cells: Mapping[str, Any], limits: Mapping[str, float] | None = None) -> str:
    """Markdown: per term and decoder, the level at which each paired score worsens by its limit.

    Args:
        cells: the sweep's cells by key.
        limits: metric -> the worsening that counts (default: normal MAE +1 deg, albedo PSNR
            -1 dB, roughness and metallic RMSE +0.02).
    """
    limits = dict(limits or {"normal_mae": 1.0, "albedo_psnr": 1.0, "roughness_rmse": 0.02, "metallic_rmse": 0.02})
    nominal = cells["nominal"]
    head = ["imperfection", "decoder", *(f"{SWEEP_METRICS[k][0]} worse by {v:g}" for k, v in limits.items())]
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * len(limits)]
    for term in TERMS:
        for decoder in DECODERS if term.invertible else DECODERS[:1]:
            level_cells = _cells_of(cells, term, decoder)
            if any(c is None for c in level_cells[1:]):
                continue
            row = [term.label, decoder]
            for k, lim in limits.items():
                sign = -1.0 if SWEEP_METRICS[k][2] else 1.0  # worse: lower PSNR, higher errors
                inc = [0.0] + [_worse(c, nominal, k, sign) for c in level_cells[1:]]
                found = tolerance(term.levels, inc, lim)
                row.append(f"> {term.levels[-1]:g}" if found is None else f"{found:.3g}")
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def _worse(cell, nominal, metric: str, sign: float) -> float | None:
    mean = paired_difference(cell, nominal, metric)["mean"]
    return None if mean is None else sign * mean


def plot_sweep(cells: Mapping[str, Any], path: str | Path) -> Path:
    """The figure (module docs) as a PNG at ``path``: paired changes from the nominal rig; needs matplotlib."""
    import textwrap  # noqa: PLC0415

    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    nominal = cells["nominal"]
    terms = [t for t in TERMS if all(c is not None for c in _cells_of(cells, t, "nominal")[1:])]
    fig, axes = plt.subplots(len(SWEEP_METRICS), len(terms), figsize=(2.4 * len(terms) + 0.6, 2.0 * len(SWEEP_METRICS)),
                             squeeze=False, sharey="row")  # fmt: skip
    styles = {"nominal": ("tab:red", "o", "decoder assumes the nominal rig"),
              "true": ("tab:blue", "s", "decoder given the true rig")}  # fmt: skip
    for j, term in enumerate(terms):
        axes[0, j].set_title(textwrap.fill(term.label, 30), fontsize=7)
        for decoder in DECODERS if term.invertible else DECODERS[:1]:
            level_cells = _cells_of(cells, term, decoder)
            if any(c is None for c in level_cells[1:]):
                continue
            level_cells[0] = nominal
            color, marker, label = styles[decoder]
            for i, (metric, (header, _, _)) in enumerate(SWEEP_METRICS.items()):
                d = [paired_difference(c, nominal, metric) for c in level_cells]
                mean = np.array([np.nan if x["mean"] is None else x["mean"] for x in d])
                lo = np.array([np.nan if not x["ci"] or x["ci"][0] is None else x["ci"][0] for x in d])
                hi = np.array([np.nan if not x["ci"] or x["ci"][1] is None else x["ci"][1] for x in d])
                ax = axes[i, j]
                ax.plot(term.levels, mean, marker=marker, color=color, label=label, ms=3)
                ax.fill_between(term.levels, lo, hi, color=color, alpha=0.15, lw=0)
                ax.axhline(0.0, color="0.5", lw=0.6)
                if j == 0:
                    ax.set_ylabel("change in\n" + header, fontsize=8)
                ax.tick_params(labelsize=7)
                ax.grid(alpha=0.3)
                if term.levels[-1] < term.levels[0] and not ax.xaxis_inverted():  # worse to the right
                    ax.invert_xaxis()
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=2, fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


# ---------------------------------------------------------------------------- calibrated decoder


def pool_cells(per_split: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Cells of several splits joined per key (keys all splits have): scenes ``SPLIT:INDEX``, rows concatenated.

    >>> a = {"k": {"scenes": [0], "rows": [{"pixels": 1, "mask_iou": 1.0, "ours": dict.fromkeys(SWEEP_METRICS, 1.0)}]}}
    >>> pool_cells({"x": a, "y": a})["k"]["scenes"]
    ['x:0', 'y:0']
    """
    from .robustness import _summary  # noqa: PLC0415

    keys = set.intersection(*(set(cells) for cells in per_split.values()))
    out = {}
    for key in sorted(keys):
        scenes, rows = [], []
        for split, cells in per_split.items():
            scenes += [f"{split}:{s}" for s in cells[key]["scenes"]]
            rows += cells[key]["rows"]
        first = next(iter(per_split.values()))[key]
        out[key] = {**{k: v for k, v in first.items() if k not in ("scenes", "rows", "summary", "seconds")},
                    "scenes": scenes, "rows": rows, "summary": _summary(rows)}  # fmt: skip
    return out


def _case_cells(cells: Mapping[str, Any]) -> list[tuple[str, str, Mapping[str, Any]]]:
    """``(case, decoder, cell)`` in table order (cases as in :data:`network.robustness_calibrated.CASES`)."""
    from .robustness_calibrated import CAL_DECODERS, case_names  # noqa: PLC0415

    return [(c, d, cells[f"{c}-{d}"]) for c in case_names() for d in CAL_DECODERS if f"{c}-{d}" in cells]


def calibration_table(cells: Mapping[str, Any]) -> str:
    """Markdown: per case and decoder, each metric's mean [95 % CI] and its paired change from the unperturbed rig."""
    from .robustness_calibrated import UNPERTURBED  # noqa: PLC0415

    base = cells[UNPERTURBED]
    head = ["rig", "decoder", *(h for h, _, _ in SWEEP_METRICS.values()), "mask IoU",
            *(f"change in {h.split(' (')[0]}" for h, _, _ in SWEEP_METRICS.values())]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(head) - 2)]
    for case, decoder, cell in [(UNPERTURBED, "-", base), *_case_cells(cells)]:
        s = cell["summary"]
        vals = [summary_text(s[k], d) for k, (_, d, _) in SWEEP_METRICS.items()]
        deltas = [
            summary_text(paired_difference(cell, base, k), d, signed=True) for k, (_, d, _) in SWEEP_METRICS.items()
        ]
        lines.append("| " + " | ".join([case, decoder, *vals, summary_text(s["mask_iou"], 3), *deltas]) + " |")
    return "\n".join(lines) + "\n"


def calibration_verdicts(cells: Mapping[str, Any]) -> str:
    """Markdown: per case and metric, is the calibrated decoder back within the unperturbed rig's interval?

    Two readings: the calibrated mean inside the unperturbed mean's 95 % interval (the issue's
    criterion), and the paired per-scene change's 95 % interval containing 0 (no change detected;
    much stricter). Also the paired calibrated - true change (what the estimate's error costs).
    """
    from .robustness_calibrated import UNPERTURBED  # noqa: PLC0415

    base = cells[UNPERTURBED]
    head = ["rig", "metric", "unperturbed [95 % CI]", "calibrated", "within the CI", "calibrated - unperturbed",
            "0 in the paired CI", "calibrated - true", "nominal - unperturbed"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|---|---|---:|---:|---|---:|---|---:|---:|"]
    cases = [c for c, d, _ in _case_cells(cells) if d == "calibrated"]
    for case in cases:
        cal, true, nom = (cells.get(f"{case}-{d}") for d in ("calibrated", "true", "nominal"))
        for k, (header, digits, _) in SWEEP_METRICS.items():
            ref, mean = base["summary"][k], cal["summary"][k]["mean"]
            within = "n/a" if mean is None or not ref["ci"] else "yes" if ref["ci"][0] <= mean <= ref["ci"][1] else "no"
            d = paired_difference(cal, base, k)
            zero = "n/a" if not d["ci"] or d["ci"][0] is None else "yes" if d["ci"][0] <= 0 <= d["ci"][1] else "no"
            vs_true = "-" if true is None else summary_text(paired_difference(cal, true, k), digits, signed=True)
            vs_nom = "-" if nom is None else summary_text(paired_difference(nom, base, k), digits, signed=True)
            calibrated = summary_text(cal["summary"][k], digits) if mean is not None else "n/a"
            row = [case, header, summary_text(ref, digits), calibrated, within, summary_text(d, digits, signed=True),
                   zero, vs_true, vs_nom]  # fmt: skip
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"
