"""Dense (evaluation) decoding: every masked pixel against a fixed context, in chunks; optional stride.

In training each sampled pixel attends to all sampled pixels. Dense decoding keeps that cost bounded: a
deterministic, evenly spread subset of at most ``train_pixels`` masked pixels (:func:`context_pixels`) forms a
*context*; the context runs through the pixel transformer once, and every other masked pixel (in chunks of
``infer_chunk``) attends to the context's cached keys and values at each layer. Cost is O(P x train_pixels),
never O(P^2), and results do not depend on the chunk size. A context pixel decoded as a query attends to exactly
the context's keys, so its output is the context pass's own output, which is reused. With at most
``train_pixels`` masked pixels dense decoding equals self-attention over all of them, as in training.

:func:`decode_dense` is the fast route and :func:`decode_dense_reference` the straightforward one (equal to float
rounding): the fast route gathers features and map values as rows of channels-last tables
(:func:`~network.model.sampling.sample_bilinear_rows`), folds the pooling's constant query into its key projection
(:meth:`~network.model.decoder.PoolingAttention.forward_folded`), embeds pixels in cache-sized pieces
(:data:`EMBED_ELEMENTS`) and, on a CPU, decodes its chunks on several Python threads of one torch thread each
(:func:`query_workers`).

``stride`` > 1 trades accuracy for time: it decodes every s-th row and column (:func:`grid_pixels`) and fills the
rest by normalised convolution (:func:`fill_from_decoded`), about s^2 times less decoder work. Interpolation is
edge-aware (``refine_deg``): a filled pixel whose decoded neighbours disagree (:func:`unreliable_fill`: normals more
than ``refine_deg`` apart, BRDF values more than :data:`REFINE_BRDF`) where the grid's second differences do not show
a smooth field, or with a neighbour missing at the mask's edge, is decoded exactly instead.

Example:
    >>> grid_pixels(torch.arange(16), width=4, stride=2)  # rows and columns 1 and 3 of a 4 x 4 image
    tensor([ 5,  7, 13, 15])
    >>> context_pixels(torch.arange(10, 20), 4)
    tensor([10, 12, 15, 17])
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import torch
import torch.nn.functional as F
from torch import Tensor

from network.config import ModelConfig
from pbrdf.data.predictions import OUTPUT_CHANNELS

from .decoder import DenseInputs, PixelDecoder, safe_normalize
from .maps import NUM_MAPS

__all__ = [
    "EMBED_ELEMENTS",
    "REFINE_BRDF",
    "REFINE_DEG",
    "SMOOTH_SHARE",
    "STRIDE_PIXELS",
    "auto_stride",
    "box_max",
    "context_pixels",
    "decode_dense",
    "decode_dense_reference",
    "fill_from_decoded",
    "grid_pixels",
    "query_workers",
    "unreliable_fill",
]

#: Default ``refine_deg`` of :func:`decode_dense`: a strided fill whose decoded neighbours' normals lie more than
#: this many degrees apart is decoded exactly (docs/measurements/network.md, "Edge-aware strided decoding").
REFINE_DEG = 4.0
#: The ``refine_brdf`` of :func:`decode_dense`'s :func:`unreliable_fill`: likewise for albedo, roughness or metallic
#: neighbours that differ by more than this (absolute, per channel).
REFINE_BRDF = 0.05

#: A fill flagged by the range test is kept where the interpolation error estimated from the grid's second
#: differences is below this share of ``refine_deg`` (as a chord) and ``refine_brdf``: 0.25 deg and 0.003 for the
#: defaults (docs/measurements/network.md, "Curvature-aware refinement").
SMOOTH_SHARE = 1 / 16

#: Dense decoding embeds pixels in pieces whose widest intermediate (an observation MLP's hidden layer, 9 rows per
#: pixel) has about this many elements (16 MiB in float32), so that a piece stays cache-sized
#: (docs/measurements/network.md has the timings behind the choice).
EMBED_ELEMENTS = 1 << 22

# False: every chunk on the calling thread (torch's intra-op threads), the route before query_workers; the full-frame
# bench and the tests compare the two.
_PARALLEL_QUERIES = True


#: :func:`auto_stride` decodes masks of at least this many pixels at stride 4 (a capture-sized object: on a full
#: 1224 x 1024 frame stride 4 keeps the normals within p99 1 deg and the BRDF maps within 0.01 RMSE of stride 1,
#: docs/measurements/fullframe.md); smaller ones at stride 1.
STRIDE_PIXELS = 150_000


def auto_stride(mask_pixels: int) -> int:
    """The default decoding stride for a mask of ``mask_pixels`` pixels: 4 from :data:`STRIDE_PIXELS` on, else 1.

    Example:
        >>> auto_stride(9_000), auto_stride(650_000)
        (1, 4)
    """
    return 4 if mask_pixels >= STRIDE_PIXELS else 1


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


def box_max(x: Tensor, k: int) -> Tensor:
    """``F.max_pool2d(x, k, 1, k // 2)`` (odd ``k``) from shifted maxima: the same values, several times less CPU.

    Separable, and each 1-D window max by doubling (``max`` over ``[i, i + 2^j)``, then two overlapping spans of
    the window), so about ``2 log2(k)`` elementwise maxima instead of torch's CPU pooling kernel.

    Args:
        x: (..., H, W).
        k: Odd window size.

    Returns:
        (..., H, W): each pixel the maximum over the ``k x k`` window centred on it, inside the image.

    Example:
        >>> box_max(torch.tensor([[0.0, 0, 5, 0], [1, 0, 0, 0]]), 3)
        tensor([[1., 5., 5., 5.],
                [1., 5., 5., 5.]])
    """
    return _window_max(_window_max(x, k, x.ndim - 2), k, x.ndim - 1)


def _window_max(x: Tensor, k: int, dim: int) -> Tensor:
    """The maximum over the ``k`` (odd) entries centred on each entry along ``dim``, inside the array."""
    n, pad = x.shape[dim], k // 2
    shape = list(x.shape)
    shape[dim] = pad
    fill = torch.full(shape, -math.inf, dtype=x.dtype, device=x.device)
    m, span = torch.cat([fill, x, fill], dim), 1
    while span * 2 <= k:  # m[i] = max over [i, i + span)
        m = torch.maximum(m.narrow(dim, 0, m.shape[dim] - span), m.narrow(dim, span, m.shape[dim] - span))
        span *= 2
    return torch.maximum(m.narrow(dim, 0, n), m.narrow(dim, k - span, n))  # span <= k < 2 span: covers the window


def unreliable_fill(
    values: Tensor, decoded: Tensor, weight: Tensor, stride: int, refine_deg: float, refine_brdf: float
) -> Tensor:
    """Pixels whose :func:`fill_from_decoded` value is unreliable: their decoded neighbours disagree or are missing.

    The neighbours of a pixel are the decoded pixels with nonzero tent weight (within ``stride - 1`` rows and
    columns). A pixel is a candidate where the per-component range of their normals (max - min of x, y, z) has a
    length above ``2 sin(refine_deg / 2)`` (so any two neighbours more than ``refine_deg`` apart flag it; pairs
    up to sqrt(3) times closer may too), or where any BRDF channel ranges over more than ``refine_brdf``. A
    candidate is cleared where the values are smooth instead: linear interpolation between grid pixels ``s``
    apart errs by at most ``|f''| s^2 / 8``, so the second differences of the decoded grid (:func:`grid_pixels`)
    along rows and columns, ``(|d_xx| + |d_yy|) / 8`` at each of the grid pixels around it, estimate its error,
    which must stay below :data:`SMOOTH_SHARE` of the thresholds (0.25 deg for the default 4). A uniformly curved
    surface passes; a crease or a jump between grid pixels makes the second difference as large as the jump and
    stays flagged. Where a second difference is missing (mask or image edge) the candidate stays flagged, and so does
    every pixel whose weight sum is below 1 (a neighbour of the full bilinear stencil is missing).

    Args:
        values: (C, H, W) outputs in :data:`~pbrdf.data.predictions.OUTPUT_CHANNELS` order (normal first).
        decoded: (H, W) bool.
        weight: (H, W) the weight sum from :func:`fill_from_decoded`.
        stride: The grid spacing.
        refine_deg: Normal threshold in degrees.
        refine_brdf: Albedo/roughness/metallic threshold.

    Returns:
        (H, W) bool.
    """
    k = 2 * stride - 1
    big = torch.finfo(values.dtype).max
    chord = 2 * math.sin(math.radians(refine_deg) / 2)
    with torch.autocast(values.device.type, enabled=False):
        hi = torch.where(decoded, values, -big)[None]
        lo = torch.where(decoded, -values, -big)[None]
        span = (box_max(hi, k) + box_max(lo, k))[0]
        span = torch.where(weight > 0, span, torch.zeros_like(span))
        candidate = (span[:3].square().sum(0) > chord**2) | (span[3:] > refine_brdf).any(0)
        # Interpolation error estimated at each grid pixel from its second differences; a grid pixel without
        # both neighbours in a direction counts as rough.
        o = stride // 2
        g, ok = values[:, o::stride, o::stride], decoded[o::stride, o::stride]
        d2 = torch.zeros_like(g)
        have = torch.zeros_like(ok)
        have[1:-1, 1:-1] = ok[1:-1, 1:-1] & ok[:-2, 1:-1] & ok[2:, 1:-1] & ok[1:-1, :-2] & ok[1:-1, 2:]
        inner = g[:, 1:-1, 1:-1]
        d2[:, 1:-1, 1:-1] = (g[:, 1:-1, :-2] - 2 * inner + g[:, 1:-1, 2:]).abs() + (
            g[:, :-2, 1:-1] - 2 * inner + g[:, 2:, 1:-1]
        ).abs()
        err = d2 / 8
        tol = SMOOTH_SHARE * chord
        rough = (err[:3].square().sum(0) > tol**2) | (err[3:] > SMOOTH_SHARE * refine_brdf).any(0) | ~have
        # Spread each grid pixel's verdict to the pixels within its tent reach.
        node = torch.zeros_like(decoded, dtype=values.dtype)
        node[o::stride, o::stride] = rough.to(values.dtype)
        near_rough = box_max(node[None, None], k)[0, 0] > 0
    return (candidate & near_rough) | (weight < 1 - 0.5 / stride**2)


def decode_dense(
    decoder: PixelDecoder,
    config: ModelConfig,
    features: Tensor,
    maps: Tensor,
    mask: Tensor,
    chunk: int | None = None,
    *,
    stride: int = 1,
    refine_deg: float | None = REFINE_DEG,
    light: Tensor | None = None,
) -> dict[str, Tensor]:
    """Decode the masked pixels, in chunks, each attending to a fixed context of masked pixels.

    The context (:func:`context_pixels`) runs through the decoder once; its pixels' outputs are taken from that
    pass (a context pixel decoded as a query attends to exactly the same keys), the other pixels are decoded in
    chunks against its cached keys and values. Results do not depend on ``chunk``, and at ``stride=1`` equal
    decoding every masked pixel as a query (to float rounding).

    Args:
        decoder: The model's :class:`~network.model.decoder.PixelDecoder`.
        config: The model's configuration (``train_pixels``, ``infer_chunk`` and the decoder widths).
        features: (B, 9, D, Hc, Wc) DPT features.
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
        refine_deg: Edge-aware stride (s > 1 only): filled pixels whose decoded neighbours disagree
            (:func:`unreliable_fill` with this normal threshold in degrees and :data:`REFINE_BRDF`) or are cut
            by the mask's edge are decoded too, so they get exactly their stride-1 values; None fills every
            covered pixel by interpolation.
        light: (B, 9, 3, H, W) each map's light vector (a ``light_input`` model), or None.

    Returns:
        ``normal`` (B, 3, H, W), ``albedo`` (B, 3, H, W), ``roughness`` (B, 1, H, W), ``metallic`` (B, 1, H, W);
        zeros outside the mask.

    Raises:
        ValueError: If ``stride`` is not a positive int.
    """
    if not isinstance(stride, int) or isinstance(stride, bool) or stride < 1:
        raise ValueError(f"stride must be a positive int. Got {stride!r}")
    chunk = chunk or config.infer_chunk
    b, _, h, w = maps.shape
    dec = decoder
    out = {k: torch.zeros(b, c, h * w, device=maps.device, dtype=torch.float32) for k, c in OUTPUT_CHANNELS.items()}
    pool_query = dec.pool.folded_query()
    for i in range(b):
        idx = torch.nonzero(mask[i].reshape(-1) > 0).squeeze(1)
        if idx.numel() == 0:
            continue
        inputs = dec.dense_inputs(features[i], maps[i], None if light is None else light[i])
        ctx = context_pixels(idx, config.train_pixels)
        cache, x = dec.context_pass(_embed_rows(dec, config, inputs, ctx, pool_query)[None])
        _store(out, i, ctx, dec.heads(x))
        decoded = torch.zeros(h * w, dtype=torch.bool, device=maps.device)
        decoded[ctx] = True
        queries = idx if stride == 1 else grid_pixels(idx, w, stride)
        queries = queries[~decoded[queries]]
        _decode_queries(dec, config, out, i, inputs, queries, cache, pool_query, chunk)
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
        if refine_deg is not None:
            values = torch.cat([out[k][i] for k in OUTPUT_CHANNELS]).reshape(-1, h, w)
            bad = unreliable_fill(values, decoded.reshape(h, w), weight.reshape(h, w), stride, refine_deg, REFINE_BRDF)
            covered &= ~bad.reshape(-1)
        start = 0
        for k, c in OUTPUT_CHANNELS.items():
            part = filled[start : start + c]
            start += c
            if k == "normal":
                part = safe_normalize(part, dim=0)
            out[k][i] = torch.where(covered, part, out[k][i])
        rest = torch.nonzero(todo & ~covered).squeeze(1)
        _decode_queries(dec, config, out, i, inputs, rest, cache, pool_query, chunk)
    return {k: v.reshape(b, -1, h, w) for k, v in out.items()}


def decode_dense_reference(
    decoder: PixelDecoder,
    config: ModelConfig,
    features: Tensor,
    maps: Tensor,
    mask: Tensor,
    chunk: int | None = None,
    light: Tensor | None = None,
) -> dict[str, Tensor]:
    """:func:`decode_dense` at stride 1 the straightforward way, for tests and ``headless/bench.py``.

    Every masked pixel, context pixels included, is decoded as a query through the training-mode
    :meth:`~network.model.decoder.PixelDecoder.embed` (gathers from the (B, 9, D, Hc, Wc) features, full pooling
    attention). Same arguments (without ``stride``) and outputs as :func:`decode_dense`.
    """
    chunk = chunk or config.infer_chunk
    b, _, h, w = maps.shape
    out = {k: torch.zeros(b, c, h * w, device=maps.device, dtype=torch.float32) for k, c in OUTPUT_CHANNELS.items()}
    for i in range(b):
        idx = torch.nonzero(mask[i].reshape(-1) > 0).squeeze(1)
        if idx.numel() == 0:
            continue
        f, mp = features[i : i + 1], maps[i : i + 1]
        lt = None if light is None else light[i : i + 1]
        cache = decoder.context_cache(decoder.embed(f, mp, context_pixels(idx, config.train_pixels)[None], lt))
        for part in idx.split(chunk):
            x = decoder.transform_cached(decoder.embed(f, mp, part[None], lt), cache)
            _store(out, i, part, decoder.heads(x))
    return {k: v.reshape(b, -1, h, w) for k, v in out.items()}


def _embed_rows(
    decoder: PixelDecoder, config: ModelConfig, inputs: DenseInputs, pixels: Tensor, pool_query: Tensor
) -> Tensor:
    """:meth:`PixelDecoder.embed_rows` in pieces of bounded memory (pixels are independent): (P, D_a)."""
    cfg = config
    hidden = [cfg.agg_dim] + [
        int(d * cfg.mlp_ratio) for d, n in ((cfg.dpt_dim, cfg.obs_depth), (cfg.agg_dim, cfg.agg_depth)) if n
    ]
    piece = max(1, EMBED_ELEMENTS // (NUM_MAPS * max(hidden)))  # the widest per-pixel intermediate: 9 MLP rows
    parts = [decoder.embed_rows(inputs, p, pool_query) for p in pixels.split(piece)]
    return parts[0] if len(parts) == 1 else torch.cat(parts)


def _decode_queries(
    decoder: PixelDecoder,
    config: ModelConfig,
    out: dict[str, Tensor],
    i: int,
    inputs: DenseInputs,
    pixels: Tensor,
    cache: Sequence[tuple[Tensor, Tensor]],
    pool_query: Tensor,
    chunk: int,
) -> None:
    """Decode ``pixels`` (P,) of image ``i`` against the cached context, in chunks, into ``out``.

    On a CPU with ``torch.get_num_threads()`` = n > 1 the chunks go to n Python threads that run torch on one
    thread each (:func:`query_workers`); the chunks are independent, so the outputs are those of one thread.
    """
    if pixels.numel() == 0:
        return

    def decode(part: Tensor) -> dict[str, Tensor]:
        x = decoder.transform_cached(_embed_rows(decoder, config, inputs, part, pool_query)[None], cache)
        return decoder.heads(x)

    workers = query_workers(pixels.device, pixels.numel(), chunk)
    if workers == 1:
        for part in pixels.split(chunk):
            _store(out, i, part, decode(part))
        return
    parts = pixels.tensor_split(workers * math.ceil(pixels.numel() / (workers * chunk)))  # even shares
    threads = torch.get_num_threads()
    inference, grad = torch.is_inference_mode_enabled(), torch.is_grad_enabled()  # thread-local in torch
    dev = pixels.device.type
    cast = {"enabled": torch.is_autocast_enabled(dev), "dtype": torch.get_autocast_dtype(dev)}  # thread-local too

    def decode_alone(part: Tensor) -> dict[str, Tensor]:
        torch.set_num_threads(1)
        with torch.inference_mode(inference), torch.set_grad_enabled(grad), torch.autocast(dev, **cast):
            return decode(part)

    try:
        with ThreadPoolExecutor(workers, thread_name_prefix="decode") as pool:
            for part, pred in zip(parts, pool.map(decode_alone, parts), strict=True):
                _store(out, i, part, pred)
    finally:
        torch.set_num_threads(threads)


def query_workers(device: torch.device, pixels: int, chunk: int) -> int:
    """Python threads for :func:`decode_dense`'s chunks: torch's thread count on a CPU with 2+ chunks' worth, else 1.

    On 2 cores, two chunks decoded side by side on one torch thread each keep both cores busy with less
    synchronisation than one chunk on two intra-op threads (docs/measurements/fullframe.md); a GPU decodes one
    chunk at a time.

    Example:
        >>> query_workers(torch.device("cpu"), 100, 8192), query_workers(torch.device("meta"), 10**6, 8192)
        (1, 1)
    """
    if device.type != "cpu" or pixels < 2 * min(chunk, 2048) or not _PARALLEL_QUERIES:
        return 1
    return max(1, torch.get_num_threads())


def _store(out: dict[str, Tensor], i: int, pixels: Tensor, pred: dict[str, Tensor]) -> None:
    """Write decoded (1, C, P) outputs of image ``i`` at flat ``pixels`` into (B, C, H*W) maps."""
    for k in out:
        out[k][i, :, pixels] = pred[k][0]
