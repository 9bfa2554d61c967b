"""Model accounting: parameter counts and an analytic FLOP estimate of one forward pass.

FLOP = 2 x multiply-accumulates of every matmul (linear layer), convolution and attention product (QK^T and AV),
which is what ``torch.utils.flop_counter.FlopCounterMode`` counts (tests pin the two as equal).

Example:
    >>> from network.config import get_config
    >>> flops = estimate_flops(get_config("toy"))
    >>> flops["train"] == flops["encoder"] + flops["decoder_train"]
    True
"""

from __future__ import annotations

from torch import nn

from network.config import ModelConfig

from .maps import NUM_MAPS
from .tokenizer import IN_CHANS

__all__ = ["count_parameters", "estimate_flops"]


def count_parameters(module: nn.Module, trainable_only: bool = False) -> int:
    """Number of parameters (elements) of a module.

    Args:
        module: Any module.
        trainable_only: Count only parameters with ``requires_grad``.

    Returns:
        The number of parameter elements.

    Example:
        >>> count_parameters(nn.Linear(3, 2))  # 3 x 2 weights + 2 biases
        8
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
