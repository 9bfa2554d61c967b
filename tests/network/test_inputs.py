"""Input variants of the ablation: exactly the right maps are zeroed; normalisation commutes."""

import pytest
import torch

from network.data import normalize_maps
from network.inputs import INPUT_VARIANTS, apply_inputs, checkpoint_inputs


@pytest.fixture
def maps():
    g = torch.Generator().manual_seed(1)
    return torch.rand(2, 9, 5, 6, generator=g) + 0.1  # strictly positive: a zero can only come from masking


def test_variants_zero_exactly_the_right_maps(maps):
    unpol, lp, cp = maps[:, 0:3], maps[:, 3:6], maps[:, 6:9]
    full = apply_inputs(maps, "full")
    assert torch.equal(full, maps)
    polar = apply_inputs(maps, "polar")
    assert torch.equal(polar[:, :6], maps[:, :6]) and torch.all(polar[:, 6:] == 0)
    for v in ("spectral", "white"):  # intensity only: S0 = unpol + LP per colour
        x = apply_inputs(maps, v)
        assert torch.equal(x[:, 0:3], unpol + lp)
        assert torch.all(x[:, 3:] == 0)
    assert torch.all(cp != 0)  # the input itself was not modified in place
    assert torch.equal(maps[:, 3:6], lp)


def test_unbatched_and_leading_dims(maps):
    x = apply_inputs(maps[0], "polar")
    assert x.shape == (9, 5, 6) and torch.all(x[6:] == 0)
    y = apply_inputs(maps[None], "spectral")
    assert y.shape == (1, 2, 9, 5, 6) and torch.all(y[:, :, 3:] == 0)


@pytest.mark.parametrize("variant", INPUT_VARIANTS)
def test_commutes_with_normalisation(maps, variant):
    mask = torch.ones(2, 1, 5, 6)
    mask[0, 0, :2] = 0
    a = normalize_maps(apply_inputs(maps, variant), mask)
    b = apply_inputs(normalize_maps(maps, mask), variant)
    torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_errors_and_checkpoint_key(maps):
    assert INPUT_VARIANTS == ("white", "spectral", "polar", "full")
    with pytest.raises(ValueError, match="unknown input variant 'rgb'"):
        apply_inputs(maps, "rgb")
    with pytest.raises(ValueError, match=r"\(\.\.\., 9, H, W\)"):
        apply_inputs(maps[:, :6], "full")
    assert checkpoint_inputs({}) == "full"
    assert checkpoint_inputs({"inputs": "polar"}) == "polar"
    with pytest.raises(ValueError, match="unknown input variant"):
        checkpoint_inputs({"inputs": "cp"})


def test_white_data_comes_from_a_partial_rig_override():
    """'white' data is rendered with `--rig` = {"display": {"pattern": "white"}}: all channels lit everywhere."""
    rig = pytest.importorskip("pbrdf.sensor.rig")
    r = rig.Rig.from_dict({"display": {"pattern": "white"}})
    assert r.display.pattern == "white"
    img = r.display.pattern_image()
    assert img.min() == 1.0 and img.max() == 1.0
    default = rig.Rig().display.pattern_image()
    assert default.min() == 0.0  # the RGB halves pattern leaves regions dark per channel
