"""Per-pixel decoder: nine observations of a pixel to normal, albedo, roughness and metallic.

For a pixel x, ``z_n(x) = phi(F_n(x)) + psi_n(I_n(x))``, n = 1..9, with F_n the map's D features sampled
bilinearly (:mod:`network.model.sampling`) and psi_n a value embedding whose first layer is map-specific
(:class:`MapValueEmbedding`); self-attention across the nine observations, then cross-attention from one learnable
query (:class:`PoolingAttention`) pools them into one D_a vector; a transformer across pixels; heads for unit
normals and for albedo, roughness, metallic in [0, 1].

Shapes: features ``(B, 9, D, Hc, Wc)``, maps ``(B, 9, H, W)``, pixels ``(B, P)`` flat indices into H x W, tokens
``(B, P, D_a)``. The pooling over the nine observations is invariant to any permutation of them; only the
map-specific first layer of psi tells them apart. Linear layers keep PyTorch's default initialisation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from network.config import ModelConfig

from .layers import Attention, Block, Mlp, trunc_normal_
from .maps import NUM_MAPS
from .sampling import sample_bilinear, sample_bilinear_rows

__all__ = [
    "DenseInputs",
    "MapValueEmbedding",
    "PixelDecoder",
    "PoolingAttention",
    "safe_normalize",
]


def safe_normalize(v: Tensor, dim: int = 1, eps: float = 1e-6) -> Tensor:
    """Unit vectors along ``dim``; vectors with norm <= ``eps`` become (0, 0, 1) (facing the camera).

    The division uses the norm clamped to ``eps``, so the backward pass stays finite at zero vectors.

    Args:
        v: (*, 3, *) vectors, the component axis at ``dim``.
        dim: Component axis.
        eps: Norm below which the fallback is returned.

    Returns:
        Same shape as ``v``, unit length along ``dim``.

    Example:
        >>> safe_normalize(torch.tensor([[3.0, 0.0, 4.0], [0.0, 0.0, 0.0]]), dim=1)
        tensor([[0.6000, 0.0000, 0.8000],
                [0.0000, 0.0000, 1.0000]])
    """
    norm = torch.linalg.vector_norm(v, dim=dim, keepdim=True)
    unit = v / norm.clamp_min(eps)
    shape = [1] * v.ndim
    shape[dim] = v.shape[dim]
    fallback = torch.zeros(shape, dtype=v.dtype, device=v.device)
    fallback.view(-1)[-1] = 1.0
    return torch.where(norm > eps, unit, fallback)


class PoolingAttention(nn.Module):
    """Cross-attention from one learnable query over a set: (L, S, C) -> (L, C).

    out = attn(norm_q(query), norm_kv(x)), then out + mlp(norm2(out)). Unlike a Set-Transformer PMA there is no
    residual from the query: the query is the same for every set, so a residual would only add a constant that
    can drown the per-set signal at initialisation. ``query`` (1, 1, C) is initialised with a truncated normal
    (std 0.02).
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
    LINO-UniPS share one embedding), so the value embedding carries the map's identity: with a shared embedding the
    attention pooling over the nine observations starts out as a symmetric function of them, which learns more
    slowly (docs/measurements/network.md). ``weight`` and ``bias`` (9, hidden) start uniform in [-1, 1] (PyTorch's
    default for fan-in 1).
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
        light: (H*W, 27) each map's light vector (x, y, z per map), or None (a light-blind model).
    """

    table: Tensor
    values: Tensor
    size: tuple[int, int]
    feature_size: tuple[int, int]
    light: Tensor | None = None


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
        if config.light_input:  # the light vector of each observation's colour region, zero at the start
            self.chi = nn.Linear(3, d, bias=False)
            nn.init.zeros_(self.chi.weight)
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

    def observe(self, features: Tensor, values: Tensor, light: Tensor | None = None) -> Tensor:
        """The nine observations of each pixel, attended across before pooling: (N, 9, D), (N, 9, 1) -> (N, 9, D_a).

        ``z_n = phi(F_n) + psi_n(I_n)`` (``+ chi(L_n)`` with light), then ``obs_blocks``, ``agg_proj`` and
        ``agg_blocks``; shared by :meth:`embed` and :meth:`embed_rows`, which differ only in how they gather the
        inputs and pool.

        Args:
            features: (N, 9, D) sampled DPT features of N pixels.
            values: (N, 9, 1) their input map values.
            light: (N, 9, 3) each observation's light vector (a ``light_input`` model), or None.

        Returns:
            (N, 9, D_a) tokens for the pooling.
        """
        z = self.phi(features) + self.psi(values)
        if light is not None:
            z = z + self.chi(light.to(z.dtype))
        for blk in self.obs_blocks:
            z = blk(z)
        z = self.agg_proj(z)
        for blk in self.agg_blocks:
            z = blk(z)
        return z

    def embed(self, features: Tensor, maps: Tensor, pixels: Tensor, light: Tensor | None = None) -> Tensor:
        """Aggregated per-pixel features.

        Args:
            features: (B, 9, D, Hc, Wc) DPT features.
            maps: (B, 9, H, W) input maps.
            pixels: (B, P) flat pixel indices into H x W.
            light: (B, 9, 3, H, W) each map's light vector, or None.

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
        lv = None
        if light is not None:
            lv = torch.gather(light.reshape(b, m * 3, h * w), 2, pixels[:, None].expand(-1, m * 3, -1))
            lv = lv.permute(0, 2, 1).reshape(b * p, m, 3)
        return self.pool(self.observe(f.reshape(b * p, m, d), values.reshape(b * p, m, 1), lv)).reshape(b, p, -1)

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
        lv = None if inputs.light is None else inputs.light.index_select(0, pixels).reshape(p, m, 3)
        return self.pool.forward_folded(self.observe(f, values, lv), pool_query)

    @staticmethod
    def dense_inputs(features: Tensor, maps: Tensor, light: Tensor | None = None) -> DenseInputs:
        """Channels-last tables of one image for :meth:`embed_rows`.

        Args:
            features: (9, D, Hc, Wc) DPT features of one image.
            maps: (9, H, W) its input maps.
            light: (9, 3, H, W) each map's light vector, or None.
        """
        m, d, hc, wc = features.shape
        h, w = maps.shape[-2:]
        table = features.permute(2, 3, 0, 1).reshape(hc * wc, m * d)  # a copy made once per image
        lt = None if light is None else light.reshape(m * 3, h * w).t().contiguous()
        return DenseInputs(table, maps.reshape(m, h * w).t().contiguous(), (h, w), (hc, wc), lt)

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
            cache.append(blk.context_key_value(x))
            x = blk.forward_cached(x, cache[-1])
        return cache, x

    def transform_cached(self, x: Tensor, cache: Sequence[tuple[Tensor, Tensor]]) -> Tensor:
        """Pixels (1, P, D_a) attending to a cached context at every layer -> (1, P, D_a)."""
        for blk, kv in zip(self.pixel_blocks, cache, strict=True):
            x = blk.forward_cached(x, kv)
        return x
