"""Tests of network/model/interleave.py: sequence layouts and what each attention axis attends over."""

import pytest
import torch

from network.model.interleave import AxisAttentionBlock, from_sequences, to_sequences

# Permutations of the nine maps [R_unpol, G_unpol, B_unpol, R_LP, G_LP, B_LP, R_CP, G_CP, B_CP]; perm[i] is the map
# that lands at position i (x[:, perm]).
SWAP_UNPOL_LP = [3, 4, 5, 0, 1, 2, 6, 7, 8]  # rows of the 3 x 3 (polarization x colour) grid
SWAP_R_G = [1, 0, 2, 4, 3, 5, 7, 6, 8]  # columns of the grid
SWAP_R_UNPOL_G_LP = [4, 1, 2, 3, 0, 5, 6, 7, 8]  # not a grid symmetry


class TestSequences:
    @pytest.mark.parametrize("axis", ["spatial", "spectral", "polarimetric", "cross", "global"])
    def test_round_trip(self, axis):
        x = torch.randn(2, 9, 5, 4)
        assert torch.equal(from_sequences(to_sequences(x, axis), axis, x.shape), x)

    def test_layouts(self):
        # Token value = 100 * map + token position, so each sequence's members can be read off.
        x = (100 * torch.arange(9)[:, None] + torch.arange(5)[None]).float()[None, :, :, None]  # (1, 9, 5, 1)
        assert to_sequences(x, "spatial").shape == (9, 5, 1)
        assert to_sequences(x, "global").shape == (1, 45, 1)
        assert to_sequences(x, "cross")[2, :, 0].tolist() == [100 * m + 2 for m in range(9)]
        spectral = to_sequences(x, "spectral")  # (3 groups * 5 tokens, 3, 1)
        assert spectral.shape == (15, 3, 1)
        assert spectral[1 * 5 + 4, :, 0].tolist() == [304, 404, 504]  # group {3,4,5} (LP), token 4
        polar = to_sequences(x, "polarimetric")
        assert polar[2 * 5 + 1, :, 0].tolist() == [201, 501, 801]  # group {2,5,8} (B), token 1

    def test_unknown_axis(self):
        with pytest.raises(ValueError, match="Unknown attention axis"):
            to_sequences(torch.zeros(1, 9, 2, 2), "diagonal")


def axis_block(axis, seed=0):
    torch.manual_seed(seed)
    return AxisAttentionBlock(axis, dim=16, heads=2, mlp_ratio=2.0, qk_norm=True, layerscale=1.0).eval()


class TestAxisAttention:
    """Each interleaved step attends over exactly the axis the design names."""

    # Which (map, token) outputs change when map 0's token 1 changes.
    @pytest.mark.parametrize(
        ("axis", "maps", "all_tokens"),
        [
            ("spatial", {0}, True),
            ("spectral", {0, 1, 2}, False),
            ("polarimetric", {0, 3, 6}, False),
            ("cross", set(range(9)), False),
            ("global", set(range(9)), True),
        ],
    )
    def test_dependency_structure(self, axis, maps, all_tokens):
        block = axis_block(axis)
        x = torch.randn(1, 9, 6, 16)
        y = x.clone()
        y[0, 0, 1] += torch.randn(16)  # not a constant shift, which the pre-norm LayerNorm would remove
        with torch.no_grad():
            changed = (block(y) - block(x)).abs().amax(-1)[0] > 1e-6  # (9, 6)
        tokens = set(range(6)) if all_tokens else {1}
        expected = torch.zeros(9, 6, dtype=torch.bool)
        for m in maps:
            for t in tokens:
                expected[m, t] = True
        assert torch.equal(changed, expected)

    @pytest.mark.parametrize(
        ("axis", "perm"),
        [
            ("spectral", [1, 2, 0, 5, 3, 4, 6, 8, 7]),  # within the RGB groups of each polarization state
            ("spectral", SWAP_UNPOL_LP),  # whole groups
            ("polarimetric", [3, 1, 2, 6, 4, 5, 0, 7, 8]),  # within group {0, 3, 6}
            ("polarimetric", SWAP_R_G),  # whole groups
            ("cross", [4, 7, 0, 2, 8, 1, 3, 6, 5]),  # any permutation
            ("global", [4, 7, 0, 2, 8, 1, 3, 6, 5]),
            ("spatial", [4, 7, 0, 2, 8, 1, 3, 6, 5]),
        ],
    )
    def test_equivariant_to_map_permutations(self, axis, perm):
        block = axis_block(axis)
        x = torch.randn(2, 9, 6, 16)
        with torch.no_grad():
            torch.testing.assert_close(block(x[:, perm]), block(x)[:, perm], rtol=1e-5, atol=1e-5)

    @pytest.mark.parametrize(
        ("axis", "perm"), [("spectral", SWAP_R_UNPOL_G_LP), ("polarimetric", [1, 0, 2, 3, 4, 5, 6, 7, 8])]
    )
    def test_not_equivariant_across_groups(self, axis, perm):
        block = axis_block(axis)
        x = torch.randn(1, 9, 6, 16)
        with torch.no_grad():
            assert (block(x[:, perm]) - block(x)[:, perm]).abs().max() > 1e-3

    def test_spatial_equivariant_to_token_permutation(self):
        # No position information inside the block: the tokens carry it from the tokenizer.
        block = axis_block("spatial")
        x = torch.randn(1, 9, 6, 16)
        perm = [3, 0, 5, 1, 2, 4]
        with torch.no_grad():
            torch.testing.assert_close(block(x[:, :, perm]), block(x)[:, :, perm], rtol=1e-5, atol=1e-5)
