"""Tests of network/data.py: input normalisation, pixel gathers, the dataset reader."""

import numpy as np
import pytest
import torch

from network import data
from network.data import normalize_maps


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


# --- extreme inputs of the normalisation ---------------------------------------------------------

DTYPES = [torch.float32, torch.bfloat16, torch.float16]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("value", [1e-6, 1.0, 6e4, 3e38])
def test_normalize_maps_uniform_maps_give_one_sixth(dtype, value):
    # Hand value: six equal unpol/LP channels v at every pixel give a total 6 v, which becomes 1,
    # so every channel is 1/6, for any v above the scale floor (1e-8). 3e38 used to overflow the
    # float32 sum (inf / inf = NaN); in float16 it is the dtype's largest value 65504.
    # bfloat16 and float16 used to raise (torch.quantile needs float32).
    maps = torch.full((1, 9, 4, 5), min(value, torch.finfo(dtype).max), dtype=dtype)
    maps[:, 6:] = 0.5
    mask = torch.ones(1, 1, 4, 5, dtype=dtype)
    out = data.normalize_maps(maps, mask)
    assert out.dtype == dtype and torch.isfinite(out).all()
    tol = 1e-6 if dtype == torch.float32 else 1e-2
    torch.testing.assert_close(out[:, :6].float(), torch.full((1, 6, 4, 5), 1 / 6), atol=tol, rtol=0)
    torch.testing.assert_close(out[:, 6:].float(), torch.full((1, 3, 4, 5), 0.5))


@pytest.mark.parametrize("dtype", DTYPES)
def test_normalize_maps_extreme_cases_stay_finite(dtype):
    g = torch.Generator().manual_seed(0)
    top = torch.finfo(dtype).max
    base = torch.rand(6, 9, 8, 8, generator=g).to(dtype)
    mask = torch.ones(6, 1, 8, 8, dtype=dtype)
    base[0] = 0.0  # all dark: the quantile is 0, the scale its floor, the output 0
    base[1, :6] = top  # saturated everywhere
    base[2, :, 0, 0] = top  # one saturated pixel among dark ones: clamped to MAP_LIMIT
    base[2, :, 1:, :] = 0.0
    base[3, :6, 0, 0] = -top  # negative extremes too
    mask[4] = 0.0  # empty mask: all 0
    mask[5] = 0.0
    mask[5, :, 3, 3] = 1.0  # a single pixel: its unpol + LP total becomes 1
    out = data.normalize_maps(base, mask)
    assert out.dtype == dtype and torch.isfinite(out).all()
    assert out.abs().max() <= data.MAP_LIMIT
    assert torch.all(out[0] == 0) and torch.all(out[4] == 0)
    torch.testing.assert_close(out[1, :6].float(), torch.full((6, 8, 8), 1 / 6), atol=1e-2, rtol=0)
    assert float(out[2, 0, 0, 0]) == pytest.approx(data.MAP_LIMIT, rel=1e-2)  # bfloat16: 9984
    assert float(out[5, :6, 3, 3].float().sum()) == pytest.approx(1.0, abs=2e-2)
    assert torch.all(out[5][:, mask[5, 0] == 0] == 0)


def test_normalize_maps_lets_nan_through_for_the_training_guard():
    # NaN input is not hidden (network.train skips batches with non-finite inputs); the other
    # images of the batch are unaffected.
    maps = torch.rand(2, 9, 4, 4)
    maps[1, 0, 2, 2] = float("nan")
    out = data.normalize_maps(maps, torch.ones(2, 1, 4, 4))
    assert torch.isfinite(out[0]).all() and torch.isnan(out[1]).any()


# --- validation of the loaded items ------------------------------------------------------------


