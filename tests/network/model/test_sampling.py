"""Tests of network/model/sampling.py: random masked pixels, bilinear samples against ``F.grid_sample``."""

import pytest
import torch
import torch.nn.functional as F

from network.model.sampling import sample_bilinear, sample_bilinear_rows, sample_pixels


class TestSamplePixels:
    def test_sample_pixels(self):
        mask = torch.zeros(2, 1, 8, 8)
        mask[0, 0, :4] = 1  # 32 pixels
        mask[1, 0, 0, :3] = 1  # 3 pixels
        pixels, valid = sample_pixels(mask, 20, torch.Generator().manual_seed(3))
        assert pixels.shape == valid.shape == (2, 20)
        assert bool((pixels[0] < 32).all()) and len(set(pixels[0].tolist())) == 20 and bool(valid[0].all())
        assert valid[1].sum() == 3 and set(pixels[1][valid[1]].tolist()) == {0, 1, 2}


class TestSampleBilinear:
    @pytest.mark.parametrize(
        ("size", "feature_size"), [((64, 64), (32, 32)), ((48, 80), (24, 40)), ((30, 50), (8, 16))]
    )
    def test_sample_bilinear_matches_grid_sample(self, size, feature_size):
        g = torch.Generator().manual_seed(0)
        h, w = size
        features = torch.randn(2, 5, *feature_size, generator=g)
        pixels = torch.randint(0, h * w, (2, 40), generator=g)
        row, col = pixels // w, pixels % w
        grid = torch.stack([(col + 0.5) * 2 / w - 1, (row + 0.5) * 2 / h - 1], -1)[:, None].float()
        expected = F.grid_sample(features, grid, mode="bilinear", padding_mode="border", align_corners=False)[:, :, 0]
        torch.testing.assert_close(sample_bilinear(features, pixels, size), expected, rtol=1e-5, atol=1e-5)


class TestSampleBilinearRows:
    @pytest.mark.parametrize(
        ("size", "feature_size"), [((64, 64), (32, 32)), ((48, 80), (20, 36)), ((30, 30), (40, 40))]
    )
    def test_sample_bilinear_rows_matches_grid_sample(self, size, feature_size):
        (h, w), (hc, wc) = size, feature_size
        g = torch.Generator().manual_seed(5)
        features = torch.randn(1, 7, hc, wc, generator=g)
        pixels = torch.randperm(h * w, generator=g)[:200]
        rows, cols = pixels // w, pixels % w
        grid = torch.stack([(cols + 0.5) / w * 2 - 1, (rows + 0.5) / h * 2 - 1], -1).float()[None, None]
        expected = F.grid_sample(features, grid, mode="bilinear", padding_mode="border", align_corners=False)[0, :, 0]
        table = features[0].permute(1, 2, 0).reshape(hc * wc, 7)
        torch.testing.assert_close(
            sample_bilinear_rows(table, pixels, size, feature_size).t(), expected, atol=2e-5, rtol=1e-5
        )
