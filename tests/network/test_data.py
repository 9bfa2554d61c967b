"""Tests of network/data.py: input normalisation, pixel gathers, the dataset reader."""

import pytest
import torch

from network import data


def test_normalize_maps_is_scale_invariant_and_keeps_cp():
    g = torch.Generator().manual_seed(0)
    maps = torch.rand(2, 9, 8, 8, generator=g)
    mask = (torch.rand(2, 1, 8, 8, generator=g) > 0.3).float()
    a = data.normalize_maps(maps, mask)
    # The 0.95 quantile of the masked unpol + LP total (over colours) becomes 1, per image.
    for i in range(2):
        total = a[i, :6].sum(0)[mask[i, 0] > 0]
        assert float(torch.quantile(total, 0.95)) == pytest.approx(1.0, abs=1e-5)
    scaled = maps.clone()
    scaled[0, :6] *= 37.0  # brighter display / longer exposure of image 0 only: same normalised input
    scaled[:, 6:] *= 2.0  # CP is kept as is: twice the CP in, twice the CP out
    c = data.normalize_maps(scaled, mask)
    torch.testing.assert_close(c[:, :6], a[:, :6], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(c[:, 6:], 2.0 * a[:, 6:])
    torch.testing.assert_close(a[:, 6:], maps[:, 6:] * mask)
    # One scale for all six unpol/LP channels of an image: brightening unpol alone triples the unpol/LP ratio.
    uneven = maps.clone()
    uneven[:, :3] *= 3.0
    d = data.normalize_maps(uneven, mask)
    inside = mask[0, 0] > 0
    torch.testing.assert_close(
        d[0, :3, inside] / d[0, 3:6, inside].mean(), 3.0 * a[0, :3, inside] / a[0, 3:6, inside].mean()
    )
    assert not torch.allclose(d[:, :6], a[:, :6], atol=1e-3)
    assert torch.all(a[0][:, mask[0, 0] == 0] == 0) and torch.all(a[1][:, mask[1, 0] == 0] == 0)


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
