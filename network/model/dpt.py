"""DPT head: four levels of patch tokens reassembled at four scales and fused (RefineNet) into dense features.

The head runs on one map at a time, ``(B*9, h*w, 4C)`` tokens per level (the concatenated step outputs of one
interleaved iteration), and returns ``(B*9, D, Ho, Wo)`` features at the canonical resolution.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["DPTHead", "FusionBlock", "ResidualConvUnit"]


class ResidualConvUnit(nn.Module):
    """x + conv2(act(conv1(act(x)))), 3x3 convolutions (RefineNet)."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(dim, dim, 3, padding=1)
        self.conv2 = nn.Conv2d(dim, dim, 3, padding=1)
        self.act = nn.LeakyReLU(0.2)

    def forward(self, x: Tensor) -> Tensor:
        """(B, D, H, W) -> (B, D, H, W)."""
        return x + self.conv2(self.act(self.conv1(self.act(x))))


class FusionBlock(nn.Module):
    """RefineNet fusion: (x + rcu1(skip)) -> rcu2 -> bilinear resize -> 1x1 conv."""

    def __init__(self, dim: int, with_skip: bool) -> None:
        super().__init__()
        self.rcu1 = ResidualConvUnit(dim) if with_skip else None
        self.rcu2 = ResidualConvUnit(dim)
        self.out = nn.Conv2d(dim, dim, 1)

    def forward(self, x: Tensor, skip: Tensor | None, size: tuple[int, int]) -> Tensor:
        """Fuse (B, D, h, w) with an optional skip of the same shape and resize to ``size``."""
        if skip is not None and self.rcu1 is not None:
            x = x + self.rcu1(skip)
        x = self.rcu2(x)
        x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
        return self.out(x)


class DPTHead(nn.Module):
    """Dense prediction head: four token levels to D features at 8x the token grid.

    Reassemble level i: LayerNorm(4C) -> tokens to a (h, w) grid -> 1x1 conv to ``channels[i]`` -> resize by
    x4 (ConvTranspose 4/4), x2 (ConvTranspose 2/2), x1, x1/2 (3x3 conv, stride 2) -> 3x3 conv to D (no bias).
    Fusion from the coarsest level: four :class:`FusionBlock` s, each upsampling to the next level's size, the last
    one to 8h x 8w; then a 3x3 output conv, and a bilinear resize when ``out_size`` differs from 8h x 8w.

    Example:
        >>> import torch
        >>> head = DPTHead(in_dim=32, channels=(8, 8, 8, 8), dim=4)
        >>> levels = [torch.zeros(2, 3 * 3, 32)] * 4  # four levels of a 3 x 3 token grid
        >>> head(levels, (3, 3), (24, 24)).shape
        torch.Size([2, 4, 24, 24])
    """

    def __init__(self, in_dim: int, channels: Sequence[int], dim: int) -> None:
        super().__init__()
        self.norms = nn.ModuleList(nn.LayerNorm(in_dim, eps=1e-6) for _ in range(4))
        self.projects = nn.ModuleList(nn.Conv2d(in_dim, c, 1) for c in channels)
        c0, c1, _, c3 = channels
        self.resize = nn.ModuleList(
            [
                nn.ConvTranspose2d(c0, c0, 4, stride=4),
                nn.ConvTranspose2d(c1, c1, 2, stride=2),
                nn.Identity(),
                nn.Conv2d(c3, c3, 3, stride=2, padding=1),
            ]
        )
        self.scratch = nn.ModuleList(nn.Conv2d(c, dim, 3, padding=1, bias=False) for c in channels)
        self.fusion = nn.ModuleList([FusionBlock(dim, with_skip=i < 3) for i in range(4)])
        self.output_conv = nn.Conv2d(dim, dim, 3, padding=1)

    def forward(self, levels: Sequence[Tensor], grid: tuple[int, int], out_size: tuple[int, int]) -> Tensor:
        """Decode four levels of patch tokens.

        Args:
            levels: Four tensors (B, h*w, 4C), finest first (the earliest iteration first).
            grid: The token grid (h, w).
            out_size: Output size (Ho, Wo).

        Returns:
            Features (B, D, Ho, Wo).
        """
        h, w = grid
        feats = []
        for i, tok in enumerate(levels):
            x = self.norms[i](tok).transpose(1, 2).reshape(tok.shape[0], -1, h, w)
            x = self.resize[i](self.projects[i](x))
            feats.append(self.scratch[i](x))
        x = self.fusion[3](feats[3], None, feats[2].shape[-2:])
        x = self.fusion[2](x, feats[2], feats[1].shape[-2:])
        x = self.fusion[1](x, feats[1], feats[0].shape[-2:])
        x = self.fusion[0](x, feats[0], (8 * h, 8 * w))
        x = self.output_conv(x)
        if tuple(x.shape[-2:]) != tuple(out_size):
            x = F.interpolate(x, size=tuple(out_size), mode="bilinear", align_corners=False)
        return x
