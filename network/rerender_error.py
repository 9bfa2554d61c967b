"""Re-rendering error on real captures: the model's maps re-rendered under the display, against the measured maps.

Real captures have no ground-truth materials; what can be scored is how well the prediction
explains the capture. Each item of :class:`network.realdata.RealDataset` goes through the model
(its input variant applied), :func:`network.rerender.rerender_dense` renders the predicted
surface under the rig's display patches, and the re-rendered ``unpol`` and ``LP`` maps are
compared with the measured ones up to one global scale (the capture's exposure is unknown):
si-PSNR relative to the capture's 99th-percentile brightness, si-RMSE, si-MSE and, with LPIPS
weights installed, si-LPIPS of the unpol RGB image (:mod:`network.metrics`). Means are weighted
by each capture's mask pixels.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from . import metrics
from .inputs import apply_inputs
from .lpips import lpips_status

__all__ = ["COLUMNS", "rerender_error", "rerender_markdown"]

#: Columns: (key, header, True when higher is better).
COLUMNS = (
    ("si_psnr", "si-PSNR", True),
    ("si_lpips", "si-LPIPS", False),
    ("si_rmse", "si-RMSE", False),
    ("si_mse", "si-MSE", False),
)


def _capture_row(model: torch.nn.Module, variant: str, item: Mapping[str, torch.Tensor], lpips: bool) -> dict:
    """The error columns of one real capture (a :class:`network.realdata.RealDataset` item)."""
    from .rerender import Patches, rerender_dense  # noqa: PLC0415

    batch = {k: v[None] for k, v in item.items()}
    with torch.no_grad():
        pred = model(apply_inputs(batch["maps"], variant), batch["mask"])
        rendered = rerender_dense(pred, batch["mask"], batch["points"], Patches.unpack(batch["patches"]))
    measured = batch["maps"][0, :6].permute(1, 2, 0).numpy()
    sim = torch.cat([rendered["unpol"], rendered["lp"]], dim=1)[0].permute(1, 2, 0).numpy()
    mask = batch["mask"][0, 0].numpy() > 0
    peak = float(np.quantile(measured[mask], 0.99)) or 1.0  # PSNR relative to the capture's brightness
    row = {"pixels": int(mask.sum()), "peak": peak, "si_psnr": metrics.si_psnr(sim / peak, measured / peak, mask),
           "si_rmse": metrics.si_rmse(sim, measured, mask), "si_mse": metrics.si_mse(sim, measured, mask),
           "si_lpips": None}  # fmt: skip
    if lpips:  # LPIPS on the unpol (diffuse) RGB image, brightness-normalised
        row["si_lpips"] = metrics.si_lpips(sim[..., :3], measured[..., :3], mask, peak=peak)
    return row


def rerender_error(model: torch.nn.Module, variant: str, real: str | Path, *, limit: int | None = None) -> dict:
    """Re-rendering error of one model on a folder of real captures.

    Args:
        model: the loaded model.
        variant: its input variant (:mod:`network.inputs`).
        real: folder of real captures (:class:`network.realdata.RealDataset`).
        limit: score only the first ``limit`` captures.

    Returns:
        ``{"mean": {column: pixel-weighted mean}, "per_sample": rows}``, or ``{"skipped": reason}``
        for the white-illumination variant (real captures are taken under the RGB pattern).
    """
    from .realdata import RealDataset  # noqa: PLC0415

    if variant == "white":
        return {"skipped": "the white-illumination variant needs captures under a white display"}
    lpips_ok, _ = lpips_status()
    ds = RealDataset(real, model.config.image_size)
    rows = [
        {"index": j, **_capture_row(model, variant, ds[j], lpips_ok)}
        for j in range(len(ds) if limit is None else min(limit, len(ds)))
    ]
    mean: dict[str, float | None] = {}
    for k, _, _ in COLUMNS:
        vals = [(r[k], r["pixels"]) for r in rows if r.get(k) is not None]
        w = sum(p for _, p in vals)
        mean[k] = float(sum(v * p for v, p in vals) / w) if vals and w > 0 else None
    return {"mean": mean, "per_sample": rows}


def rerender_markdown(result: Mapping[str, Any], label: str) -> str:
    """One-row Markdown table of :func:`rerender_error`'s result (or why it was skipped).

    Example:
        >>> print(rerender_markdown({"skipped": "no captures"}, "Ours"), end="")
        Re-rendering error on real data (Ours): skipped (no captures).
    """
    if "skipped" in result:
        return f"Re-rendering error on real data ({label}): skipped ({result['skipped']}).\n"
    mean = result["mean"]
    cells = ["n/a" if mean.get(k) is None else f"{mean[k]:.{2 if k == 'si_psnr' else 4}f}" for k, _, _ in COLUMNS]
    lines = [f"Re-rendering error on real data (unpol + LP maps, {len(result['per_sample'])} captures)", "",
             "| Method | " + " | ".join(h for _, h, _ in COLUMNS) + " |",
             "|---|" + "|".join("---:" for _ in COLUMNS) + "|",
             "| " + " | ".join([label, *cells]) + " |"]  # fmt: skip
    return "\n".join(lines) + "\n"
