"""Tests of network/model/decoder.py: safe normalisation, the folded pooling, the row-table embedding."""

import pytest
import torch

from network.model.decoder import PoolingAttention, safe_normalize
from tests.helpers import make_model


class TestSafeNormalize:
    def test_zero_vector(self):
        v = torch.tensor([[0.0, 0.0, 0.0], [3.0, 0.0, 4.0]], requires_grad=True)
        n = safe_normalize(v, dim=1)
        torch.testing.assert_close(n, torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]))
        n.sum().backward()
        assert bool(torch.isfinite(v.grad).all())


class TestPoolingAttention:
    @pytest.mark.parametrize("heads", [1, 4])
    def test_folded_pooling_equals_attention_pooling(self, heads):
        torch.manual_seed(6)
        pool = PoolingAttention(32, heads)
        with torch.no_grad():
            for p in pool.parameters():
                p.add_(0.3 * torch.randn_like(p))  # non-trivial biases and norms
            x = 2 * torch.randn(50, 9, 32)
            torch.testing.assert_close(pool.forward_folded(x, pool.folded_query()), pool(x), rtol=0, atol=2e-5)


class TestPixelDecoder:
    def test_embed_rows_equals_embed(self):
        model = make_model("small", train_pixels=64)
        dec = model.decoder
        g = torch.Generator().manual_seed(4)
        feats = torch.randn(1, 9, 64, 24, 24, generator=g)
        maps = torch.rand(1, 9, 96, 96, generator=g)
        pixels = torch.randperm(96 * 96, generator=g)[:300]
        with torch.no_grad():
            rows = dec.embed_rows(dec.dense_inputs(feats[0], maps[0]), pixels, dec.pool.folded_query())
            ref = dec.embed(feats, maps, pixels[None])[0]
        torch.testing.assert_close(rows, ref, rtol=0, atol=2e-5 * float(ref.abs().max()))
