"""Interleaved attention over the nine maps' tokens: spatial, spectral, cross-observation, polarimetric.

Tokens are ``(B, 9, N, C)``: B samples, the nine maps (:mod:`network.model.maps` order), N tokens per map. Each
attention *axis* rearranges them into independent sequences (:func:`to_sequences`): ``spatial`` attends within a
map, ``spectral`` across R, G, B of one polarization state, ``polarimetric`` across unpol, LP, CP of one colour,
``cross`` across all nine maps at one token position and ``global`` across all tokens of all maps.
:class:`InterleavedAttention` runs K iterations of (spatial, spectral, cross, polarimetric) pre-norm blocks.

Convention:
    Spectral groups are ``{0, 1, 2}, {3, 4, 5}, {6, 7, 8}`` (rows of the 3 x 3 map grid), polarimetric groups
    ``{0, 3, 6}, {1, 4, 7}, {2, 5, 8}`` (its columns). Every block shares its weights across the maps and sees
    them only through its groups, so a block is equivariant to permutations within and of its groups.

Example:
    >>> x = torch.zeros(2, 9, 5, 16)
    >>> to_sequences(x, "spectral").shape  # (B * 3 groups * N tokens, 3 members, C)
    torch.Size([30, 3, 16])
    >>> torch.equal(from_sequences(to_sequences(x, "cross"), "cross", x.shape), x)
    True
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from .layers import Block, init_linear_
from .maps import NUM_MAPS

__all__ = ["AXES", "AXIS_GROUPS", "AxisAttentionBlock", "InterleavedAttention", "from_sequences", "to_sequences"]

#: Map groups attended together by each grouped axis (every group is one attention sequence).
AXIS_GROUPS: dict[str, tuple[tuple[int, ...], ...]] = {
    "spectral": ((0, 1, 2), (3, 4, 5), (6, 7, 8)),
    "polarimetric": ((0, 3, 6), (1, 4, 7), (2, 5, 8)),
    "cross": (tuple(range(NUM_MAPS)),),
}
#: Attention axes: ``spatial`` (tokens of one map), the grouped axes above, and ``global`` (all tokens of all maps).
AXES = ("spatial", "spectral", "polarimetric", "cross", "global")


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