def _forge(root, index, key, fn):
    """Rewrite a sample's ``key`` channels with ``fn(array)`` and re-sign the sidecar (sha256, size),
    as a buggy writer would: the hash matches, the contents are wrong."""
    import hashlib
    import json

    from pbrdf.data import sample as psample
    from pbrdf.io.exr import read_exr, write_exr

    paths = psample.sample_paths(root, index)
    channels = read_exr(paths.exr)
    names = psample.CHANNELS[key]
    arr = fn(np.stack([channels[n] for n in names], axis=-1))
    for k, n in enumerate(names):
        channels[n] = np.ascontiguousarray(arr[..., k])
    write_exr(paths.exr, channels, allow_nonfinite=True)
    meta = json.loads(paths.sidecar.read_text())
    meta["sha256"] = hashlib.sha256(paths.exr.read_bytes()).hexdigest()
    meta["exr_bytes"] = paths.exr.stat().st_size
    paths.sidecar.write_text(json.dumps(meta))
    return paths.exr


@pytest.fixture
def small_dataset(tmp_path):
    from pbrdf.data import sample as psample
    from tests.helpers import make_sample

    rng = np.random.default_rng(5)
    for i in range(2):
        sample, meta = make_sample(rng)
        psample.write_sample(tmp_path, i, sample, meta)
    return tmp_path


def test_dataset_reads_valid_small_samples(small_dataset):
    ds = data.SampleDataset(small_dataset)
    assert len(ds) == 2 and ds[1]["maps"].shape == (9, 4, 6)


def _zero_normals_in_mask(a):
    a = a.copy()
    a[0, 0] = 0.0  # make_sample puts pixel (0, 0) inside the mask
    return a


def _empty_mask(a):
    return np.zeros_like(a)


@pytest.mark.parametrize(
    ("key", "fn", "message"),
    [
        ("roughness", lambda a: np.full_like(a, 7.0), r"roughness values must be in \[0, 1\]; got \[7, 7\]"),
        ("albedo", lambda a: a - 2.0, r"albedo values must be in \[0, 1\]"),
        ("metallic", lambda a: np.full_like(a, np.nan), r"metallic holds non-finite values"),
        ("normal", _zero_normals_in_mask, r"normal must be unit vectors inside the mask .* at \(row 0, col 0\)"),
        ("mask", _empty_mask, r"mask is empty"),
    ],
)
def test_dataset_refuses_bad_items_with_matching_hash(small_dataset, key, fn, message):
    exr = _forge(small_dataset, 1, key, fn)
    ds = data.SampleDataset(small_dataset)
    assert len(ds) == 2  # the forged sample still counts as complete: its hash matches
    ds[0]  # the good one loads
    with pytest.raises(ValueError, match=message) as err:
        ds[1]
    assert str(err.value).startswith(f"{exr}: ") and "\n" not in str(err.value)


# ------------------------------------------------------------------------------------------------
# calibrated input scale


def _decoded_maps(stokes, exposures):
    """Noise-free raws of ``stokes`` for an exposure bracket, decoded: what a capture folder gives."""
    from pbrdf.sensor.camera import CameraModel, simulate_capture
    from pbrdf.sensor.decode import decode

    model = CameraModel(exposures=exposures)
    dec = decode(simulate_capture(stokes, model, noise=False), model)
    return torch.from_numpy(np.ascontiguousarray(dec.maps.transpose(2, 0, 1)))[None], dec.mask


