"""Pixel sampling: random masked pixels for training, bilinear feature samples at pixel centres.

Pixels are flat indices ``row * W + col`` into an ``(H, W)`` image. Features live on a coarser (or finer)
``(Hc, Wc)`` grid covering the same area; a pixel centre ``(row + 0.5, col + 0.5)`` maps to feature coordinates
``(row + 0.5) * Hc / H - 0.5`` (as ``F.grid_sample`` with ``align_corners=False``, border padding).

Example:
    >>> features = torch.arange(4.0).reshape(1, 1, 2, 2)  # a 2 x 2 feature map over a 4 x 4 image
    >>> sample_bilinear(features, torch.tensor([[0, 5, 15]]), (4, 4))  # pixels (0, 0), (1, 1), (3, 3)
    tensor([[[0.0000, 0.7500, 3.0000]]])
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["sample_bilinear", "sample_bilinear_rows", "sample_pixels"]


def sample_pixels(mask: Tensor, count: int, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor]:
    """Random pixels inside the mask, without repetition, per image.

    Args:
        mask: (B, 1, H, W), nonzero inside the object.
        count: Pixels wanted per image.
        generator: Optional generator (on ``mask``'s device).

    Returns:
        ``pixels`` (B, P) flat indices ``row * W + col`` and ``valid`` (B, P) bool, with
        P = min(count, largest mask count in the batch). Images with fewer than P masked pixels are padded
        with outside pixels marked invalid.
    """
    b = mask.shape[0]
    inside = mask.reshape(b, -1) > 0
    p = max(1, min(count, int(inside.sum(1).max())))
    scores = torch.rand(inside.shape, generator=generator, device=mask.device)
    scores = torch.where(inside, scores, scores - 2.0)
    pixels = scores.topk(p, dim=1).indices
    return pixels, torch.gather(inside, 1, pixels)


def sample_bilinear(features: Tensor, pixels: Tensor, size: tuple[int, int]) -> Tensor:
    """Bilinear samples of a feature map at the centres of pixels of a finer (or coarser) image.

    Same values as ``F.grid_sample(..., mode="bilinear", padding_mode="border", align_corners=False)`` at the
    pixel centres, but the coordinates and weights are computed in float32 and the samples gathered, so that under
    bf16 autocast neither the coordinates are rounded to bf16 (up to 0.4 of a 192-pixel feature cell) nor the whole
    feature map is cast to float32 for each chunk.

    Args:
        features: (B, C, Hc, Wc).
        pixels: (B, P) flat indices ``row * W + col`` into an image of ``size`` = (H, W) covering the same area.
        size: (H, W).

    Returns:
        (B, C, P), in ``features.dtype``.
    """
    b, c, hc, wc = features.shape
    y0, x0, y1, x1, wy, wx = _bilinear_corners(pixels, size, (hc, wc))
    wy, wx = wy.to(features.dtype)[:, None], wx.to(features.dtype)[:, None]
    flat = features.reshape(b, c, hc * wc)

    def take(yi: Tensor, xi: Tensor) -> Tensor:
        return torch.gather(flat, 2, (yi * wc + xi)[:, None].expand(-1, c, -1))

    top = take(y0, x0) * (1 - wx) + take(y0, x1) * wx
    bottom = take(y1, x0) * (1 - wx) + take(y1, x1) * wx
    return top * (1 - wy) + bottom * wy


def _bilinear_corners(
    pixels: Tensor, size: tuple[int, int], feature_size: tuple[int, int]
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Corner indices (y0, x0, y1, x1) and float32 weights (wy, wx) of :func:`sample_bilinear` at pixel centres."""
    (h, w), (hc, wc) = size, feature_size
    row = torch.div(pixels, w, rounding_mode="floor")
    col = pixels - row * w
    y = ((row.float() + 0.5) * (hc / h) - 0.5).clamp(0, hc - 1)
    x = ((col.float() + 0.5) * (wc / w) - 0.5).clamp(0, wc - 1)
    y0, x0 = y.floor().long(), x.floor().long()
    y1, x1 = (y0 + 1).clamp(max=hc - 1), (x0 + 1).clamp(max=wc - 1)
    return y0, x0, y1, x1, y - y0, x - x0


def sample_bilinear_rows(table: Tensor, pixels: Tensor, size: tuple[int, int], feature_size: tuple[int, int]) -> Tensor:
    """:func:`sample_bilinear` of one image from a channels-last table: the same values (to float rounding).

    The four corner rows are gathered and weighted by one ``F.embedding_bag`` (contiguous rows, no (C, P) gathers
    with expanded indices), which is what makes dense decoding's sampling cheap.

    Args:
        table: (Hc*Wc, C) features of one image, row ``y * Wc + x``.
        pixels: (P,) flat indices ``row * W + col`` into an image of ``size`` = (H, W).
        size: (H, W).
        feature_size: (Hc, Wc).

    Returns:
        (P, C), in ``table.dtype``.
    """
    wc = feature_size[1]
    y0, x0, y1, x1, wy, wx = _bilinear_corners(pixels, size, feature_size)
    index = torch.stack([y0 * wc + x0, y0 * wc + x1, y1 * wc + x0, y1 * wc + x1], dim=1)
    weight = torch.stack([(1 - wy) * (1 - wx), (1 - wy) * wx, wy * (1 - wx), wy * wx], dim=1).to(table.dtype)
    return F.embedding_bag(index, table, per_sample_weights=weight, mode="sum")
