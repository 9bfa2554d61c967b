"""Relight the ground truth and the prediction of a scene alike, and score the relit frames.

An artist judges an asset by how it relights, not by its maps. For a synthetic scene the true
maps are known, so both map sets go through exactly the same Blender import and Cycles relight
(``headless/relight.py``: the capture's camera, a point-light orbit and a sky), and each
prediction frame is scored against the truth frame under the same light: PSNR and LPIPS over the
pixels either asset covers (a missing or extra part of the prediction counts against it).

The prediction's relief is anchored at the true median depth, standing in for the distance a user
measures and enters as ``distance_m``; everything else comes from the capture path.

Example:
    >>> import numpy as np
    >>> a = np.zeros((4, 4, 4)); a[1:3, 1:3] = 0.5, 0.5, 0.5, 1.0
    >>> b = a.copy(); b[1, 1, :3] = 0.6
    >>> round(frame_scores(b, a, lpips=False)["psnr"], 2)
    26.02
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from network import metrics

__all__ = ["frame_scores", "relight", "truth_maps", "compare_relit"]

#: ``headless/relight.py``, run in its own process (bpy never shares one with torch).
RELIGHT_SCRIPT = Path(__file__).resolve().parents[2] / "headless" / "relight.py"


def truth_maps(gt: dict[str, np.ndarray], region: np.ndarray) -> dict[str, np.ndarray]:
    """The ground truth as :func:`pbrdf.data.predictions.write_predictions` expects a prediction.

    Args:
        gt: ``normal (H, W, 3)``, ``albedo (H, W, 3)``, ``roughness``, ``metallic`` ``(H, W)`` or
            ``(H, W, 1)`` and optionally ``depth`` (camera-frame z in m, 0 outside).
        region: ``(H, W)`` bool, the object coverage.

    Returns:
        ``(H, W, C)`` float32 maps, zero outside ``region``, with ``mask`` (and ``depth``).
    """
    out = {}
    for key in ("normal", "albedo", "roughness", "metallic", "depth"):
        if key not in gt:
            continue
        a = np.asarray(gt[key], dtype=np.float32)
        a = a[..., None] if a.ndim == 2 else a
        out[key] = np.where(region[..., None], a, 0.0).astype(np.float32)
    out["mask"] = region.astype(np.float32)[..., None]
    return out


def relight(assets: list[tuple[Path, str, Path, bool]], *, frames: int, size: int, samples: int, denoise: bool,
            on_done: Callable[[int], None] | None = None) -> list[list[Path]]:  # fmt: skip
    """Import each asset's ``maps_dir/<name>_*`` into Blender and relight it, all in one Blender process.

    ``headless/relight.py --jobs``: bpy starts once for every asset, and each asset is relit as a
    process of its own would relight it.

    Args:
        assets: ``(maps_dir, name, dest, save_blend)`` per asset: the frames go to ``dest``, and
            with ``save_blend`` the scene to ``dest/<name>.blend``.
        frames: point-light orbit frames per asset.
        size: longest side of a frame in pixels.
        samples: Cycles samples per pixel.
        denoise: Cycles' denoiser on the frames.
        on_done: called with the number of assets finished so far, as each finishes (a progress bar).

    Returns:
        Each asset's frames (orbit, then sky), in the order of ``assets``.

    Raises:
        RuntimeError: the relight process failed (its last error line).
    """
    jobs = [{"input": str(m), "name": n, "out": str(d), "save_blend": b} for m, n, d, b in assets]
    with tempfile.TemporaryDirectory(prefix="relight-jobs-") as tmp:
        jobs_file = Path(tmp) / "jobs.json"
        jobs_file.write_text(json.dumps(jobs, indent=1) + "\n")
        cmd = [sys.executable, str(RELIGHT_SCRIPT), "--jobs", str(jobs_file), "--frames", str(frames),
               "--size", str(size), "--samples", str(samples), "--denoise" if denoise else "--no-denoise",
               "--quiet"]  # fmt: skip
        errors = Path(tmp) / "stderr.txt"  # a file, not a pipe: a full pipe would stall the process
        with errors.open("w") as err, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True) as proc:
            done = 0
            for line in proc.stdout:  # "wrote N files to OUT" as each asset finishes
                if line.startswith("wrote ") and on_done is not None:
                    done += 1
                    on_done(done)
        stderr = errors.read_text()
    if proc.returncode:
        last = (stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"Blender relighting failed: {last}")
    return [[*sorted(d.glob("point_*.png")), *sorted(d.glob("env_*.png"))] for _, _, d, _ in assets]


def frame_scores(pred: np.ndarray, truth: np.ndarray, *, lpips: bool = True) -> dict[str, float | None]:
    """PSNR (dB) and LPIPS of one relit prediction frame against the truth frame.

    Args:
        pred: ``(H, W, 4)`` RGBA in [0, 1] (alpha: the asset's coverage).
        truth: the same for the ground truth.
        lpips: also compute LPIPS (needs torch and the LPIPS weights).

    Returns:
        ``{"psnr": dB, "lpips": value or None}`` over the pixels either frame covers (alpha > 0).
    """
    if pred.shape != truth.shape or pred.ndim != 3 or pred.shape[-1] != 4:
        raise ValueError(f"expected two (H, W, 4) RGBA frames; got {pred.shape} and {truth.shape}")
    mask = (pred[..., 3] > 0) | (truth[..., 3] > 0)
    if not mask.any():
        return {"psnr": None, "lpips": None}
    a, b = pred[..., :3], truth[..., :3]
    return {"psnr": metrics.psnr(a, b, mask), "lpips": metrics.lpips(a, b, mask) if lpips else None}


def compare_relit(pred_frames: list[Path], truth_frames: list[Path], *, lpips: bool = True) -> list[dict]:
    """:func:`frame_scores` of each pair of frames with the same file name.

    Returns:
        One ``{"frame": file name, "psnr": ..., "lpips": ...}`` per frame, in order.

    Raises:
        ValueError: the two relights did not write the same frames.
    """
    if [p.name for p in pred_frames] != [t.name for t in truth_frames]:
        raise ValueError("the prediction and the truth were not relit into the same frames")
    return [{"frame": p.name, **frame_scores(_rgba(p), _rgba(t), lpips=lpips)}
            for p, t in zip(pred_frames, truth_frames, strict=True)]  # fmt: skip


def _rgba(path: Path) -> np.ndarray:
    from PIL import Image  # noqa: PLC0415

    with Image.open(path) as im:
        return np.asarray(im.convert("RGBA"), dtype=np.float64) / 255.0
