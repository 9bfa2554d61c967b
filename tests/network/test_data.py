"""Tests of network/data.py: input normalisation, pixel gathers, the dataset reader."""

import pytest
import torch

from network import data


def test_normalize_maps_is_scale_invariant_and_keeps_cp():
    g = torch.Generator().manual_seed(0)
    maps = torch.rand(2, 9, 8, 8, generator=g)
    mask = (torch.rand(2, 1, 8, 8, generator=g) > 0.3).float()
    a = data.normalize_maps(maps, mask)
    b = data.normalize_maps(maps * torch.tensor([1.0] * 6 + [1.0] * 3)[None, :, None, None] * 1.0, mask)
    scaled = maps.clone()
    scaled[:, :6] *= 37.0  # brighter display / longer exposure: same normalised input
    c = data.normalize_maps(scaled, mask)
    torch.testing.assert_close(a, b)
    torch.testing.assert_close(a, c, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(a[:, 6:], maps[:, 6:] * mask)
    assert torch.all(a[:, :, mask[0, 0] == 0][0] == 0)


def test_gather_pixels():
    maps = torch.arange(2 * 3 * 4 * 5, dtype=torch.float32).reshape(2, 3, 4, 5)
    pix = torch.tensor([[0, 7], [19, 5]])
    g = data.gather_pixels(maps, pix)
    assert g.shape == (2, 3, 2)
    assert float(g[1, 2, 0]) == float(maps[1, 2, 3, 4]) and float(g[0, 1, 1]) == float(maps[0, 1, 1, 2])


@pytest.mark.mitsuba
def test_dataset_reads_samples(tiny_dataset):
    ds = data.SampleDataset(tiny_dataset, size=64)
    item = ds[0]
    assert item["maps"].shape == (9, 64, 64) and item["mask"].shape == (1, 64, 64)
    n = item["normal"][:, item["mask"][0] > 0]
    torch.testing.assert_close(n.norm(dim=0), torch.ones(n.shape[1]), atol=1e-4, rtol=0)
