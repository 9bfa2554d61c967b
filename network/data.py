"""Dataset samples as tensors for the network (channel-first inside network/).

Reads the renderer's samples (:mod:`pbrdf.data.dataset`) and, for real captures, the decoder's output.
Input normalisation lives here once (:func:`normalize_maps`), used by training and inference:
the unpol and LP maps are radiometric and scale with exposure and display brightness, so they
are divided by one robust scale per capture; CP is already a ratio in [-1, 1].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch.utils.data import Dataset

from pbrdf.data import dataset as pdataset

__all__ = ["normalize_maps", "sample_to_tensors", "SampleDataset", "resize_batch", "gather_pixels"]

TARGET_KEYS = ("normal", "albedo", "roughness", "metallic")


def normalize_maps(maps: torch.Tensor, mask: torch.Tensor, *, quantile: float = 0.95) -> torch.Tensor:
    """Scale unpol and LP maps by the ``quantile`` of their masked total; CP is kept.

    Args:
        maps: ``(*, 9, H, W)`` nine maps in :data:`pbrdf.sensor.decode.NINE_MAP_NAMES` order.
        mask: ``(*, 1, H, W)`` valid pixels.
        quantile: which quantile of ``unpol + LP`` (summed over colours) becomes 1.

    Returns:
        ``(*, 9, H, W)`` normalised maps (0 outside the mask).
    """
    m = mask.to(maps.dtype)
    total = (maps[..., :6, :, :].sum(dim=-3, keepdim=True) * m).flatten(-3)  # (*, H*W)
    scales = []
    for row, mrow in zip(total.reshape(-1, total.shape[-1]), m.reshape(-1, total.shape[-1]), strict=True):
        vals = row[mrow > 0]
        scales.append(torch.quantile(vals, quantile) if vals.numel() else row.new_tensor(1.0))
    scale = torch.stack(scales).reshape(*total.shape[:-1], 1, 1, 1).clamp_min(1e-8)
    out = torch.cat([maps[..., :6, :, :] / scale, maps[..., 6:, :, :]], dim=-3)
    return out * m


def gather_pixels(maps: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """``(B, C, H, W)`` maps at flat pixel indices ``(B, P)`` (``row * W + col``) -> ``(B, C, P)``.

    Example:
        >>> maps = torch.arange(6.0).reshape(1, 1, 2, 3)
        >>> gather_pixels(maps, torch.tensor([[5, 0]]))  # pixels (1, 2) and (0, 0)
        tensor([[[5., 0.]]])
    """
    b, c = maps.shape[:2]
    return maps.reshape(b, c, -1).gather(2, pixels[:, None, :].expand(-1, c, -1))


def sample_to_tensors(sample: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Channel-last sample arrays -> channel-first float tensors (mask as float 0/1)."""
    out = {"maps": torch.from_numpy(np.ascontiguousarray(sample["maps"].transpose(2, 0, 1)))}
    out["mask"] = torch.from_numpy(sample["mask"].astype(np.float32))[None]
    for k in TARGET_KEYS:
        if k in sample:
            a = sample[k]
            a = a[..., None] if a.ndim == 2 else a
            out[k] = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))
    return out


def resize_batch(batch: dict[str, torch.Tensor], size: int) -> dict[str, torch.Tensor]:
    """Resize every map of a (batched or not) sample to ``size x size``.

    Bilinear for the maps and targets, nearest for the mask; normals are renormalised and the
    outputs zeroed outside the resized mask.
    """
    out = {}
    for k, v in batch.items():
        x = v[None] if v.ndim == 3 else v
        if k == "mask":
            y = F.interpolate(x, size=(size, size), mode="nearest")
        else:
            y = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)
        out[k] = y if v.ndim == 4 else y[0]
    mask = out["mask"]
    if "normal" in out:
        n = out["normal"]
        out["normal"] = n / n.norm(dim=-3, keepdim=True).clamp_min(1e-8)
    for k in out:
        if k != "mask":
            out[k] = out[k] * mask
    return out


class SampleDataset(Dataset):
    """The completed samples of a rendered dataset folder, as normalised tensors.

    Args:
        root: dataset folder written by ``headless/render.py``.
        size: resize every sample to ``size x size`` (None keeps the rendered size).
        indices: which sample indices to use (default: all completed ones, sorted).
    """

    def __init__(self, root: str | Path, *, size: int | None = None, indices: list[int] | None = None) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: dataset folder not found")
        done = sorted(pdataset.completed_indices(self.root))
        if not done:
            raise ValueError(f"{self.root}: no completed samples (render some with headless/render.py)")
        self.indices = done if indices is None else [i for i in indices if i in set(done)]
        self.size = size

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        sample, _ = pdataset.read_sample(self.root, self.indices[i], keys=("maps", "mask", *TARGET_KEYS))
        t = sample_to_tensors(sample)
        if self.size is not None and t["maps"].shape[-1] != self.size:
            t = resize_batch(t, self.size)
        t["maps"] = normalize_maps(t["maps"], t["mask"])
        return t
