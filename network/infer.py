"""Inference at any input size: crop to the mask, resize to the network, decode masked pixels, map back.

Inputs are either a dataset sample (EXR with the nine maps and mask) or a capture folder (raw
HDR brackets + ``capture.json``), which goes through :mod:`pbrdf.decode` exactly like the
synthetic data did. Outputs are full-size ``(H, W, C)`` float32 maps, zero outside the mask.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812

from pbrdf import capture as pcapture
from pbrdf import dataset as pdataset

from .data import normalize_maps
from .model import PolarInverseModel

__all__ = ["OUTPUTS", "load_input", "predict", "mask_bbox"]

#: Output maps and their channel counts.
OUTPUTS = {"normal": 3, "albedo": 3, "roughness": 1, "metallic": 1}


def load_input(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Nine maps ``(H, W, 9)`` and mask ``(H, W)`` from a sample EXR/JSON or a capture folder."""
    path = Path(path)
    if path.is_dir() and (path / pcapture.CAPTURE_JSON).is_file():
        dec = pcapture.decode_capture(path)
        return dec.maps, dec.mask
    if path.suffix in (".exr", ".json") and path.exists():
        sample, _ = pdataset.read_sample(path, keys=("maps", "mask"))
        return sample["maps"], sample["mask"]
    raise FileNotFoundError(f"{path}: not a sample (.exr/.json) or a capture folder with {pcapture.CAPTURE_JSON}")


def mask_bbox(mask: np.ndarray, margin: float = 0.05) -> tuple[int, int, int, int]:
    """Square ``(y0, x0, y1, x1)`` around the mask with a margin, clipped to the image."""
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        raise ValueError("the mask is empty: nothing to reconstruct")
    h, w = mask.shape
    cy, cx = (ys.min() + ys.max() + 1) / 2, (xs.min() + xs.max() + 1) / 2
    side = max(ys.max() - ys.min() + 1, xs.max() - xs.min() + 1) * (1 + 2 * margin)
    side = int(min(max(side, 8), max(h, w)))
    y0 = int(np.clip(round(cy - side / 2), 0, max(h - side, 0)))
    x0 = int(np.clip(round(cx - side / 2), 0, max(w - side, 0)))
    return y0, x0, min(y0 + side, h), min(x0 + side, w)


@torch.no_grad()
def predict(model: PolarInverseModel, maps: np.ndarray, mask: np.ndarray) -> dict[str, np.ndarray]:
    """Normal, albedo, roughness, metallic ``(H, W, C)`` for nine maps of any size.

    The masked region is cropped (square), resized to the model's input size, decoded (masked
    pixels only, in chunks) and resized back into the full frame.
    """
    if maps.ndim != 3 or maps.shape[-1] != 9 or mask.shape != maps.shape[:2]:
        raise ValueError(f"expected maps (H, W, 9) and mask (H, W); got {maps.shape} and {mask.shape}")
    if not np.all(np.isfinite(maps)):
        raise ValueError("maps contain NaN or Inf")
    y0, x0, y1, x1 = mask_bbox(mask)
    size = model.config.image_size
    m = torch.from_numpy(np.ascontiguousarray(maps[y0:y1, x0:x1].transpose(2, 0, 1)))[None].float()
    k = torch.from_numpy(mask[y0:y1, x0:x1].astype(np.float32))[None, None]
    m = F.interpolate(m, size=(size, size), mode="bilinear", align_corners=False)
    k = F.interpolate(k, size=(size, size), mode="nearest")
    model.eval()
    pred = model(normalize_maps(m, k), k)
    h, w = mask.shape
    out = {}
    for name, c in OUTPUTS.items():
        x = F.interpolate(pred[name], size=(y1 - y0, x1 - x0), mode="bilinear", align_corners=False)[0]
        if name == "normal":
            x = x / x.norm(dim=0, keepdim=True).clamp_min(1e-8)
        full = np.zeros((h, w, c), np.float32)
        full[y0:y1, x0:x1] = x.permute(1, 2, 0).numpy()
        full[~mask] = 0.0
        out[name] = full
    out["mask"] = mask.astype(np.float32)[..., None]
    return out
