"""The feed-forward model: nine polarimetric maps and a mask to per-pixel normal, albedo, roughness and metallic.

Pipeline (the LINO-UniPS / PDIR design, reimplemented):

1. **Tokenizer** (:mod:`network.model.tokenizer`): each of the nine maps goes through one shared DINOv2-style ViT
   at the canonical resolution; a learned polarization-state and colour-channel embedding is added.
2. **Interleaved attention** (:mod:`network.model.interleave`): tokens ``(B, 9, N, C)``; K iterations of spatial,
   spectral, cross-observation and polarimetric pre-norm attention blocks.
3. **DPT head** (:mod:`network.model.dpt`): the patch tokens of four iterations (4C each) are reassembled at four
   scales and fused into D features per map at the canonical resolution.
4. **Per-pixel decoder** (:mod:`network.model.decoder`): per pixel, the nine observations (sampled features and
   map values) are embedded, attend to each other and are pooled into one D_a vector; a transformer across pixels
   and output heads follow. In evaluation mode every masked pixel is decoded against a fixed context of pixels
   (:mod:`network.model.dense`).

Map order (:mod:`network.model.maps`): ``[R_unpol, G_unpol, B_unpol, R_LP, G_LP, B_LP, R_CP, G_CP, B_CP]``.

Symmetry: every stage shares its weights across maps and every attention step sees the maps only through its
groups; the pooling over the nine observations is even invariant to *any* permutation. So without the identity
parameters (:class:`~network.model.tokenizer.MapEmbedding` on the tokens, the map-specific first layer of
:class:`~network.model.decoder.MapValueEmbedding`) the model is *invariant* to any permutation that preserves both
partitions (permuting the polarization states, the colour channels, or both: rows and columns of the 3 x 3 map
grid), and only the grouped attention makes it sensitive to other permutations. The identity parameters break the
remaining symmetry, so the model can tell unpol from LP and R from G.

Initialisation: the tokenizer and interleaved blocks use a truncated normal (``config.init_std``, 0.02) for linear
layers, zero biases, LayerScale ``config.vit_layerscale`` (1.0) and ``config.interleave_layerscale`` (0.01); class,
register, position and map embeddings and the pooling query a truncated normal of std 0.02. The DPT and the
per-pixel decoder keep PyTorch's default initialisation (why: ``init_std`` in :class:`network.config.ModelConfig`).

Input scaling is the data pipeline's job (:func:`network.data.normalize_maps`): the model expects the maps already
normalised and does not rescale them.

Light input (``config.light_input``, :mod:`network.light_input`): ``light`` (B, 9, H, W) holds the display's
irradiance vector of each colour region; map n sees its own region's vector (``MAP_COLOR[n]``). It enters the
tokenizer as ``light_embed`` (a patch projection, 3 -> C, added to the patch embeddings) and the decoder as
``decoder.chi`` (3 -> D, added to each observation); both start at zero, so weights loaded from a light-blind
checkpoint (:func:`network.checkpoint.init_from_checkpoint`) give exactly the light-blind model's outputs.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from network.config import ModelConfig

from .decoder import PixelDecoder
from .dense import REFINE_DEG, decode_dense, decode_dense_reference
from .dpt import DPTHead
from .interleave import InterleavedAttention
from .maps import MAP_COLOR, NUM_MAPS
from .sampling import sample_pixels
from .tokenizer import IN_CHANS, MapEmbedding, ViTTokenizer

__all__ = ["PolarInverseModel"]


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
        if config.light_input:
            self.light_embed = nn.Conv2d(3, c, config.patch_size, stride=config.patch_size, bias=False)
            nn.init.zeros_(self.light_embed.weight)
        k = config.interleave_iters
        #: Iterations feeding the four DPT levels (evenly spread; repeats when K < 4).
        self.dpt_levels = tuple(round(i * (k - 1) / 3) for i in range(4))

    def tokenizer_size(self, height: int, width: int) -> tuple[int, int]:
        """Tokenizer input size for an (height, width) input: scaled by canonical/image, rounded to patches."""
        cfg = self.config
        scale = cfg.canonical_size / cfg.image_size
        p = cfg.patch_size
        return (max(p, round(height * scale / p) * p), max(p, round(width * scale / p) * p))

    def per_map_light(self, light: Tensor | None, like: Tensor) -> Tensor | None:
        """(B, 9, H, W) light channels -> (B, 9, 3, H, W), map n's region vector; None for a light-blind model.

        Raises:
            ValueError: a light-input model without ``light``, or ``light`` of the wrong shape.
        """
        if not self.config.light_input:
            return None
        b, _, h, w = like.shape
        if light is None or tuple(light.shape) != (b, 9, h, w):
            got = None if light is None else tuple(light.shape)
            raise ValueError(f"light must have shape {(b, 9, h, w)} for a light_input model. Got {got}")
        index = torch.tensor([3 * c + k for c in MAP_COLOR for k in range(3)], device=light.device)
        return light.to(like.dtype).index_select(1, index).reshape(b, NUM_MAPS, 3, h, w)

    def encode(self, maps: Tensor, mask: Tensor, light: Tensor | None = None) -> Tensor:
        """Per-map features at the canonical resolution.

        Args:
            maps: (B, 9, H, W).
            mask: (B, 1, H, W) in {0, 1}.
            light: (B, 9, H, W) light channels (``config.light_input`` only; ignored otherwise).

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
        extra = None
        lm = self.per_map_light(light, maps)
        if lm is not None:
            lx = lm.reshape(b, m * 3, h, w) * mask
            if (hc, wc) != (h, w):
                lx = F.interpolate(lx, size=(hc, wc), mode="area")
            extra = self.light_embed(lx.reshape(b * m, 3, hc, wc)).flatten(2).transpose(1, 2)
        tokens, grid = self.tokenizer(inp, extra)
        tokens = tokens.reshape(b, m, tokens.shape[1], -1) + self.map_embed()[:, None].to(tokens.dtype)
        outputs = self.interleave(tokens)
        start = self.tokenizer.num_prefix
        levels = [outputs[i][:, :, start:].reshape(b * m, grid[0] * grid[1], -1) for i in self.dpt_levels]
        feats = self.dpt(levels, grid, (hc, wc))
        return feats.reshape(b, m, feats.shape[1], hc, wc)

    def decode_pixels(
        self, features: Tensor, maps: Tensor, pixels: Tensor, valid: Tensor | None = None, light: Tensor | None = None
    ) -> dict[str, Tensor]:
        """Decode a set of pixels per image, the pixels of an image attending to each other.

        Args:
            features: (B, 9, D, Hc, Wc) from :meth:`encode`.
            maps: (B, 9, H, W).
            pixels: (B, P) flat indices into H x W.
            valid: Optional (B, P) bool; invalid pixels are not attended to (their outputs are meaningless).
            light: (B, 9, H, W) light channels (``config.light_input`` only).

        Returns:
            ``normal`` (B, 3, P), ``albedo`` (B, 3, P), ``roughness`` (B, 1, P), ``metallic`` (B, 1, P).
        """
        x = self.decoder.embed(features, maps, pixels, self.per_map_light(light, maps))
        key_mask = None
        if valid is not None and not bool(valid.all()):
            key_mask = valid.clone()
            key_mask[~valid.any(dim=1), 0] = True  # an image without valid pixels attends to one dummy key
        return self.decoder.heads(self.decoder.transform(x, key_mask))

    def decode_dense(
        self,
        features: Tensor,
        maps: Tensor,
        mask: Tensor,
        chunk: int | None = None,
        *,
        stride: int = 1,
        refine_deg: float | None = REFINE_DEG,
        light: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """Decode the masked pixels densely: :func:`~network.model.dense.decode_dense` with this model's decoder.

        Args:
            features: (B, 9, D, Hc, Wc) from :meth:`encode`.
            maps: (B, 9, H, W).
            mask: (B, 1, H, W).
            chunk: Query pixels per pixel-transformer call (default ``config.infer_chunk``).
            stride: 1 decodes every masked pixel; s > 1 decodes every s-th row and column and fills the rest.
            refine_deg: s > 1: also decode the filled pixels whose decoded neighbours' normals differ by more than
                this (degrees), whose BRDF values differ, or that the mask's edge cuts; None interpolates them all.
            light: (B, 9, H, W) light channels (``config.light_input`` only).

        Returns:
            ``normal`` (B, 3, H, W), ``albedo`` (B, 3, H, W), ``roughness`` (B, 1, H, W), ``metallic`` (B, 1, H, W);
            zeros outside the mask.

        Raises:
            ValueError: If ``stride`` is not a positive int.
        """
        return decode_dense(
            self.decoder, self.config, features, maps, mask, chunk, stride=stride, refine_deg=refine_deg,
            light=self.per_map_light(light, maps),
        )  # fmt: skip

    def decode_dense_reference(
        self, features: Tensor, maps: Tensor, mask: Tensor, chunk: int | None = None, light: Tensor | None = None
    ) -> dict[str, Tensor]:
        """:meth:`decode_dense` at stride 1 the straightforward way, for tests and benchmarks.

        See :func:`~network.model.dense.decode_dense_reference`; same arguments (without ``stride``) and outputs.
        """
        lm = self.per_map_light(light, maps)
        return decode_dense_reference(self.decoder, self.config, features, maps, mask, chunk, light=lm)

    def forward(
        self,
        maps: Tensor,
        mask: Tensor,
        *,
        pixels: Tensor | None = None,
        generator: torch.Generator | None = None,
        chunk: int | None = None,
        stride: int = 1,
        refine_deg: float | None = REFINE_DEG,
        light: Tensor | None = None,
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
            refine_deg: Edge-aware stride (:meth:`decode_dense`); None turns the refinement off.
            light: (B, 9, H, W) light channels (:mod:`network.light_input`); required by a ``light_input`` model,
                ignored by others.

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
        features = self.encode(maps, mask, light)
        if pixels is not None:
            if pixels.ndim != 2 or pixels.shape[0] != b:
                raise ValueError(f"pixels must have shape ({b}, P). Got {tuple(pixels.shape)}")
            pixels = pixels.long()
            out = self.decode_pixels(features, maps, pixels, light=light)
            return {**out, "pixels": pixels, "valid": torch.ones_like(pixels, dtype=torch.bool)}
        if self.training:
            pixels, valid = sample_pixels(mask, self.config.train_pixels, generator)
            out = self.decode_pixels(features, maps, pixels, valid, light)
            return {**out, "pixels": pixels, "valid": valid}
        return self.decode_dense(features, maps, mask, chunk, stride=stride, refine_deg=refine_deg, light=light)