def test_calibrated_input_is_exposure_independent_and_keeps_absolute_brightness():
    """Physics: the decoder divides by exposure, so only the scene's radiance reaches the network.

    A uniformly lit diffuse patch (unpolarized, radiance 0.2 display radiances) captured with two
    different brackets gives the same calibrated input, and the same patch at half the albedo gives
    half of it; the exposure-invariant scale maps both albedos to the same input.
    """
    from network.data import CALIBRATED_GAIN

    stokes = np.zeros((16, 16, 3, 4))
    stokes[..., 0] = [0.2, 0.15, 0.1]  # S0 per colour; s1 = s2 = s3 = 0: unpolarized, all "unpol"
    a, mask = _decoded_maps(stokes, (0.01, 0.02, 0.1, 0.2))
    b, _ = _decoded_maps(stokes, (0.004, 0.05))
    half, _ = _decoded_maps(stokes * 0.5, (0.01, 0.02, 0.1, 0.2))
    k = torch.from_numpy(mask.astype(np.float32))[None, None]
    cal = {n: normalize_maps(x, k, radiance=1.0)[0, :, mask] for n, x in (("a", a), ("b", b), ("half", half))}
    # unpol maps = CALIBRATED_GAIN x the patch's radiance per colour, to the 12-bit quantisation
    np.testing.assert_allclose(cal["a"][:3].mean(1), CALIBRATED_GAIN * np.array([0.2, 0.15, 0.1]), rtol=2e-3)
    np.testing.assert_allclose(cal["b"][:6], cal["a"][:6], rtol=5e-3, atol=1e-3)
    np.testing.assert_allclose(cal["half"][:3], 0.5 * cal["a"][:3], rtol=5e-3)
    # A display twice as bright (radiance 2 in the same units) halves the input as well.
    np.testing.assert_allclose(normalize_maps(a, k, radiance=2.0)[0, :3, mask], 0.5 * cal["a"][:3], rtol=1e-6)
    inv = {n: normalize_maps(x, k)[0, :, mask] for n, x in (("a", a), ("half", half))}
    np.testing.assert_allclose(inv["half"][:3], inv["a"][:3], rtol=5e-3)  # albedo lost


def test_calibrated_normalisation_rejects_bad_radiance_and_stays_finite():
    maps, mask = torch.ones(2, 9, 4, 4), torch.ones(2, 1, 4, 4)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="radiance must be positive and finite"):
            normalize_maps(maps, mask, radiance=bad)
    # One radiance per image of a batch.
    out = normalize_maps(maps, mask, radiance=torch.tensor([1.0, 3.5]))
    assert out[0, 0, 0, 0].item() == pytest.approx(3.5) and out[1, 0, 0, 0].item() == pytest.approx(1.0)
    # Values near the float limits are clamped, never NaN; a half-precision result stays finite.
    huge = torch.full((1, 9, 2, 2), 3e38)
    for dtype in (torch.float32, torch.float16, torch.bfloat16):
        x = normalize_maps(huge.clamp(max=torch.finfo(dtype).max).to(dtype), torch.ones(1, 1, 2, 2), radiance=1e-30)
        assert torch.isfinite(x).all() and x.dtype == dtype


def test_input_radiance_falls_back_for_relative_captures():
    from network.data import checkpoint_input_scale, input_radiance

    assert input_radiance("calibrated", 2.0) == 2.0
    assert input_radiance("exposure-invariant", 2.0) is None
    with pytest.warns(UserWarning, match="albedo is relative"):
        assert input_radiance("calibrated", None, "cap") is None
    with pytest.raises(ValueError, match="unknown input scale"):
        input_radiance("absolute", 1.0)
    assert checkpoint_input_scale({}) == "exposure-invariant"  # files from before calibrated input
    with pytest.raises(ValueError, match="unknown input_scale"):
        checkpoint_input_scale({"input_scale": "linear"})


@pytest.mark.mitsuba
def test_rendered_training_maps_and_decoded_raws_share_units(tmp_path):
    """The training data and the capture path must put the same number on the same radiance."""
    from blender_addon.core.generate import GenerateConfig, generate
    from network.infer import load_input
    from pbrdf.data import sample as psample

    root = tmp_path / "ds"
    generate(GenerateConfig(out=root, count=1, resolution=64, spp=8, seed=3, keep_raw=True), progress=False)
    sample, meta = psample.read_sample(root, 0, keys=("maps", "mask"))
    raw = psample.sample_paths(root, 0).raw
    inp = load_input(raw)
    decoded, auto = inp.maps, inp.mask
    assert inp.radiance == meta["rig"]["display"]["radiance"] == 1.0
    # The capture carries the crop's calibration: load_input gives back the maps' intrinsics.
    np.testing.assert_allclose(inp.intrinsics, meta["intrinsics"], rtol=1e-12)
    inside = sample["mask"].astype(bool) & auto
    ratio = decoded[..., :6].sum(-1)[inside].sum() / sample["maps"][..., :6].sum(-1)[inside].sum()
    assert ratio == pytest.approx(1.0, abs=0.03)  # camera noise and demosaicking only
