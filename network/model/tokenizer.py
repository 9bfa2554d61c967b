"""Per-map tokenizer: a DINOv2-style ViT applied to each of the nine maps, and the learned map identity.

Each map (times the mask), resized to the canonical resolution and stacked with the resized mask (:data:`IN_CHANS`
= 2 input channels), goes through one shared ViT: patch embedding, class token, register tokens, a learned
position embedding interpolated bicubically to the token grid, pre-norm blocks with LayerScale, final LayerNorm.
:class:`MapEmbedding` then adds a learned polarization-state embedding and colour-channel embedding, so later
stages know which map a token comes from.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .layers import Block, init_linear_, trunc_normal_
from .maps import MAP_COLOR, MAP_POLARIZATION

__all__ = ["IN_CHANS", "MapEmbedding", "PatchEmbed", "ViTTokenizer", "interpolate_pos_embed"]

#: Input channels of the tokenizer: (map value x mask, mask).
IN_CHANS = 2


def interpolate_pos_embed(pos_embed: Tensor, grid: tuple[int, int], prefix: int = 1) -> Tensor:
    """Resize a learned position embedding to another token grid (bicubic, align_corners=False).

    Args:
        pos_embed: (1, prefix + G*G, C): ``prefix`` leading positions (the class token) then a square G x G grid.
        grid: Target grid (h, w).
        prefix: Number of leading non-grid positions, copied unchanged.

    Returns:
        (1, prefix + h*w, C); the input itself when the grid already matches.

    Raises:
        ValueError: If the grid part is not square.

    Example:
        >>> pos = torch.zeros(1, 1 + 4 * 4, 8)  # class token + a 4 x 4 grid
        >>> interpolate_pos_embed(pos, (3, 5)).shape
        torch.Size([1, 16, 8])
    """
    n = pos_embed.shape[1] - prefix
    side = math.isqrt(n)
    if side * side != n:
        raise ValueError(f"Position embedding grid must be square; got {n} grid positions")
    if (side, side) == tuple(grid):
        return pos_embed
    head, body = pos_embed[:, :prefix], pos_embed[:, prefix:]
    c = body.shape[-1]
    body = body.reshape(1, side, side, c).permute(0, 3, 1, 2)
    dtype = body.dtype
    body = F.interpolate(body.float(), size=tuple(grid), mode="bicubic", align_corners=False).to(dtype)
    body = body.permute(0, 2, 3, 1).reshape(1, grid[0] * grid[1], c)
    return torch.cat([head, body], dim=1)


class PatchEmbed(nn.Module):
    """Non-overlapping patches to tokens (``proj``: Conv2d with kernel = stride = patch size)."""

    def __init__(self, patch_size: int, in_chans: int, dim: int) -> None:
        super().__init__()
        self.proj = nn.Conv2d(in_chans, dim, patch_size, stride=patch_size)

    def forward(self, x: Tensor) -> tuple[Tensor, tuple[int, int]]:
        """(B, in_chans, H, W) -> tokens (B, h*w, C) and the grid (h, w)."""
        x = self.proj(x)
        return x.flatten(2).transpose(1, 2), (x.shape[2], x.shape[3])


class ViTTokenizer(nn.Module):
    """DINOv2-style ViT with register tokens, applied to one map at a time.

    State-dict keys (the format :func:`load_pretrained_vit` reads; DINOv2's own names):
    ``cls_token`` (1, 1, C), ``register_tokens`` (1, R, C), ``pos_embed`` (1, 1 + G*G, C) with G the pretraining
    grid, ``patch_embed.proj.weight`` (C, 2, p, p), ``patch_embed.proj.bias`` (C,),
    ``blocks.{i}.norm1.{weight,bias}``, ``blocks.{i}.attn.qkv.{weight,bias}`` (3C, C), ``blocks.{i}.attn.proj.*``,
    ``blocks.{i}.ls1.gamma``, ``blocks.{i}.norm2.*``, ``blocks.{i}.mlp.fc1.*``, ``blocks.{i}.mlp.fc2.*``,
    ``blocks.{i}.ls2.gamma``, ``norm.{weight,bias}``.

    Output tokens are ``[cls, registers, patches]``; the position embedding covers the class token and the patches
    (registers get none) and is interpolated bicubically when the token grid differs from G.
    """

    def __init__(
        self,
        patch_size: int,
        dim: int,
        depth: int,
        heads: int,
        registers: int,
        grid: int,
        mlp_ratio: float = 4.0,
        layerscale: float = 1.0,
        in_chans: int = IN_CHANS,
        init_std: float = 0.02,
    ) -> None:
        super().__init__()
        self.patch_size = patch_size
        self.num_prefix = 1 + registers
        self.patch_embed = PatchEmbed(patch_size, in_chans, dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim))
        self.register_tokens = nn.Parameter(torch.zeros(1, registers, dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + grid * grid, dim))
        self.blocks = nn.ModuleList(Block(dim, heads, mlp_ratio, layerscale=layerscale) for _ in range(depth))
        self.norm = nn.LayerNorm(dim, eps=1e-6)
        init_linear_(self, init_std)
        trunc_normal_(self.pos_embed)
        trunc_normal_(self.cls_token)
        trunc_normal_(self.register_tokens)

    def forward(self, x: Tensor, extra: Tensor | None = None) -> tuple[Tensor, tuple[int, int]]:
        """Tokens of a batch of single maps.

        Args:
            x: (B, in_chans, H, W), H and W multiples of the patch size.
            extra: Optional (B, h*w, C) added to the patch embeddings (the light input's tokens).

        Returns:
            Tokens (B, 1 + R + h*w, C) after the final LayerNorm, and the grid (h, w).
        """
        tokens, grid = self.patch_embed(x)
        if extra is not None:
            tokens = tokens + extra.to(tokens.dtype)
        b = tokens.shape[0]
        tokens = torch.cat([self.cls_token.expand(b, -1, -1), tokens], dim=1)
        tokens = tokens + interpolate_pos_embed(self.pos_embed, grid).to(tokens.dtype)
        tokens = torch.cat([tokens[:, :1], self.register_tokens.expand(b, -1, -1), tokens[:, 1:]], dim=1)
        for blk in self.blocks:
            tokens = blk(tokens)
        return self.norm(tokens), grid


class MapEmbedding(nn.Module):
    """Learned identity of each map: polarization-state embedding + colour-channel embedding.

    ``polarization`` (3, C) rows: unpol, LP, CP; ``color`` (3, C) rows: R, G, B; map n gets
    ``polarization[MAP_POLARIZATION[n]] + color[MAP_COLOR[n]]``.
    """

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.polarization = nn.Parameter(torch.zeros(3, dim))
        self.color = nn.Parameter(torch.zeros(3, dim))
        trunc_normal_(self.polarization)
        trunc_normal_(self.color)
        self.register_buffer("pol_index", torch.tensor(MAP_POLARIZATION), persistent=False)
        self.register_buffer("color_index", torch.tensor(MAP_COLOR), persistent=False)

    def forward(self) -> Tensor:
        """The nine embeddings, (9, C)."""
        return self.polarization[self.pol_index] + self.color[self.color_index]
