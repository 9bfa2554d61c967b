"""Constant predictors from training-set statistics: the rows every results table carries.

A learned model is only worth its cost where it beats answering the same thing everywhere: the
normal facing the camera ``(0, 0, 1)``, and the training set's mean albedo, roughness and
metallic. The means are pixel-weighted over the training split's masks and stored as a small
JSON file beside the checkpoint (``train_stats.json``), so evaluation never needs the training
data itself.

Example:
    >>> stats = {"albedo": [0.5, 0.4, 0.3], "roughness": 0.4, "metallic": 0.3}
    >>> pred = constant_predict(stats, np.ones((2, 3), bool))
    >>> pred["normal"][0, 0].tolist(), pred["roughness"][1, 2, 0].item()
    ([0.0, 0.0, 1.0], 0.4000000059604645)
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.data.splits import dataset_split
from pbrdf.io.atomic import atomic_write_text

__all__ = ["STATS_FORMAT", "STATS_FILE", "train_statistics", "save_statistics", "load_statistics", "constant_predict"]

#: Value of the ``format`` key of a statistics file.
STATS_FORMAT = "pdir-train-stats/1"
#: Default file name, beside the checkpoint.
STATS_FILE = "train_stats.json"


def train_statistics(root: str | os.PathLike, *, limit: int | None = None) -> dict[str, Any]:
    """Pixel-weighted means of albedo (RGB), roughness and metallic over a dataset's masks.

    Args:
        root: the training dataset (a ``train`` split, or an unlabelled one).
        limit: read only the first ``limit`` samples.

    Returns:
        ``{"format", "split", "samples", "pixels", "albedo": [r, g, b], "roughness", "metallic"}``.

    Raises:
        ValueError: no completed samples, or a test/val split.
    """
    name = dataset_split(root)
    if name is not None and not name.startswith("train"):
        raise ValueError(f"{root}: training statistics come from the train split, not {name!r}")
    indices = sorted(pdataset.completed_indices(root, verify_hash=False))[:limit]
    if not indices:
        raise ValueError(f"{root}: no completed samples")
    sums = np.zeros(5)
    pixels = 0
    for i in indices:
        s, _ = psample.read_sample(root, i, keys=("mask", "albedo", "roughness", "metallic"))
        m = s["mask"]
        sums[:3] += s["albedo"][m].sum(axis=0, dtype=np.float64)
        sums[3] += s["roughness"][m].sum(dtype=np.float64)
        sums[4] += s["metallic"][m].sum(dtype=np.float64)
        pixels += int(m.sum())
    mean = sums / max(pixels, 1)
    return {
        "format": STATS_FORMAT,
        "split": name,
        "samples": len(indices),
        "pixels": pixels,
        "albedo": [float(x) for x in mean[:3]],
        "roughness": float(mean[3]),
        "metallic": float(mean[4]),
    }


def save_statistics(stats: dict[str, Any], path: str | os.PathLike) -> Path:
    """Write statistics as strict JSON (atomically); returns the path."""
    path = Path(path)
    atomic_write_text(path, json.dumps(stats, indent=2, allow_nan=False) + "\n")
    return path


def load_statistics(path: str | os.PathLike) -> dict[str, Any]:
    """Read and check a statistics file.

    Raises:
        FileNotFoundError: no file (the message says how to make one).
        ValueError: wrong format or values outside [0, 1].
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: training statistics not found (make them with "
            "`headless/evaluate.py --write-train-stats FILE --input TRAIN_DIR`)"
        )
    try:
        stats = json.loads(path.read_text())
    except ValueError as e:
        raise ValueError(f"{path}: invalid JSON ({e})") from None
    if not isinstance(stats, dict) or stats.get("format") != STATS_FORMAT:
        raise ValueError(f"{path}: not a {STATS_FORMAT} file")
    values = [*stats.get("albedo", []), stats.get("roughness"), stats.get("metallic")]
    if len(values) != 5 or not all(isinstance(v, float | int) and math.isfinite(v) and 0 <= v <= 1 for v in values):
        raise ValueError(f"{path}: albedo (3 values), roughness and metallic must be numbers in [0, 1]")
    return stats


def constant_predict(stats: dict[str, Any], mask: NDArray) -> dict[str, NDArray[np.float32]]:
    """The constant predictions on ``mask`` ``(H, W)``: normal (0, 0, 1) and the training means.

    Returns:
        ``normal``, ``albedo`` ``(H, W, 3)``, ``roughness``, ``metallic`` ``(H, W, 1)``; 0 outside
        the mask.
    """
    m = np.asarray(mask, dtype=bool)[..., None]
    h, w = m.shape[:2]
    full = {
        "normal": np.broadcast_to(np.array([0.0, 0.0, 1.0]), (h, w, 3)),
        "albedo": np.broadcast_to(np.asarray(stats["albedo"], dtype=np.float64), (h, w, 3)),
        "roughness": np.full((h, w, 1), float(stats["roughness"])),
        "metallic": np.full((h, w, 1), float(stats["metallic"])),
    }
    return {k: np.where(m, v, 0.0).astype(np.float32) for k, v in full.items()}
