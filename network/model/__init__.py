"""The feed-forward model (:class:`PolarInverseModel`) and its parts, one module per stage.

==================  ==============================================================================================
module              contents
==================  ==============================================================================================
``maps``            the nine-map layout (order, polarization state and colour of each map)
``layers``          transformer building blocks (attention, MLP, LayerScale, pre-norm block; DINOv2 names)
``tokenizer``       per-map DINOv2-style ViT and the learned map identity
``interleave``      spatial / spectral / cross-observation / polarimetric attention over the nine maps
``dpt``             DPT head: tokens to dense per-map features
``sampling``        random masked pixels, bilinear feature samples at pixel centres
``decoder``         per-pixel decoder (observation attention, pooling, pixel transformer, heads)
``dense``           dense decoding against a cached context, chunked, with an optional stride
``polar_model``     :class:`PolarInverseModel`, which ties the stages together
``pretrained``      pretrained ViT weights for the tokenizer
``flops``           parameter counts and the analytic FLOP estimate
==================  ==============================================================================================

Every public name of the sub-modules is re-exported here, e.g.
``from network.model import PolarInverseModel, count_parameters, grid_pixels``.
"""

from .decoder import DenseInputs, MapValueEmbedding, PixelDecoder, PoolingAttention, safe_normalize
from .dense import (
    EMBED_ELEMENTS,
    context_pixels,
    decode_dense,
    decode_dense_reference,
    fill_from_decoded,
    grid_pixels,
)
from .dpt import DPTHead, FusionBlock, ResidualConvUnit
from .flops import count_parameters, estimate_flops
from .interleave import AXES, AXIS_GROUPS, AxisAttentionBlock, InterleavedAttention, from_sequences, to_sequences
from .layers import Attention, Block, LayerScale, Mlp, init_linear_, multi_head_attention, trunc_normal_
from .maps import MAP_COLOR, MAP_POLARIZATION, NUM_MAPS
from .polar_model import PolarInverseModel
from .pretrained import IGNORED_PRETRAINED_KEYS, LoadReport, load_pretrained_vit
from .sampling import sample_bilinear, sample_bilinear_rows, sample_pixels
from .tokenizer import IN_CHANS, MapEmbedding, PatchEmbed, ViTTokenizer, interpolate_pos_embed

__all__ = [
    "AXES",
    "AXIS_GROUPS",
    "EMBED_ELEMENTS",
    "IGNORED_PRETRAINED_KEYS",
    "IN_CHANS",
    "MAP_COLOR",
    "MAP_POLARIZATION",
    "NUM_MAPS",
    "Attention",
    "AxisAttentionBlock",
    "Block",
    "DPTHead",
    "DenseInputs",
    "FusionBlock",
    "InterleavedAttention",
    "LayerScale",
    "LoadReport",
    "MapEmbedding",
    "MapValueEmbedding",
    "Mlp",
    "PatchEmbed",
    "PixelDecoder",
    "PolarInverseModel",
    "PoolingAttention",
    "ResidualConvUnit",
    "ViTTokenizer",
    "context_pixels",
    "count_parameters",
    "decode_dense",
    "decode_dense_reference",
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
