"""The feed-forward model: nine polarimetric maps to per-pixel normal, albedo, roughness and metallic.

Pipeline (a reimplementation of the LINO-UniPS / PDIR design described in notes/network.md, not their code):

1. **Tokenizer** (:class:`ViTTokenizer`): each of the nine maps (times the mask), resized to the canonical
   resolution and stacked with the resized mask (2 input channels), goes through one shared DINOv2-style ViT
   (patch embedding, class token, register tokens, learned position embedding interpolated bicubically to the
   token grid, pre-norm blocks with LayerScale, final LayerNorm). A learned polarization-state embedding and a
   learned colour-channel embedding (:class:`MapEmbedding`) are then added, so later stages know which map is which.
2. **Interleaved attention** (:class:`InterleavedAttention`): tokens ``(B, 9, N, C)``; K iterations of four
   pre-norm attention blocks: spatial (within a map), spectral (R, G, B of the same polarization state),
   cross-observation (all nine maps), polarimetric (unpol, LP, CP of the same colour channel).
3. **DPT head** (:class:`DPTHead`): the patch tokens of four iterations (each the concatenation of its four
   step outputs, 4C) are reassembled at four scales and fused (RefineNet) into D features per map at the
   canonical resolution.
4. **Per-pixel decoder** (:class:`PixelDecoder`): for a pixel x, z_n(x) = phi(F_n(x)) + psi_n(I_n(x)), n = 1..9,
   with F_n sampled bilinearly from the canonical-resolution features and psi_n a value embedding whose first
   layer is map-specific (:class:`MapValueEmbedding`); self-attention across the nine observations, then
   cross-attention from one learnable query pools them into D_a; a transformer across pixels; heads for unit
   normals and for albedo, roughness, metallic in [0, 1].

Map order and attention groups (DESIGN.md): ``[R_unpol, G_unpol, B_unpol, R_LP, G_LP, B_LP, R_CP, G_CP, B_CP]``;
spectral groups {0,1,2}, {3,4,5}, {6,7,8}; polarimetric groups {0,3,6}, {1,4,7}, {2,5,8}.

Symmetry (what the design implies, pinned by tests): every stage shares its weights across maps and every
attention step sees the maps only through its groups; the pooling over the nine observations is even invariant to
*any* permutation. So without the identity parameters (:class:`MapEmbedding` on the tokens, the map-specific
first layer of :class:`MapValueEmbedding`) the model is *invariant* to any permutation that preserves both
partitions (permuting the polarization states, the colour channels, or both: rows and columns of the 3 x 3 map
grid), and only the grouped attention makes it sensitive to other permutations. The identity parameters break the
remaining symmetry, so the model can tell unpol from LP and R from G.

Initialisation: the tokenizer and interleaved blocks use a truncated normal (``config.init_std``, 0.02) for linear
layers, zero biases, LayerScale 1.0 (ViT, as LINO-UniPS) and 0.01 (interleaved); class, register, position and map
embeddings and the pooling query a truncated normal of std 0.02. The DPT and the per-pixel decoder keep PyTorch's
default initialisation (measured on the toy model: with std 0.02 in the decoder, training stayed at the
constant-prediction plateau).

Pixel transformer and chunking: in training each sampled pixel attends to all sampled pixels (self-attention over
``train_pixels`` tokens). In dense (evaluation) decoding a deterministic, evenly spread subset of at most
``train_pixels`` masked pixels forms a *context*; the context runs through the pixel transformer once, and every
pixel (in chunks of ``infer_chunk``) attends to the context at each layer. Cost is O(P x train_pixels), never
O(P^2), and results do not depend on the chunk size. A context pixel decoded as a query gets exactly its output
as a context member, and with at most ``train_pixels`` masked pixels dense decoding equals self-attention over all
of them, as in training.

Dense decoding speed (:meth:`PolarInverseModel.decode_dense`, equal to the straightforward
:meth:`PolarInverseModel.decode_dense_reference` to float rounding): the context pixels' outputs come from the
context pass instead of being decoded again; features and map values are gathered as rows of channels-last tables
(:func:`sample_bilinear_rows`); the pooling's constant query is folded into its key projection
(:meth:`PoolingAttention.forward_folded`); the per-pixel embedding runs in cache-sized pieces. About 1.7 x faster on
CPU for ``small`` and ``paper``. ``stride`` > 1 trades accuracy for time: it decodes every s-th row and column
and interpolates the rest (:func:`fill_from_decoded`).

Input scaling is the data pipeline's job: the model expects the maps already normalised (e.g. per image) and
does not rescale them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from network.config import ModelConfig

__all__ = [
    "AXIS_GROUPS",
    "AXES",
    "AxisAttentionBlock",
    "Block",
    "DPTHead",
    "DenseInputs",
    "EMBED_ELEMENTS",
    "InterleavedAttention",
    "LoadReport",
    "MAP_COLOR",
    "MAP_POLARIZATION",
    "MapEmbedding",
    "MapValueEmbedding",
    "NUM_MAPS",
    "OUTPUT_CHANNELS",
    "PixelDecoder",
    "PolarInverseModel",
    "ViTTokenizer",
    "context_pixels",
    "count_parameters",
    "estimate_flops",
    "fill_from_decoded",
    "from_sequences",
    "grid_pixels",
    "init_linear_",
    "interpolate_pos_embed",
    "load_pretrained_vit",
    "multi_head_attention",
    "safe_normalize",
    "sample_bilinear",
    "sample_bilinear_rows",
    "sample_pixels",
    "to_sequences",
    "trunc_normal_",
]

NUM_MAPS = 9
#: Polarization state of each map: 0 unpolarized, 1 LP, 2 CP.
MAP_POLARIZATION = (0, 0, 0, 1, 1, 1, 2, 2, 2)
#: Colour channel of each map: 0 R, 1 G, 2 B.
MAP_COLOR = (0, 1, 2, 0, 1, 2, 0, 1, 2)
#: Map groups attended together by each grouped axis (every group is one attention sequence).
AXIS_GROUPS: dict[str, tuple[tuple[int, ...], ...]] = {
    "spectral": ((0, 1, 2), (3, 4, 5), (6, 7, 8)),
    "polarimetric": ((0, 3, 6), (1, 4, 7), (2, 5, 8)),
    "cross": (tuple(range(NUM_MAPS)),),
}
#: Attention axes: ``spatial`` (tokens of one map), the grouped axes above, and ``global`` (all tokens of all maps).
AXES = ("spatial", "spectral", "polarimetric", "cross", "global")
#: Input channels of the tokenizer: (map value x mask, mask).
IN_CHANS = 2
#: Output maps of the decoder and their channels.
OUTPUT_CHANNELS = {"normal": 3, "albedo": 3, "roughness": 1, "metallic": 1}
#: Dense decoding embeds pixels in pieces whose widest intermediate (an observation MLP's hidden layer, 9 rows per
#: pixel) has about this many elements (16 MiB in float32). Measured on one CPU core: ``small`` 256-2048-pixel
#: pieces ran 25-35 % faster than 8192, ``paper`` 128-512 about 10 % faster than 1024.
EMBED_ELEMENTS = 1 << 22


# ----------------------------------------------------------------------------------------------------------------
# Pure functions
# ----------------------------------------------------------------------------------------------------------------


def multi_head_attention(q: Tensor, k: Tensor, v: Tensor, key_padding_mask: Tensor | None = None) -> Tensor:
    """Scaled dot-product attention over heads, through ``F.scaled_dot_product_attention``.

    The scale is 1/sqrt(head dim) (the SDPA default), so flash and memory-efficient kernels apply on GPU
    (flash only without ``key_padding_mask``).

    Args:
        q: Queries, (L, H, Sq, d).
        k: Keys, (L, H, Sk, d).
        v: Values, (L, H, Sk, d).
        key_padding_mask: Optional bool (L, Sk), True where a key may be attended. Every row needs a True.

    Returns:
        (L, H, Sq, d).
    """
    mask = None if key_padding_mask is None else key_padding_mask[:, None, None, :]
    return F.scaled_dot_product_attention(q, k, v, attn_mask=mask)


def to_sequences(x: Tensor, axis: str) -> Tensor:
    """Rearrange tokens into the attention sequences of one axis.

    Args:
        x: Tokens, (B, 9, N, C) (maps in the nine-map order, N tokens per map).
        axis: One of :data:`AXES`. ``spatial``: one sequence of N per map, (B*9, N, C). ``spectral``,
            ``polarimetric``: one sequence of 3 per group and token, (B*3*N, 3, C). ``cross``: one sequence of 9
            per token, (B*N, 9, C). ``global``: one sequence of 9*N per sample, (B, 9*N, C).

    Returns:
        The sequences, (L, S, C).

    Convention:
        Grouped axes order sequences by (sample, group, token) and members as listed in :data:`AXIS_GROUPS`;
        e.g. for ``polarimetric`` the second member of each sequence of group 0 is map 3 (R_LP).
    """
    b, m, n, c = x.shape
    if axis == "spatial":
        return x.reshape(b * m, n, c)
    if axis == "global":
        return x.reshape(b, m * n, c)
    groups = _axis_groups(axis)
    g, s = len(groups), len(groups[0])
    order = [i for grp in groups for i in grp]
    if order != list(range(m)):
        x = x[:, order]
    return x.reshape(b, g, s, n, c).permute(0, 1, 3, 2, 4).reshape(b * g * n, s, c)


def from_sequences(y: Tensor, axis: str, shape: Sequence[int]) -> Tensor:
    """Inverse of :func:`to_sequences`.

    Args:
        y: Sequences, (L, S, C), as returned by ``to_sequences(x, axis)``.
        axis: The axis used.
        shape: ``x.shape``, (B, 9, N, C).

    Returns:
        Tokens, (B, 9, N, C).
    """
    b, m, n, c = shape
    if axis in ("spatial", "global"):
        return y.reshape(b, m, n, c)
    groups = _axis_groups(axis)
    g, s = len(groups), len(groups[0])
    x = y.reshape(b, g, n, s, c).permute(0, 1, 3, 2, 4).reshape(b, m, n, c)
    order = [i for grp in groups for i in grp]
    if order != list(range(m)):
        inverse = [0] * m
        for pos, i in enumerate(order):
            inverse[i] = pos
        x = x[:, inverse]
    return x


def _axis_groups(axis: str) -> tuple[tuple[int, ...], ...]:
    if axis not in AXIS_GROUPS:
        raise ValueError(f"Unknown attention axis {axis!r}; valid axes are {AXES}")
    return AXIS_GROUPS[axis]


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


def safe_normalize(v: Tensor, dim: int = 1, eps: float = 1e-6) -> Tensor:
    """Unit vectors along ``dim``; vectors with norm <= ``eps`` become (0, 0, 1) (facing the camera).

    The division uses the norm clamped to ``eps``, so the backward pass stays finite at zero vectors.

    Args:
        v: (*, 3, *) vectors, the component axis at ``dim``.
        dim: Component axis.
        eps: Norm below which the fallback is returned.

    Returns:
        Same shape as ``v``, unit length along ``dim``.
    """
    norm = torch.linalg.vector_norm(v, dim=dim, keepdim=True)
    unit = v / norm.clamp_min(eps)
    shape = [1] * v.ndim
    shape[dim] = v.shape[dim]
    fallback = torch.zeros(shape, dtype=v.dtype, device=v.device)
    fallback.view(-1)[-1] = 1.0
    return torch.where(norm > eps, unit, fallback)


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


def context_pixels(pixels: Tensor, count: int) -> Tensor:
    """A deterministic, evenly spread subset of at most ``count`` of the given pixels.

    Args:
        pixels: (P,) flat pixel indices (e.g. the masked pixels in raster order).
        count: Maximum subset size.

    Returns:
        (min(P, count),): all pixels if P <= count, else ``pixels[(i * P) // count]`` for i < count.
    """
    p = pixels.shape[0]
    if p <= count:
        return pixels
    idx = torch.arange(count, device=pixels.device) * p // count
    return pixels[idx]


def grid_pixels(pixels: Tensor, width: int, stride: int) -> Tensor:
    """The pixels on every ``stride``-th row and column (rows and columns ``stride // 2 + k * stride``).

    Args:
        pixels: (P,) flat indices ``row * width + col``.
        width: Image width W.
        stride: Grid spacing (1 keeps all pixels).

    Returns:
        The subset, in the given order.
    """
    if stride == 1:
        return pixels
    row = torch.div(pixels, width, rounding_mode="floor")
    col = pixels - row * width
    keep = (row % stride == stride // 2) & (col % stride == stride // 2)
    return pixels[keep]


def fill_from_decoded(values: Tensor, decoded: Tensor, stride: int) -> tuple[Tensor, Tensor]:
    """Normalised convolution: every pixel as the tent-weighted mean of the decoded pixels near it.

    The kernel is separable, ``k(t) = 1 - |t| / stride`` for ``|t| < stride``, so where the four decoded
    :func:`grid_pixels` around a pixel are all there (and nothing else is decoded nearby) the result is exactly
    their bilinear interpolation; near the mask's edge the missing ones drop out and the rest are renormalised.

    Args:
        values: (C, H, W); only the values at ``decoded`` pixels are used.
        decoded: (H, W) bool.
        stride: Kernel half-width + 1 (the grid spacing).

    Returns:
        ``filled`` (C, H, W) (0 where no decoded pixel lies within ``stride - 1`` rows and columns) and the kernel
        weight sum ``weight`` (H, W) (0 exactly there, >= 1 / stride^2 elsewhere).
    """
    c = values.shape[0]
    t = torch.arange(1 - stride, stride, device=values.device, dtype=values.dtype)
    k = 1 - t.abs() / stride
    wgt = decoded.to(values.dtype)
    stack = torch.cat([values * wgt, wgt[None]])[None]  # (1, C + 1, H, W)
    ky = k.view(1, 1, -1, 1).expand(c + 1, 1, -1, 1)
    kx = k.view(1, 1, 1, -1).expand(c + 1, 1, 1, -1)
    with torch.autocast(values.device.type, enabled=False):  # in the outputs' precision, not bf16
        acc = F.conv2d(stack, ky, padding=(stride - 1, 0), groups=c + 1)
        acc = F.conv2d(acc, kx, padding=(0, stride - 1), groups=c + 1)
    num, den = acc[0, :c], acc[0, c]
    # Sums of exact zeros stay zero, and any decoded pixel in reach adds at least 1 / stride^2.
    den = torch.where(den > 0.5 / stride**2, den, torch.zeros_like(den))
    return num / den.clamp_min(0.5 / stride**2), den


# ----------------------------------------------------------------------------------------------------------------
# Building blocks
# ----------------------------------------------------------------------------------------------------------------


def trunc_normal_(tensor: Tensor, std: float = 0.02, bound: float = 2.0) -> Tensor:
    """Fill in place with a normal of mean 0 and ``std``, truncated to +-``bound`` std (by resampling).

    Same distribution as ``nn.init.trunc_normal_(tensor, std=std, a=-bound*std, b=bound*std)``, about 20x faster
    on CPU (that one goes through erfinv; it took 21 s for the ``paper`` model). Uses the global generator.
    """
    with torch.no_grad():
        if tensor.is_meta:
            return tensor
        tensor.normal_(0.0, std)
        for _ in range(100):
            out = tensor.abs() > bound * std
            count = int(out.sum())
            if count == 0:
                break
            tensor[out] = torch.randn(count, dtype=tensor.dtype, device=tensor.device) * std
    return tensor


def init_linear_(module: nn.Module, std: float = 0.02) -> None:
    """Truncated normal (``std``, cut at +-2 std) for the linear weights in ``module``, zero biases, unit LayerNorms.

    Apply with ``module.apply(functools.partial(init_linear_, std=std))`` or call on a tree (it recurses).
    """
    for sub in module.modules():
        if isinstance(sub, nn.Linear):
            trunc_normal_(sub.weight, std)
            if sub.bias is not None:
                nn.init.zeros_(sub.bias)
        elif isinstance(sub, nn.LayerNorm) and sub.elementwise_affine:
            nn.init.ones_(sub.weight)
            nn.init.zeros_(sub.bias)


class LayerScale(nn.Module):
    """Per-channel scale of a residual branch, ``x * gamma`` (gamma initialised to ``init``)."""

    def __init__(self, dim: int, init: float) -> None:
        super().__init__()
        self.init = init
        self.gamma = nn.Parameter(torch.full((dim,), float(init)))

    def forward(self, x: Tensor) -> Tensor:
        """Scale (*, C) by gamma."""
        return x * self.gamma


class Mlp(nn.Module):
    """Two linear layers with GELU (DINOv2 names ``fc1``, ``fc2``)."""

    def __init__(self, dim: int, hidden: int, out: int | None = None) -> None:
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, out or dim)

    def forward(self, x: Tensor) -> Tensor:
        """(*, dim) -> (*, out)."""
        return self.fc2(self.act(self.fc1(x)))


class Attention(nn.Module):
    """Multi-head attention with a fused ``qkv`` projection (DINOv2 names), self- or cross-attention.

    For cross-attention the query rows and key/value rows of ``qkv`` are applied separately.
    """

    def __init__(self, dim: int, heads: int, qk_norm: bool = False) -> None:
        super().__init__()
        self.heads = heads
        self.head_dim = dim // heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)
        self.q_norm = nn.LayerNorm(self.head_dim) if qk_norm else nn.Identity()
        self.k_norm = nn.LayerNorm(self.head_dim) if qk_norm else nn.Identity()

    def _split(self, x: Tensor, parts: int) -> list[Tensor]:
        n, s, _ = x.shape
        x = x.reshape(n, s, parts, self.heads, self.head_dim).permute(2, 0, 3, 1, 4)
        return list(x.unbind(0))

    def project_query(self, x: Tensor) -> Tensor:
        """Queries (L, S, C) -> (L, H, S, d)."""
        c = x.shape[-1]
        bias = None if self.qkv.bias is None else self.qkv.bias[:c]
        (q,) = self._split(F.linear(x, self.qkv.weight[:c], bias), 1)
        return self.q_norm(q)

    def project_key_value(self, context: Tensor) -> tuple[Tensor, Tensor]:
        """Context (L, S, C) -> keys and values, each (L, H, S, d)."""
        c = context.shape[-1]
        bias = None if self.qkv.bias is None else self.qkv.bias[c:]
        k, v = self._split(F.linear(context, self.qkv.weight[c:], bias), 2)
        return self.k_norm(k), v

    def attend(self, q: Tensor, k: Tensor, v: Tensor, key_padding_mask: Tensor | None = None) -> Tensor:
        """Attention and output projection: (L, H, Sq, d) -> (L, Sq, C)."""
        out = multi_head_attention(q, k, v, key_padding_mask)
        n, h, s, d = out.shape
        return self.proj(out.transpose(1, 2).reshape(n, s, h * d))

    def forward(self, x: Tensor, context: Tensor | None = None, key_padding_mask: Tensor | None = None) -> Tensor:
        """Attention of ``x`` over ``context`` (default: itself).

        Args:
            x: Queries, (L, Sq, C).
            context: Keys/values, (L, Sk, C); ``None`` for self-attention.
            key_padding_mask: Optional bool (L, Sk), True where a key may be attended.

        Returns:
            (L, Sq, C).
        """
        if context is None:
            q, k, v = self._split(self.qkv(x), 3)
            q, k = self.q_norm(q), self.k_norm(k)
        else:
            q = self.project_query(x)
            k, v = self.project_key_value(context)
        return self.attend(q, k, v, key_padding_mask)


class Block(nn.Module):
    """Pre-norm transformer block: x + ls1(attn(norm1 x)), then x + ls2(mlp(norm2 x)).

    Parameter names follow DINOv2 (``norm1``, ``attn.qkv``, ``attn.proj``, ``ls1.gamma``, ``norm2``,
    ``mlp.fc1``, ``mlp.fc2``, ``ls2.gamma``). With ``context`` it is a cross-attention block (the context is
    normalised with ``norm1`` too), which is self-attention when ``context`` equals ``x``.
    """

    def __init__(
        self, dim: int, heads: int, mlp_ratio: float = 4.0, qk_norm: bool = False, layerscale: float | None = None
    ) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = Attention(dim, heads, qk_norm)
        self.ls1 = LayerScale(dim, layerscale) if layerscale is not None else nn.Identity()
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim, layerscale) if layerscale is not None else nn.Identity()

    def forward(self, x: Tensor, context: Tensor | None = None, key_padding_mask: Tensor | None = None) -> Tensor:
        """(L, S, C) -> (L, S, C); ``context`` (L, Sk, C), ``key_padding_mask`` (L, Sk) bool."""
        h = self.norm1(x)
        ctx = None if context is None else self.norm1(context)
        x = x + self.ls1(self.attn(h, ctx, key_padding_mask))
        return x + self.ls2(self.mlp(self.norm2(x)))

    def context_key_value(self, context: Tensor) -> tuple[Tensor, Tensor]:
        """Keys and values of a context (L, Sk, C), for :meth:`forward_cached`."""
        return self.attn.project_key_value(self.norm1(context))

    def forward_cached(self, x: Tensor, kv: tuple[Tensor, Tensor]) -> Tensor:
        """Cross-attention block over precomputed context keys/values: (L, Sq, C) -> (L, Sq, C)."""
        q = self.attn.project_query(self.norm1(x))
        x = x + self.ls1(self.attn.attend(q, *kv))
        return x + self.ls2(self.mlp(self.norm2(x)))


# ----------------------------------------------------------------------------------------------------------------
# Tokenizer
# ----------------------------------------------------------------------------------------------------------------


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

    def forward(self, x: Tensor) -> tuple[Tensor, tuple[int, int]]:
        """Tokens of a batch of single maps.

        Args:
            x: (B, in_chans, H, W), H and W multiples of the patch size.

        Returns:
            Tokens (B, 1 + R + h*w, C) after the final LayerNorm, and the grid (h, w).
        """
        tokens, grid = self.patch_embed(x)
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


# ----------------------------------------------------------------------------------------------------------------
# Interleaved attention
# ----------------------------------------------------------------------------------------------------------------


class AxisAttentionBlock(nn.Module):
    """A pre-norm transformer :class:`Block` applied along one attention axis of (B, 9, N, C) tokens.

    The block is equivariant to any permutation of the sequences' members: ``spatial`` to permutations of the
    tokens of a map (and of the maps), ``spectral``/``polarimetric`` to permutations within (and of) their groups,
    ``cross``/``global`` to any permutation of the nine maps. Maps in different groups do not interact.
    """

    def __init__(self, axis: str, dim: int, heads: int, mlp_ratio: float, qk_norm: bool, layerscale: float) -> None:
        super().__init__()
        if axis not in AXES:
            raise ValueError(f"Unknown attention axis {axis!r}; valid axes are {AXES}")
        self.axis = axis
        self.block = Block(dim, heads, mlp_ratio, qk_norm, layerscale)

    def forward(self, x: Tensor) -> Tensor:
        """(B, 9, N, C) -> (B, 9, N, C)."""
        return from_sequences(self.block(to_sequences(x, self.axis)), self.axis, x.shape)


class InterleavedAttention(nn.Module):
    """K iterations of (spatial, spectral, cross-observation, polarimetric) attention.

    ``iters.{k}.{spatial,spectral,cross,polarimetric}`` are :class:`AxisAttentionBlock` s; ``cross`` uses axis
    ``cross`` (per token position) or ``global`` (all tokens) after ``cross_observation``.
    """

    STEPS = ("spatial", "spectral", "cross", "polarimetric")

    def __init__(
        self,
        dim: int,
        heads: int,
        iters: int,
        mlp_ratio: float = 4.0,
        qk_norm: bool = True,
        layerscale: float = 0.01,
        cross_observation: str = "token",
        init_std: float = 0.02,
    ) -> None:
        super().__init__()
        axes = {"spatial": "spatial", "spectral": "spectral", "polarimetric": "polarimetric"}
        axes["cross"] = "cross" if cross_observation == "token" else "global"
        self.iters = nn.ModuleList(
            nn.ModuleDict(
                {s: AxisAttentionBlock(axes[s], dim, heads, mlp_ratio, qk_norm, layerscale) for s in self.STEPS}
            )
            for _ in range(iters)
        )
        init_linear_(self, init_std)

    def forward(self, x: Tensor) -> list[Tensor]:
        """Run all iterations.

        Args:
            x: Tokens, (B, 9, N, C).

        Returns:
            K tensors (B, 9, N, 4C): per iteration, its four step outputs concatenated (spatial, spectral, cross,
            polarimetric); the last C channels of the last one are the final tokens.
        """
        outputs = []
        for it in self.iters:
            steps = []
            for name in self.STEPS:
                x = it[name](x)
                steps.append(x)
            outputs.append(torch.cat(steps, dim=-1))
        return outputs


# ----------------------------------------------------------------------------------------------------------------
# DPT head
# ----------------------------------------------------------------------------------------------------------------


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


# ----------------------------------------------------------------------------------------------------------------
# Per-pixel decoder
# ----------------------------------------------------------------------------------------------------------------


class PoolingAttention(nn.Module):
    """Cross-attention from one learnable query over a set: (L, S, C) -> (L, C).

    out = attn(norm_q(query), norm_kv(x)), then out + mlp(norm2(out)). Unlike a Set-Transformer PMA there is no
    residual from the query: it is the same for every set, and at initialisation it drowned the per-set signal.
    ``query`` (1, 1, C) is initialised with a truncated normal (std 0.02); SDM-UniPS left its seed uninitialised.
    """

    def __init__(self, dim: int, heads: int, mlp_ratio: float = 4.0) -> None:
        super().__init__()
        self.query = nn.Parameter(torch.zeros(1, 1, dim))
        self.norm_q = nn.LayerNorm(dim, eps=1e-6)
        self.norm_kv = nn.LayerNorm(dim, eps=1e-6)
        self.attn = Attention(dim, heads)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        trunc_normal_(self.query)

    def forward(self, x: Tensor) -> Tensor:
        """Pool (L, S, C) into (L, C)."""
        q = self.query.expand(x.shape[0], -1, -1).to(x.dtype)
        out = self.attn(self.norm_q(q), self.norm_kv(x))  # no residual from the query: it is the same for all sets
        out = out + self.mlp(self.norm2(out))
        return out[:, 0]

    def folded_query(self) -> Tensor:
        """The constant query folded into the key projection, (C, H), for :meth:`forward_folded`.

        Column h is ``W_k,h^T q_h / sqrt(d)``: head h's attention logit of a normalised set member x is
        ``x . u_h`` plus ``q_h . b_k,h / sqrt(d)``, a constant that softmax cancels.
        """
        attn = self.attn
        c, heads, d = self.query.shape[-1], attn.heads, attn.head_dim
        q = attn.project_query(self.norm_q(self.query))[0, :, 0]  # (H, d)
        wk = attn.qkv.weight[c : 2 * c].reshape(heads, d, c)
        return torch.einsum("hd,hdc->ch", q, wk) * d**-0.5

    def forward_folded(self, x: Tensor, query: Tensor) -> Tensor:
        """:meth:`forward` (equal to float rounding) without the key/value projections of the set.

        The pooling query is the same for every set, so its logits need only the set's normalised members and
        ``query`` = :meth:`folded_query`, and since the attention weights sum to one, the value projection
        applies once to each head's weighted mean instead of to all S members: about 2 C^2 instead of
        4 S C^2 multiply-adds per set.

        Args:
            x: (L, S, C) sets.
            query: (C, H) from :meth:`folded_query`.

        Returns:
            (L, C).
        """
        attn = self.attn
        n, _, c = x.shape
        heads, d = attn.heads, attn.head_dim
        xn = self.norm_kv(x)
        weights = torch.softmax(torch.matmul(xn, query.to(xn.dtype)), dim=1)  # (L, S, H)
        mean = torch.matmul(weights.transpose(1, 2), xn)  # (L, H, C): each head's weighted mean member
        wv = attn.qkv.weight[2 * c :].reshape(heads, d, c).to(xn.dtype)
        out = torch.matmul(mean.transpose(0, 1), wv.transpose(1, 2)).transpose(0, 1).reshape(n, c)  # (L, H*d)
        if attn.qkv.bias is not None:
            out = out + attn.qkv.bias[2 * c :].to(out.dtype)
        out = attn.proj(out)
        return out + self.mlp(self.norm2(out))


class MapValueEmbedding(nn.Module):
    """psi_n: a pixel value of map n to D: fc2(GELU(I * weight[n] + bias[n])), the first layer map-specific.

    The nine maps are not exchangeable (unlike the images of universal photometric stereo, where SDM-UniPS and
    LINO-UniPS share one embedding), so the value embedding carries the map's identity: with a shared embedding and
    a tiny identity embedding, the attention pooling over the nine observations starts out as a symmetric function
    of them and the toy model needs several times more steps to learn e.g. albedo = unpolarized colour.
    ``weight`` and ``bias`` (9, hidden) start uniform in [-1, 1] (PyTorch's default for fan-in 1).
    """

    def __init__(self, hidden: int, dim: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(NUM_MAPS, hidden).uniform_(-1.0, 1.0))
        self.bias = nn.Parameter(torch.empty(NUM_MAPS, hidden).uniform_(-1.0, 1.0))
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, values: Tensor) -> Tensor:
        """(*, 9, 1) map values -> (*, 9, D)."""
        return self.fc2(self.act(values * self.weight.to(values.dtype) + self.bias.to(values.dtype)))


@dataclass
class DenseInputs:
    """One image's inputs to dense decoding, laid out for row gathers (:meth:`PixelDecoder.dense_inputs`).

    Attributes:
        table: (Hc*Wc, 9*D) DPT features, row ``y * Wc + x``, the nine maps' D features in map order.
        values: (H*W, 9) input map values, row ``row * W + col``.
        size: (H, W) of the input.
        feature_size: (Hc, Wc) of the features.
    """

    table: Tensor
    values: Tensor
    size: tuple[int, int]
    feature_size: tuple[int, int]


class PixelDecoder(nn.Module):
    """Per-pixel decoder: nine observations of a pixel to normal, albedo, roughness, metallic.

    z_n(x) = phi(F_n(x)) + psi_n(I_n(x)), with F_n the map's D features sampled bilinearly at x, I_n(x) the map
    value and psi_n a :class:`MapValueEmbedding` (map-specific first layer); ``obs_blocks`` attend across the nine
    observations (width D), ``agg_proj`` lifts to D_a, ``agg_blocks`` attend again, ``pool`` (learnable query)
    aggregates to one D_a vector; the pixel transformer (``pixel_blocks``) attends across pixels; ``normal_head``
    (3) and ``brdf_head`` (albedo 3, roughness 1, metallic 1). Linear layers keep PyTorch's default initialisation.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        d, da = config.dpt_dim, config.agg_dim
        self.phi = nn.Linear(d, d)
        self.psi = MapValueEmbedding(config.pixel_embed_hidden, d)
        self.obs_blocks = nn.ModuleList(
            Block(d, config.decoder_heads, config.mlp_ratio) for _ in range(config.obs_depth)
        )
        self.agg_proj = nn.Linear(d, da)
        self.agg_blocks = nn.ModuleList(
            Block(da, config.decoder_heads, config.mlp_ratio) for _ in range(config.agg_depth)
        )
        self.pool = PoolingAttention(da, config.decoder_heads, config.mlp_ratio)
        self.pixel_blocks = nn.ModuleList(
            Block(da, config.pixel_heads, config.mlp_ratio) for _ in range(config.pixel_depth)
        )
        self.norm = nn.LayerNorm(da, eps=1e-6)
        self.normal_head = Mlp(da, da // 2, 3)
        self.brdf_head = Mlp(da, da // 2, 5)

    def embed(self, features: Tensor, maps: Tensor, pixels: Tensor) -> Tensor:
        """Aggregated per-pixel features.

        Args:
            features: (B, 9, D, Hc, Wc) DPT features.
            maps: (B, 9, H, W) input maps.
            pixels: (B, P) flat pixel indices into H x W.

        Returns:
            (B, P, D_a).
        """
        b, m, d, hc, wc = features.shape
        h, w = maps.shape[-2:]
        p = pixels.shape[1]
        sampled = sample_bilinear(features.reshape(b, m * d, hc, wc), pixels, (h, w))  # (B, 9*D, P)
        f = sampled.reshape(b, m, d, p).permute(0, 3, 1, 2)  # (B, P, 9, D)
        values = torch.gather(maps.reshape(b, m, h * w), 2, pixels[:, None].expand(-1, m, -1))
        values = values.permute(0, 2, 1)[..., None].to(f.dtype)  # (B, P, 9, 1)
        z = self.phi(f) + self.psi(values)
        z = z.reshape(b * p, m, d)
        for blk in self.obs_blocks:
            z = blk(z)
        z = self.agg_proj(z)
        for blk in self.agg_blocks:
            z = blk(z)
        return self.pool(z).reshape(b, p, -1)

    def embed_rows(self, inputs: DenseInputs, pixels: Tensor, pool_query: Tensor) -> Tensor:
        """:meth:`embed` of one image's pixels from channels-last tables: the same values to float rounding.

        Dense (evaluation) decoding's embedding: features sampled with :func:`sample_bilinear_rows`, map values
        gathered as rows, and the pooling through :meth:`PoolingAttention.forward_folded`.

        Args:
            inputs: The image's :class:`DenseInputs` (:meth:`dense_inputs`).
            pixels: (P,) flat pixel indices into H x W.
            pool_query: (D_a, heads) from ``self.pool.folded_query()``.

        Returns:
            (P, D_a).
        """
        m = NUM_MAPS
        p = pixels.shape[0]
        f = sample_bilinear_rows(inputs.table, pixels, inputs.size, inputs.feature_size).reshape(p, m, -1)
        values = inputs.values.index_select(0, pixels)[..., None].to(f.dtype)  # (P, 9, 1)
        z = self.phi(f) + self.psi(values)
        for blk in self.obs_blocks:
            z = blk(z)
        z = self.agg_proj(z)
        for blk in self.agg_blocks:
            z = blk(z)
        return self.pool.forward_folded(z, pool_query)

    @staticmethod
    def dense_inputs(features: Tensor, maps: Tensor) -> DenseInputs:
        """Channels-last tables of one image for :meth:`embed_rows`.

        Args:
            features: (9, D, Hc, Wc) DPT features of one image.
            maps: (9, H, W) its input maps.
        """
        m, d, hc, wc = features.shape
        h, w = maps.shape[-2:]
        table = features.permute(2, 3, 0, 1).reshape(hc * wc, m * d)  # a copy made once per image
        return DenseInputs(table, maps.reshape(m, h * w).t().contiguous(), (h, w), (hc, wc))

    def heads(self, x: Tensor) -> dict[str, Tensor]:
        """Output heads on (B, P, D_a) tokens, computed in float32.

        Returns:
            ``normal`` (B, 3, P) unit vectors, ``albedo`` (B, 3, P), ``roughness`` (B, 1, P),
            ``metallic`` (B, 1, P), each in [0, 1] (sigmoid).
        """
        x = self.norm(x)
        normal = self.normal_head(x).float().transpose(1, 2)
        brdf = torch.sigmoid(self.brdf_head(x).float()).transpose(1, 2)
        return {
            "normal": safe_normalize(normal, dim=1),
            "albedo": brdf[:, 0:3],
            "roughness": brdf[:, 3:4],
            "metallic": brdf[:, 4:5],
        }

    def transform(self, x: Tensor, key_padding_mask: Tensor | None = None) -> Tensor:
        """Self-attention across pixels: (B, P, D_a) -> (B, P, D_a); ``key_padding_mask`` (B, P) bool."""
        for blk in self.pixel_blocks:
            x = blk(x, None, key_padding_mask)
        return x

    def context_cache(self, context: Tensor) -> list[tuple[Tensor, Tensor]]:
        """Per pixel-transformer layer, the keys and values of a context (1, K, D_a) run through :meth:`transform`.

        Layer l's keys/values come from the context's tokens at the input of layer l.
        """
        return self.context_pass(context)[0]

    def context_pass(self, context: Tensor) -> tuple[list[tuple[Tensor, Tensor]], Tensor]:
        """:meth:`context_cache` and the context's own tokens after the pixel transformer, (1, K, D_a).

        A context pixel decoded as a query attends to exactly these keys and values, so its output is the
        context's output (to float rounding): dense decoding takes it from here instead of decoding it again.
        """
        cache = []
        x = context
        for blk in self.pixel_blocks:
            k, v = blk.context_key_value(x)
            cache.append((k, v))
            q = blk.attn.project_query(blk.norm1(x))
            x = x + blk.ls1(blk.attn.attend(q, k, v))
            x = x + blk.ls2(blk.mlp(blk.norm2(x)))
        return cache, x

    def transform_cached(self, x: Tensor, cache: Sequence[tuple[Tensor, Tensor]]) -> Tensor:
        """Pixels (1, P, D_a) attending to a cached context at every layer -> (1, P, D_a)."""
        for blk, kv in zip(self.pixel_blocks, cache, strict=True):
            x = blk.forward_cached(x, kv)
        return x


def _store(out: dict[str, Tensor], i: int, pixels: Tensor, pred: dict[str, Tensor]) -> None:
    """Write decoded (1, C, P) outputs of image ``i`` at flat ``pixels`` into (B, C, H*W) maps."""
    for k in out:
        out[k][i, :, pixels] = pred[k][0]


# ----------------------------------------------------------------------------------------------------------------
# The model
# ----------------------------------------------------------------------------------------------------------------


class PolarInverseModel(nn.Module):
    """Nine polarimetric maps and a mask to normal, albedo, roughness and metallic.

    Attributes:
        tokenizer: The per-map :class:`ViTTokenizer`.
        map_embed: :class:`MapEmbedding` added to the tokenizer's output tokens.
        interleave: :class:`InterleavedAttention`.
        dpt: :class:`DPTHead`.
        decoder: :class:`PixelDecoder`.

    Example:
        >>> from network.config import get_config
        >>> model = PolarInverseModel(get_config("toy")).eval()
        >>> maps, mask = torch.rand(1, 9, 64, 64), torch.ones(1, 1, 64, 64)
        >>> model(maps, mask)["normal"].shape
        torch.Size([1, 3, 64, 64])
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        c = config.embed_dim
        self.tokenizer = ViTTokenizer(
            config.patch_size,
            c,
            config.depth,
            config.heads,
            config.registers,
            config.token_grid,
            config.mlp_ratio,
            config.vit_layerscale,
            init_std=config.init_std,
        )
        self.map_embed = MapEmbedding(c)
        self.interleave = InterleavedAttention(
            c,
            config.heads,
            config.interleave_iters,
            config.mlp_ratio,
            config.qk_norm,
            config.interleave_layerscale,
            config.cross_observation,
            init_std=config.init_std,
        )
        self.dpt = DPTHead(4 * c, config.dpt_channels, config.dpt_dim)
        self.decoder = PixelDecoder(config)
        k = config.interleave_iters
        #: Iterations feeding the four DPT levels (evenly spread; repeats when K < 4).
        self.dpt_levels = tuple(round(i * (k - 1) / 3) for i in range(4))

    def tokenizer_size(self, height: int, width: int) -> tuple[int, int]:
        """Tokenizer input size for an (height, width) input: scaled by canonical/image, rounded to patches."""
        cfg = self.config
        scale = cfg.canonical_size / cfg.image_size
        p = cfg.patch_size
        return (max(p, round(height * scale / p) * p), max(p, round(width * scale / p) * p))

    def encode(self, maps: Tensor, mask: Tensor) -> Tensor:
        """Per-map features at the canonical resolution.

        Args:
            maps: (B, 9, H, W).
            mask: (B, 1, H, W) in {0, 1}.

        Returns:
            DPT features (B, 9, D, Hc, Wc), (Hc, Wc) = :meth:`tokenizer_size`.
        """
        b, m, h, w = maps.shape
        hc, wc = self.tokenizer_size(h, w)
        x = maps * mask
        mk = mask
        if (hc, wc) != (h, w):
            x = F.interpolate(x, size=(hc, wc), mode="area")
            mk = F.interpolate(mask, size=(hc, wc), mode="area")
        inp = torch.stack([x, mk.expand(-1, m, -1, -1)], dim=2).reshape(b * m, IN_CHANS, hc, wc)
        tokens, grid = self.tokenizer(inp)
        tokens = tokens.reshape(b, m, tokens.shape[1], -1) + self.map_embed()[:, None].to(tokens.dtype)
        outputs = self.interleave(tokens)
        start = self.tokenizer.num_prefix
        levels = [outputs[i][:, :, start:].reshape(b * m, grid[0] * grid[1], -1) for i in self.dpt_levels]
        feats = self.dpt(levels, grid, (hc, wc))
        return feats.reshape(b, m, feats.shape[1], hc, wc)

    def decode_pixels(
        self, features: Tensor, maps: Tensor, pixels: Tensor, valid: Tensor | None = None
    ) -> dict[str, Tensor]:
        """Decode a set of pixels per image, the pixels of an image attending to each other.

        Args:
            features: (B, 9, D, Hc, Wc) from :meth:`encode`.
            maps: (B, 9, H, W).
            pixels: (B, P) flat indices into H x W.
            valid: Optional (B, P) bool; invalid pixels are not attended to (their outputs are meaningless).

        Returns:
            ``normal`` (B, 3, P), ``albedo`` (B, 3, P), ``roughness`` (B, 1, P), ``metallic`` (B, 1, P).
        """
        x = self.decoder.embed(features, maps, pixels)
        key_mask = None
        if valid is not None and not bool(valid.all()):
            key_mask = valid.clone()
            key_mask[~valid.any(dim=1), 0] = True  # an image without valid pixels attends to one dummy key
        return self.decoder.heads(self.decoder.transform(x, key_mask))

    def decode_dense(
        self, features: Tensor, maps: Tensor, mask: Tensor, chunk: int | None = None, *, stride: int = 1
    ) -> dict[str, Tensor]:
        """Decode the masked pixels, in chunks, each attending to a fixed context of masked pixels.

        The context (:func:`context_pixels`) runs through the decoder once; its pixels' outputs are taken from that
        pass (a context pixel decoded as a query attends to exactly the same keys), the other pixels are decoded in
        chunks against its cached keys and values. Results do not depend on ``chunk``, and at ``stride=1`` equal
        decoding every masked pixel as a query (to float rounding).

        Args:
            features: (B, 9, D, Hc, Wc) from :meth:`encode`.
            maps: (B, 9, H, W).
            mask: (B, 1, H, W).
            chunk: Query pixels per pixel-transformer call (default ``config.infer_chunk``); the per-pixel
                embedding runs in smaller pieces (:data:`EMBED_ELEMENTS`).
            stride: Speed/accuracy trade-off. 1 decodes every masked pixel. s > 1 decodes the masked pixels of
                :func:`grid_pixels` (every s-th row and column) and the context, and fills the other masked pixels
                from them by :func:`fill_from_decoded` (bilinear between decoded grid pixels, renormalised
                normals); masked pixels with no decoded pixel within s - 1 rows and columns (thin parts of the
                mask) are decoded too. Decoded pixels get exactly their stride-1 values; the decoder does about
                s^2 times less work.

        Returns:
            ``normal`` (B, 3, H, W), ``albedo`` (B, 3, H, W), ``roughness`` (B, 1, H, W), ``metallic`` (B, 1, H, W);
            zeros outside the mask.

        Raises:
            ValueError: If ``stride`` is not a positive int.
        """
        if not isinstance(stride, int) or isinstance(stride, bool) or stride < 1:
            raise ValueError(f"stride must be a positive int. Got {stride!r}")
        chunk = chunk or self.config.infer_chunk
        b, _, h, w = maps.shape
        dec = self.decoder
        out = {k: torch.zeros(b, c, h * w, device=maps.device, dtype=torch.float32) for k, c in OUTPUT_CHANNELS.items()}
        pool_query = dec.pool.folded_query()
        for i in range(b):
            idx = torch.nonzero(mask[i].reshape(-1) > 0).squeeze(1)
            if idx.numel() == 0:
                continue
            inputs = dec.dense_inputs(features[i], maps[i])
            ctx = context_pixels(idx, self.config.train_pixels)
            cache, x = dec.context_pass(self._embed_rows(inputs, ctx, pool_query)[None])
            _store(out, i, ctx, dec.heads(x))
            decoded = torch.zeros(h * w, dtype=torch.bool, device=maps.device)
            decoded[ctx] = True
            queries = idx if stride == 1 else grid_pixels(idx, w, stride)
            queries = queries[~decoded[queries]]
            self._decode_queries(out, i, inputs, queries, cache, pool_query, chunk)
            if stride == 1:
                continue
            decoded[queries] = True
            inside = mask[i, 0].reshape(-1) > 0
            filled, weight = fill_from_decoded(
                torch.cat([out[k][i] for k in OUTPUT_CHANNELS]).reshape(-1, h, w), decoded.reshape(h, w), stride
            )
            filled, weight = filled.reshape(filled.shape[0], -1), weight.reshape(-1)
            todo = inside & ~decoded
            covered = todo & (weight > 0)
            start = 0
            for k, c in OUTPUT_CHANNELS.items():
                part = filled[start : start + c]
                start += c
                if k == "normal":
                    part = safe_normalize(part, dim=0)
                out[k][i] = torch.where(covered, part, out[k][i])
            rest = torch.nonzero(todo & ~covered).squeeze(1)
            self._decode_queries(out, i, inputs, rest, cache, pool_query, chunk)
        return {k: v.reshape(b, -1, h, w) for k, v in out.items()}

    def decode_dense_reference(
        self, features: Tensor, maps: Tensor, mask: Tensor, chunk: int | None = None
    ) -> dict[str, Tensor]:
        """:meth:`decode_dense` at stride 1 the straightforward way, for tests and ``headless/bench.py``.

        Every masked pixel, context pixels included, is decoded as a query through the training-mode
        :meth:`PixelDecoder.embed` (gathers from the (B, 9, D, Hc, Wc) features, full pooling attention); this was
        the dense decoder before the row-table embedding, the folded pooling and the context reuse.
        Same arguments and outputs as :meth:`decode_dense`.
        """
        chunk = chunk or self.config.infer_chunk
        b, _, h, w = maps.shape
        out = {k: torch.zeros(b, c, h * w, device=maps.device, dtype=torch.float32) for k, c in OUTPUT_CHANNELS.items()}
        for i in range(b):
            idx = torch.nonzero(mask[i].reshape(-1) > 0).squeeze(1)
            if idx.numel() == 0:
                continue
            f, mp = features[i : i + 1], maps[i : i + 1]
            cache = self.decoder.context_cache(
                self.decoder.embed(f, mp, context_pixels(idx, self.config.train_pixels)[None])
            )
            for part in idx.split(chunk):
                _store(
                    out,
                    i,
                    part,
                    self.decoder.heads(self.decoder.transform_cached(self.decoder.embed(f, mp, part[None]), cache)),
                )
        return {k: v.reshape(b, -1, h, w) for k, v in out.items()}

    def _embed_rows(self, inputs: DenseInputs, pixels: Tensor, pool_query: Tensor) -> Tensor:
        """:meth:`PixelDecoder.embed_rows` in pieces of bounded memory (pixels are independent): (P, D_a)."""
        cfg = self.config
        hidden = [cfg.agg_dim] + [
            int(d * cfg.mlp_ratio) for d, n in ((cfg.dpt_dim, cfg.obs_depth), (cfg.agg_dim, cfg.agg_depth)) if n
        ]
        piece = max(1, EMBED_ELEMENTS // (NUM_MAPS * max(hidden)))  # the widest per-pixel intermediate: 9 MLP rows
        parts = [self.decoder.embed_rows(inputs, p, pool_query) for p in pixels.split(piece)]
        return parts[0] if len(parts) == 1 else torch.cat(parts)

    def _decode_queries(
        self,
        out: dict[str, Tensor],
        i: int,
        inputs: DenseInputs,
        pixels: Tensor,
        cache: Sequence[tuple[Tensor, Tensor]],
        pool_query: Tensor,
        chunk: int,
    ) -> None:
        """Decode ``pixels`` (P,) of image ``i`` against the cached context, in chunks, into ``out``."""
        if pixels.numel() == 0:
            return
        for part in pixels.split(chunk):
            x = self.decoder.transform_cached(self._embed_rows(inputs, part, pool_query)[None], cache)
            _store(out, i, part, self.decoder.heads(x))

    def forward(
        self,
        maps: Tensor,
        mask: Tensor,
        *,
        pixels: Tensor | None = None,
        generator: torch.Generator | None = None,
        chunk: int | None = None,
        stride: int = 1,
    ) -> dict[str, Tensor]:
        """Predict normal, albedo, roughness and metallic.

        Args:
            maps: (B, 9, H, W) in the nine-map order, normalised by the data pipeline.
            mask: (B, 1, H, W) in {0, 1}.
            pixels: Optional (B, P) flat pixel indices (``row * W + col``) to decode; they attend to each other.
            generator: Random generator for training-mode pixel sampling (on the input's device).
            chunk: Dense decoding chunk size (default ``config.infer_chunk``).
            stride: Dense decoding only: decode every ``stride``-th row and column and interpolate the rest
                (:meth:`decode_dense`); 1 (default) decodes every masked pixel.

        Returns:
            With ``pixels`` given, or in training mode (``train_pixels`` random masked pixels per image):
            ``normal`` (B, 3, P) unit camera-frame (OpenGL) vectors, ``albedo`` (B, 3, P), ``roughness`` (B, 1, P),
            ``metallic`` (B, 1, P) in [0, 1], ``pixels`` (B, P) long and ``valid`` (B, P) bool (False for padding
            when an image has fewer masked pixels). In evaluation mode without ``pixels``: full maps
            ``normal`` (B, 3, H, W), ``albedo`` (B, 3, H, W), ``roughness`` (B, 1, H, W), ``metallic`` (B, 1, H, W),
            zeros outside the mask. Outputs are float32 (also under autocast).

        Raises:
            ValueError: On wrong shapes.
        """
        if maps.ndim != 4 or maps.shape[1] != NUM_MAPS:
            raise ValueError(f"maps must have shape (B, 9, H, W). Got {tuple(maps.shape)}")
        b, _, h, w = maps.shape
        if tuple(mask.shape) != (b, 1, h, w):
            raise ValueError(f"mask must have shape {(b, 1, h, w)}. Got {tuple(mask.shape)}")
        p = self.config.patch_size
        if h < p or w < p:
            raise ValueError(f"Input must be at least {p} x {p} pixels. Got {h} x {w}")
        mask = mask.to(maps.dtype)
        features = self.encode(maps, mask)
        if pixels is not None:
            if pixels.ndim != 2 or pixels.shape[0] != b:
                raise ValueError(f"pixels must have shape ({b}, P). Got {tuple(pixels.shape)}")
            pixels = pixels.long()
            out = self.decode_pixels(features, maps, pixels)
            return {**out, "pixels": pixels, "valid": torch.ones_like(pixels, dtype=torch.bool)}
        if self.training:
            pixels, valid = sample_pixels(mask, self.config.train_pixels, generator)
            out = self.decode_pixels(features, maps, pixels, valid)
            return {**out, "pixels": pixels, "valid": valid}
        return self.decode_dense(features, maps, mask, chunk, stride=stride)


# ----------------------------------------------------------------------------------------------------------------
# Pretrained weights
# ----------------------------------------------------------------------------------------------------------------

#: Keys of DINOv2 checkpoints that the tokenizer does not use (ignored, reported).
IGNORED_PRETRAINED_KEYS = ("mask_token",)


@dataclass
class LoadReport:
    """What :func:`load_pretrained_vit` did.

    Attributes:
        loaded: Keys copied into the tokenizer.
        adapted: Keys copied after a documented conversion (position-grid resize, RGB -> (value, mask) channels).
        missing: Tokenizer keys absent from the file (left as initialised).
        unexpected: File keys the tokenizer does not have.
        mismatched: ``(key, expected shape, file shape)`` that could not be converted.
        ignored: Known unused DINOv2 keys (``mask_token``).
    """

    loaded: list[str] = field(default_factory=list)
    adapted: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)
    mismatched: list[tuple[str, tuple[int, ...], tuple[int, ...]]] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when every tokenizer key was loaded and nothing was left over."""
        return not (self.missing or self.unexpected or self.mismatched)

    def summary(self, limit: int = 10) -> str:
        """One line per problem category, each listing at most ``limit`` keys."""

        def show(items: list) -> str:
            more = f" ... (+{len(items) - limit} more)" if len(items) > limit else ""
            return ", ".join(str(i) for i in items[:limit]) + more

        lines = [f"loaded {len(self.loaded)} tensors ({len(self.adapted)} adapted)"]
        if self.missing:
            lines.append(f"missing {len(self.missing)}: {show(self.missing)}")
        if self.unexpected:
            lines.append(f"unexpected {len(self.unexpected)}: {show(self.unexpected)}")
        if self.mismatched:
            lines.append(f"shape mismatch {len(self.mismatched)} (key, expected, file): {show(self.mismatched)}")
        return "; ".join(lines)


def load_pretrained_vit(
    model: PolarInverseModel | ViTTokenizer, path: str | Path, *, strict: bool = True
) -> LoadReport:
    """Load tokenizer weights from a local file.

    Format: ``torch.save`` of a flat dict ``{name: tensor}`` with the :class:`ViTTokenizer` key names (DINOv2's
    own; e.g. ``model.tokenizer.state_dict()``, or a DINOv2-reg checkpoint such as ``dinov2_vits14_reg4``). It is
    read with ``torch.load(weights_only=True)``, so no code is unpickled. Conversions applied:

    - ``pos_embed`` with another square grid: resized bicubically to the tokenizer's grid.
    - ``patch_embed.proj.weight`` with 3 input channels (RGB, as DINOv2): summed into the value channel (a
      grey map replicated to RGB gives the same response), zeros for the mask channel.
    - ``mask_token`` is ignored.

    A different patch size or width cannot be converted and is reported as a shape mismatch.

    Args:
        model: A :class:`PolarInverseModel` (its ``tokenizer`` is loaded) or a :class:`ViTTokenizer`.
        path: The file.
        strict: Raise unless every tokenizer key loads and no file key is left over. With ``strict=False``,
            loadable tensors are copied and the rest reported.

    Returns:
        A :class:`LoadReport`.

    Raises:
        OSError: If the file cannot be read.
        ValueError: If the file is not a dict of tensors, or (strict) on missing, unexpected or mismatched keys;
            the message names the file and the keys. Nothing is copied in that case.
    """
    tokenizer = model.tokenizer if isinstance(model, PolarInverseModel) else model
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as exc:
        raise OSError(f"Cannot read pretrained ViT weights from {path}: {exc}") from exc
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        raise ValueError(f"{path}: expected a flat dict of tensors (a state dict), got {type(state).__name__}")
    own = tokenizer.state_dict()
    report = LoadReport()
    converted: dict[str, Tensor] = {}
    for key, value in state.items():
        if key in IGNORED_PRETRAINED_KEYS:
            report.ignored.append(key)
            continue
        if key not in own:
            report.unexpected.append(key)
            continue
        target = own[key]
        if value.shape == target.shape:
            converted[key] = value
            report.loaded.append(key)
            continue
        adapted = _adapt_pretrained(key, value, target, tokenizer)
        if adapted is None:
            report.mismatched.append((key, tuple(target.shape), tuple(value.shape)))
        else:
            converted[key] = adapted
            report.loaded.append(key)
            report.adapted.append(key)
    report.missing = [k for k in own if k not in state]
    if strict and not report.ok:
        raise ValueError(f"{path}: pretrained ViT weights do not match the tokenizer: {report.summary()}")
    with torch.no_grad():
        for key, value in converted.items():
            own[key].copy_(value.to(own[key].dtype))
    return report


def _adapt_pretrained(key: str, value: Tensor, target: Tensor, tokenizer: ViTTokenizer) -> Tensor | None:
    """Convert a pretrained tensor of another shape, or None when no documented conversion applies."""
    if key == "pos_embed" and value.ndim == 3 and value.shape[2] == target.shape[2]:
        side = math.isqrt(target.shape[1] - 1)
        try:
            return interpolate_pos_embed(value, (side, side))
        except ValueError:
            return None
    if (
        key == "patch_embed.proj.weight"
        and value.ndim == 4
        and value.shape[1] == 3
        and target.shape[1] == IN_CHANS
        and (value.shape[0], value.shape[2], value.shape[3]) == (target.shape[0], target.shape[2], target.shape[3])
    ):
        out = torch.zeros_like(target, dtype=value.dtype)
        out[:, 0] = value.sum(dim=1)
        return out
    return None


# ----------------------------------------------------------------------------------------------------------------
# Accounting
# ----------------------------------------------------------------------------------------------------------------


def count_parameters(module: nn.Module, trainable_only: bool = False) -> int:
    """Number of parameters (elements) of a module.

    Args:
        module: Any module.
        trainable_only: Count only parameters with ``requires_grad``.
    """
    return sum(p.numel() for p in module.parameters() if p.requires_grad or not trainable_only)


def _block_flops(queries: int, keys: int, dim: int, hidden: int, context_rows: int | None = None) -> int:
    """FLOPs of one transformer block: ``queries`` query rows attending to ``keys`` keys each.

    ``context_rows``: rows whose key/value projections are computed (default: the queries, i.e. self-attention).
    """
    rows = queries if context_rows is None else context_rows
    return (
        2 * queries * dim * dim  # q projection
        + 2 * rows * dim * 2 * dim  # k, v projections
        + 4 * queries * keys * dim  # QK^T and AV
        + 2 * queries * dim * dim  # output projection
        + 4 * queries * dim * hidden  # MLP
    )


def _pixel_embed_flops(cfg: ModelConfig, pixels: int, folded: bool = False) -> int:
    """FLOPs of :meth:`PixelDecoder.embed` for ``pixels`` pixels (phi, psi, observation blocks, pooling).

    ``folded``: of :meth:`PixelDecoder.embed_rows` instead (pooling by :meth:`PoolingAttention.forward_folded`;
    the per-call :meth:`PoolingAttention.folded_query` is not included).
    """
    m, d, da, hp = NUM_MAPS, cfg.dpt_dim, cfg.agg_dim, cfg.pixel_embed_hidden
    per = 2 * m * d * d + 2 * m * hp * d  # phi, psi (its first layer is elementwise)
    per += cfg.obs_depth * _block_flops(m, m, d, int(d * cfg.mlp_ratio))
    per += 2 * m * d * da  # agg_proj
    per += cfg.agg_depth * _block_flops(m, m, da, int(da * cfg.mlp_ratio))
    if folded:  # logits, weighted means, value and output projections, MLP
        per += 4 * m * da * cfg.decoder_heads + 4 * da * da + 4 * da * int(da * cfg.mlp_ratio)
    else:
        per += _block_flops(1, m, da, int(da * cfg.mlp_ratio), context_rows=m)  # pooling query
    return pixels * per


def _heads_flops(cfg: ModelConfig, pixels: int) -> int:
    da = cfg.agg_dim
    return pixels * (2 * (2 * da * (da // 2)) + 2 * (da // 2) * (3 + 5))


def estimate_flops(
    config: ModelConfig, image_size: int | tuple[int, int] | None = None, *, masked_pixels: int | None = None
) -> dict[str, int]:
    """Analytic FLOP count of one forward pass for one capture (batch 1).

    Counts 2 x multiply-accumulates of every matmul (linear layers), convolution (incl. transposed) and attention
    product (QK^T and AV), which is what ``torch.utils.flop_counter.FlopCounterMode`` counts; normalisations,
    activations, softmax, bias additions and interpolations are not counted (they are a few percent at most).

    Args:
        config: Model configuration.
        image_size: Input size, an int (square) or (H, W); default ``config.image_size``.
        masked_pixels: Pixels inside the mask for dense decoding; default all H x W.

    Returns:
        FLOPs per part: ``tokenizer``, ``interleave``, ``dpt``, ``encoder`` (the three), ``decoder_train``
        (``train_pixels`` pixels, or all masked pixels if fewer, attending to each other), ``decoder_dense``
        (:meth:`PolarInverseModel.decode_dense` at stride 1: every masked pixel, each attending to the
        ``train_pixels`` context), ``train`` (encoder + decoder_train) and ``dense`` (encoder + decoder_dense).
    """
    cfg = config
    if image_size is None:
        image_size = cfg.image_size
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    p = cfg.patch_size
    scale = cfg.canonical_size / cfg.image_size
    hc, wc = max(p, round(h * scale / p) * p), max(p, round(w * scale / p) * p)
    gh, gw = hc // p, wc // p
    n_patch = gh * gw
    m, c = NUM_MAPS, cfg.embed_dim
    hidden = int(c * cfg.mlp_ratio)
    tokens = 1 + cfg.registers + n_patch

    tokenizer = m * (2 * IN_CHANS * c * p * p * n_patch + cfg.depth * _block_flops(tokens, tokens, c, hidden))

    seq = {"spatial": tokens, "spectral": 3, "polarimetric": 3}
    seq["cross"] = m if cfg.cross_observation == "token" else m * tokens
    interleave = cfg.interleave_iters * sum(m * _block_flops(tokens, seq[s], c, hidden) for s in seq)

    c0, c1, c2, c3 = cfg.dpt_channels
    d = cfg.dpt_dim
    s0, s1, s2 = 16 * n_patch, 4 * n_patch, n_patch
    s3 = ((gh + 1) // 2) * ((gw + 1) // 2)
    dpt = 2 * 4 * c * (c0 + c1 + c2 + c3) * n_patch  # reassemble 1x1 projections
    dpt += 2 * c0 * c0 * 16 * n_patch + 2 * c1 * c1 * 4 * n_patch + 2 * c3 * c3 * 9 * s3  # resize
    dpt += 2 * 9 * d * (c0 * s0 + c1 * s1 + c2 * s2 + c3 * s3)  # scratch 3x3 convs
    rcu = 2 * (2 * 9 * d * d)  # one residual conv unit per pixel
    dpt += rcu * s3 + 2 * d * d * s2  # fusion 3 (coarsest): rcu2, resize to s2, 1x1
    dpt += 2 * rcu * s2 + 2 * d * d * s1  # fusion 2
    dpt += 2 * rcu * s1 + 2 * d * d * s0  # fusion 1
    dpt += 2 * rcu * s0 + 2 * d * d * 4 * s0  # fusion 0, to 8x the grid
    dpt += 2 * 9 * d * d * 4 * s0  # output conv
    dpt *= m

    da, dh = cfg.agg_dim, int(cfg.agg_dim * cfg.mlp_ratio)
    total_pixels = h * w if masked_pixels is None else masked_pixels
    n_train = min(cfg.train_pixels, total_pixels)
    decoder_train = (
        _pixel_embed_flops(cfg, n_train)
        + cfg.pixel_depth * _block_flops(n_train, n_train, da, dh)
        + _heads_flops(cfg, n_train)
    )
    k = n_train  # context size
    decoder_dense = (
        4 * da * da  # the pooling query folded into the key projection, once
        + _pixel_embed_flops(cfg, total_pixels, folded=True)  # each pixel once: the context's outputs are reused
        + cfg.pixel_depth * _block_flops(k, k, da, dh)  # the context through the pixel transformer
        + cfg.pixel_depth * _block_flops(total_pixels - k, k, da, dh, context_rows=0)  # queries over cached keys
        + _heads_flops(cfg, total_pixels)
    )
    encoder = tokenizer + interleave + dpt
    return {
        "tokenizer": tokenizer,
        "interleave": interleave,
        "dpt": dpt,
        "encoder": encoder,
        "decoder_train": decoder_train,
        "decoder_dense": decoder_dense,
        "train": encoder + decoder_train,
        "dense": encoder + decoder_dense,
    }
