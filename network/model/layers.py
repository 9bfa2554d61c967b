"""Transformer building blocks with DINOv2 parameter names: attention, MLP, LayerScale, pre-norm block.

Sequences are laid out ``(L, S, C)``: L independent sequences of S tokens of width C. Attention heads split C into
``H`` heads of ``d = C / H`` channels and run through ``F.scaled_dot_product_attention``. Parameter names
(``attn.qkv``, ``attn.proj``, ``ls1.gamma``, ``mlp.fc1`` ...) follow DINOv2, so pretrained ViT weights load by name
(:mod:`network.model.pretrained`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = [
    "Attention",
    "Block",
    "LayerScale",
    "Mlp",
    "init_linear_",
    "multi_head_attention",
    "skip_init",
    "trunc_normal_",
]

#: ``torch.nn.init`` fill functions that :func:`skip_init` turns into no-ops (torch's layers call them from
#: ``reset_parameters``).
_TORCH_INIT_FILLS = (
    "uniform_", "normal_", "trunc_normal_", "constant_", "ones_", "zeros_", "eye_", "dirac_", "xavier_uniform_",
    "xavier_normal_", "kaiming_uniform_", "kaiming_normal_", "orthogonal_", "sparse_",
)  # fmt: skip
_skipping = 0


@contextlib.contextmanager
def skip_init() -> Iterator[None]:
    """Construct modules without filling their parameters, for weights that are loaded right after.

    Inside the block :func:`trunc_normal_` and :func:`init_linear_` do nothing, and neither do the ``torch.nn.init``
    fill functions that torch's layers call from ``reset_parameters``: parameters keep what ``torch.empty`` left, so
    every one must be overwritten (``load_state_dict`` with ``strict=True`` checks that each is). Buffers that
    constructors compute (not fill at random) are unaffected. The ``torch.nn.init`` functions are swapped for the
    block, so do not construct modules in other threads meanwhile.

    Example:
        >>> with skip_init():
        ...     layer = nn.Linear(4, 4)
        >>> _ = layer.load_state_dict(nn.Linear(4, 4).state_dict())
    """
    global _skipping
    saved = {name: getattr(nn.init, name) for name in _TORCH_INIT_FILLS if hasattr(nn.init, name)}
    _skipping += 1
    try:
        for name in saved:
            setattr(nn.init, name, _keep)
        yield
    finally:
        _skipping -= 1
        for name, fn in saved.items():
            setattr(nn.init, name, fn)


def _keep(tensor: Tensor, *args, **kwargs) -> Tensor:
    return tensor


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


def trunc_normal_(tensor: Tensor, std: float = 0.02, bound: float = 2.0) -> Tensor:
    """Fill in place with a normal of mean 0 and ``std``, truncated to +-``bound`` std (by resampling).

    Same distribution as ``nn.init.trunc_normal_(tensor, std=std, a=-bound*std, b=bound*std)``, but without its
    inverse-CDF (erfinv) route, which is slow on CPU for large models. Uses the global generator; meta tensors are
    returned unchanged.

    Args:
        tensor: The tensor to fill, any shape.
        std: Standard deviation.
        bound: Truncation, in standard deviations.

    Returns:
        ``tensor``.

    Example:
        >>> w = trunc_normal_(torch.empty(1000), std=0.02)
        >>> bool(w.abs().max() <= 0.04)
        True
    """
    with torch.no_grad():
        if tensor.is_meta or _skipping:
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

    It recurses into every sub-module, so one call on a tree initialises all of it.

    Args:
        module: The module tree to initialise in place.
        std: Standard deviation of the linear weights.
    """
    if _skipping:
        return
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
