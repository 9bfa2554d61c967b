"""Model configurations: one frozen dataclass and four named presets.

Checkpoints store a configuration as a plain dict (:func:`ModelConfig.to_dict`), never as a pickled object;
:func:`ModelConfig.from_dict` rebuilds it and rejects unknown keys. Parameter counts and FLOPs of a configuration
come from :func:`network.model.count_parameters` and :func:`network.model.estimate_flops`; the presets' numbers
and CPU timings are in docs/measurements/network.md.

- ``toy``: 64 x 64 input, 4 x 4 tokens of dim 32, K = 1, D = 16, D_a = 32, 64 training pixels. For tests only.
- ``small``: 384 x 384 input, tokenizer at 96 x 96 (12 x 12 tokens of dim 128, 4 blocks), K = 2, D = 64
  features at 96 x 96, D_a = 96, 2048 training pixels. For CPU experiments.
- ``medium``: 384 x 384 input, tokenizer at 128 x 128 (16 x 16 tokens of dim 256, 6 blocks, 8 heads), K = 3,
  DPT widths (64, 128, 256, 256) to D = 96 features at 128 x 128, D_a = 128 (no aggregation blocks, as
  ``small``), 2048 training pixels: between ``small`` and ``paper``, sized for GPU leases (its bf16 checkpoint
  is tens of MB) with a per-pixel decoder still fit for the CPU inference path (docs/measurements/network.md).
- ``paper``: the sizes of the LINO-UniPS reference implementation: a ViT-S tokenizer (dim 384, 12 blocks,
  6 heads, 4 registers) with **8-pixel patches** on the maps resized to the canonical resolution 192 (24 x 24
  tokens; LINO-UniPS uses ``vit_small(patch_size=8)``, not DINOv2's 14), K = 4 interleaved iterations, DPT with
  reassemble widths (256, 512, 1024, 1024) to D = 256 features at 192 x 192, per-pixel decoder with D_a = 384
  (2 observation blocks at D, 3 at D_a, 2 pixel-transformer blocks), 2048 training pixels. Unlike LINO-UniPS
  there is no wavelet (Haar) full-resolution branch: full-resolution detail enters the decoder through
  psi(I_n(x)) only.

Example:
    >>> cfg = get_config("toy", train_pixels=32)
    >>> cfg.train_pixels, cfg.token_grid
    (32, 4)
    >>> ModelConfig.from_dict(cfg.to_dict()) == cfg
    True
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

__all__ = ["CONFIGS", "CROSS_OBSERVATION_MODES", "ModelConfig", "get_config"]

#: Valid values of :attr:`ModelConfig.cross_observation`.
CROSS_OBSERVATION_MODES = ("token", "global")


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of :class:`network.model.PolarInverseModel`; the defaults are the ``paper`` preset.

    Attributes:
        image_size: Nominal network input size in pixels (square); the decoder works at the input resolution.
            Other input sizes are accepted: the tokenizer resolution scales with ``canonical_size / image_size``.
        canonical_size: Resolution the maps are resized to for the tokenizer, and of the DPT feature maps
            (the reference requires ``image_size == 2 * canonical_size``; here any ratio works).
        patch_size: ViT patch size in pixels; ``canonical_size`` must be a multiple of it.
        embed_dim: Token dimension C of the tokenizer and the interleaved attention.
        depth: Number of tokenizer (ViT) blocks.
        heads: Attention heads of the tokenizer and of the interleaved attention.
        registers: Number of register tokens (DINOv2-reg style; placed after the class token, no position embedding).
        mlp_ratio: MLP hidden size / token dimension in every transformer block.
        init_std: Standard deviation of the truncated-normal (at +-2 std) initialisation of the tokenizer's and the
            interleaved blocks' linear layers (0.02, the ViT/DINOv2 convention). The DPT convolutions and the
            per-pixel decoder keep PyTorch's default initialisation (uniform, scale 1/sqrt(fan-in)), as in
            SDM-UniPS/LINO-UniPS: with 0.02 the toy decoder stayed at the constant-prediction plateau
            (docs/measurements/network.md).
        vit_layerscale: Initial LayerScale of the tokenizer blocks. 1.0 (= no damping) follows LINO-UniPS's
            randomly initialised ``vit_small(init_values=1.0)``; DINOv2's pretrained weights used 1e-5, and loading
            them overwrites it.
        interleave_iters: K, the number of (spatial, spectral, cross-observation, polarimetric) iterations.
        interleave_layerscale: Initial LayerScale of the interleaved blocks (0.01 as in LINO-UniPS's aggregator),
            so that the pretrained-or-not tokenizer output passes nearly unchanged at initialisation.
        qk_norm: LayerNorm on queries and keys (per head) in the interleaved blocks, as in LINO-UniPS; keeps
            attention logits bounded under bf16.
        cross_observation: ``"token"``: the cross-observation step attends across the nine maps at the same
            token position (sequences of 9); ``"global"``: across all tokens of all nine maps (sequences of
            9 x tokens, LINO-UniPS's "global" frame attention; costlier).
        dpt_channels: Widths of the four DPT reassemble stages (at 4x, 2x, 1x and 1/2x the token grid).
        dpt_dim: D, the DPT feature width (per map, at ``canonical_size``).
        pixel_embed_hidden: Hidden width of psi, the MLP embedding a map's pixel value into D.
        obs_depth: Self-attention blocks across the nine observations of a pixel, at width D.
        agg_dim: D_a, the width of a pixel's aggregated feature.
        agg_depth: Self-attention blocks across the nine observations at width D_a, before pooling.
        decoder_heads: Attention heads of the observation blocks and the pooling (learnable-query) attention.
        pixel_depth: Blocks of the transformer across sampled pixels.
        pixel_heads: Attention heads of that transformer.
        train_pixels: Pixels decoded per image in training mode (random, inside the mask); also the number of
            context pixels every pixel attends to in dense (evaluation) decoding.
        infer_chunk: Pixels decoded together in dense decoding (memory bound; results do not depend on it).
        light_input: The model also takes the display's irradiance per colour region at the object's distance
            (:mod:`network.light_input`, 9 channels): each map's region vector enters the tokenizer's patch tokens
            and the decoder's observations through zero-initialised projections, so a model given them starts
            out as the same function as without. False (default, and every checkpoint without the key) builds
            the model exactly as before.
    """

    image_size: int = 384
    canonical_size: int = 192
    patch_size: int = 8
    embed_dim: int = 384
    depth: int = 12
    heads: int = 6
    registers: int = 4
    mlp_ratio: float = 4.0
    init_std: float = 0.02
    vit_layerscale: float = 1.0
    interleave_iters: int = 4
    interleave_layerscale: float = 0.01
    qk_norm: bool = True
    cross_observation: str = "token"
    dpt_channels: tuple[int, int, int, int] = field(default=(256, 512, 1024, 1024))
    dpt_dim: int = 256
    pixel_embed_hidden: int = 32
    obs_depth: int = 2
    agg_dim: int = 384
    agg_depth: int = 3
    decoder_heads: int = 8
    pixel_depth: int = 2
    pixel_heads: int = 8
    train_pixels: int = 2048
    infer_chunk: int = 4096
    light_input: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "dpt_channels", tuple(int(c) for c in self.dpt_channels))
        positive = (
            "image_size",
            "canonical_size",
            "patch_size",
            "embed_dim",
            "depth",
            "heads",
            "interleave_iters",
            "dpt_dim",
            "pixel_embed_hidden",
            "agg_dim",
            "decoder_heads",
            "pixel_heads",
            "train_pixels",
            "infer_chunk",
        )
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"ModelConfig.{name} must be a positive int. Got {value!r}")
        for name in ("registers", "obs_depth", "agg_depth", "pixel_depth"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"ModelConfig.{name} must be a non-negative int. Got {value!r}")
        for name in ("mlp_ratio", "init_std"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ModelConfig.{name} must be > 0. Got {getattr(self, name)!r}")
        if not isinstance(self.light_input, bool):
            raise ValueError(f"ModelConfig.light_input must be a bool. Got {self.light_input!r}")
        if len(self.dpt_channels) != 4 or min(self.dpt_channels) < 1:
            raise ValueError(f"ModelConfig.dpt_channels must be 4 positive ints. Got {self.dpt_channels!r}")
        if self.canonical_size % self.patch_size:
            raise ValueError(
                f"ModelConfig.canonical_size ({self.canonical_size}) must be a multiple of patch_size "
                f"({self.patch_size})"
            )
        for dim, heads, what in (
            (self.embed_dim, self.heads, "embed_dim / heads"),
            (self.dpt_dim, self.decoder_heads, "dpt_dim / decoder_heads"),
            (self.agg_dim, self.decoder_heads, "agg_dim / decoder_heads"),
            (self.agg_dim, self.pixel_heads, "agg_dim / pixel_heads"),
        ):
            if dim % heads:
                raise ValueError(f"ModelConfig: {what} = {dim} / {heads} is not an integer")
        if self.cross_observation not in CROSS_OBSERVATION_MODES:
            raise ValueError(
                f"ModelConfig.cross_observation must be one of {CROSS_OBSERVATION_MODES}. "
                f"Got {self.cross_observation!r}"
            )

    @property
    def token_grid(self) -> int:
        """Side of the token grid at the nominal size (``canonical_size // patch_size``)."""
        return self.canonical_size // self.patch_size

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON-serialisable dict of the fields (tuples become lists).

        ``light_input`` is left out while False, so a light-blind model's dict is the one checkpoints
        written before the field existed hold (resuming compares them).
        """
        out = dataclasses.asdict(self)
        out["dpt_channels"] = list(self.dpt_channels)
        if not self.light_input:
            del out["light_input"]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Rebuild a configuration from :meth:`to_dict` output.

        Missing keys take the defaults (the ``paper`` preset).

        Raises:
            ValueError: On unknown keys or invalid values.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"Unknown ModelConfig keys {unknown}; valid keys are {sorted(names)}")
        return cls(**data)


CONFIGS: dict[str, ModelConfig] = {
    "toy": ModelConfig(
        image_size=64,
        canonical_size=32,
        patch_size=8,
        embed_dim=32,
        depth=1,
        heads=2,
        registers=2,
        interleave_iters=1,
        dpt_channels=(16, 16, 32, 32),
        dpt_dim=16,
        pixel_embed_hidden=8,
        obs_depth=1,
        agg_dim=32,
        agg_depth=1,
        decoder_heads=2,
        pixel_depth=1,
        pixel_heads=2,
        train_pixels=64,
        infer_chunk=512,
    ),
    "small": ModelConfig(
        image_size=384,
        canonical_size=96,
        patch_size=8,
        embed_dim=128,
        depth=4,
        heads=4,
        registers=4,
        interleave_iters=2,
        dpt_channels=(32, 64, 128, 128),
        dpt_dim=64,
        pixel_embed_hidden=16,
        obs_depth=1,
        agg_dim=96,
        agg_depth=0,
        decoder_heads=4,
        pixel_depth=1,
        pixel_heads=4,
        train_pixels=2048,
        infer_chunk=8192,
    ),
    "paper": ModelConfig(),
}
#: ``medium``: ``small`` widened and deepened (the sizes it changes; docs/measurements/network.md).
CONFIGS["medium"] = dataclasses.replace(
    CONFIGS["small"], canonical_size=128, embed_dim=256, depth=6, heads=8, interleave_iters=3,
    dpt_channels=(64, 128, 256, 256), dpt_dim=96, agg_dim=128,
)  # fmt: skip


def get_config(name: str, **overrides: Any) -> ModelConfig:
    """A named preset, optionally with some fields replaced.

    Args:
        name: One of ``"toy"``, ``"small"``, ``"medium"``, ``"paper"``.
        **overrides: Field values to replace, e.g. ``train_pixels=1024``.

    Returns:
        The (validated) configuration.

    Raises:
        ValueError: On an unknown preset name, an unknown field or an invalid value.

    Example:
        >>> get_config("toy", train_pixels=32).train_pixels
        32
    """
    if name not in CONFIGS:
        raise ValueError(f"Unknown model config {name!r}; valid names are {sorted(CONFIGS)}")
    names = {f.name for f in dataclasses.fields(ModelConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ValueError(f"Unknown ModelConfig keys {unknown}; valid keys are {sorted(names)}")
    return dataclasses.replace(CONFIGS[name], **overrides)
