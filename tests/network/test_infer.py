"""Tests of network/infer.py: predictions at any size and stride, samples and capture folders, the CLI."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from network.config import get_config
from network.infer import load_input, predict
from network.model.polar_model import PolarInverseModel
from pbrdf.data import capture
from pbrdf.data.predictions import write_predictions
from pbrdf.io import exr
from pbrdf.sensor import camera
from tests.helpers import make_model

pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py

KEYS = ("normal", "albedo", "roughness", "metallic")


class TestPredict:
    def test_default_is_stride_one_and_stride_is_close(self):
        model = make_model()
        yy, xx = np.mgrid[0:90, 0:70]
        maps = np.stack([0.3 + 0.2 * np.sin(0.05 * yy + k) * np.cos(0.04 * xx - k) for k in range(9)], -1)
        maps = maps.astype(np.float32)
        mask = (yy - 45) ** 2 + (xx - 35) ** 2 < 30**2
        default = predict(model, maps, mask)
        one = predict(model, maps, mask, stride=1)
        two = predict(model, maps, mask, stride=2)
        for key in KEYS:
            np.testing.assert_array_equal(default[key], one[key])
            assert np.isfinite(two[key]).all() and two[key].shape == one[key].shape
        norms = np.linalg.norm(two["normal"][mask], axis=-1)
        np.testing.assert_allclose(norms, 1.0, atol=1e-5)
        angle = np.degrees(np.arccos(np.clip(np.sum(one["normal"] * two["normal"], -1), -1, 1)))[mask]
        assert angle.mean() < 1.0


@pytest.mark.mitsuba
def test_infer_on_sample_and_capture(tiny_dataset, tmp_path):
    root = Path(__file__).resolve().parents[2]
    torch.manual_seed(0)
    model = PolarInverseModel(get_config("toy"))
    ckpt = tmp_path / "model.pt"
    torch.save({"config": model.config.to_dict(), "model": model.state_dict()}, ckpt)
    sample = tiny_dataset / "samples" / "000000.exr"
    inp = load_input(sample)
    maps, mask = inp.maps, inp.mask
    pred = predict(model, maps, mask)
    assert pred["normal"].shape == (*mask.shape, 3) and pred["roughness"].shape == (*mask.shape, 1)
    assert np.all(pred["albedo"][~mask] == 0)
    np.testing.assert_allclose(np.linalg.norm(pred["normal"][mask], axis=-1), 1.0, atol=1e-4)
    # A capture folder goes through the decoder (any size; here 48 x 64 raw -> 24 x 32 maps).
    s = np.zeros((48, 64, 3, 4))
    s[12:36, 16:48, :, 0] = 0.3
    s[12:36, 16:48, :, 1] = -0.1
    m = camera.CameraModel()
    cap = capture.save_capture(tmp_path / "cap", camera.simulate_capture(s, m, rng=np.random.default_rng(0)), m)
    cmd = [sys.executable, "headless/infer.py", "--checkpoint", str(ckpt), "--input", str(cap)]
    proc = subprocess.run([*cmd, "--out", str(tmp_path / "o")], cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    normal = exr.read_exr(tmp_path / "o" / "cap_normal.exr")
    assert normal["normal.X"].shape == (24, 32)
    assert (tmp_path / "o" / "cap_albedo.png").is_file()
    bad = subprocess.run(
        [sys.executable, "headless/infer.py", "--checkpoint", str(ckpt), "--input", str(tmp_path / "nope"), "--out",
         str(tmp_path / "o2"), "--quiet"], cwd=root, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.startswith("error:")


# ----------------------------------------------------------------------------------------------------------
# Hardening: ranges, non-finite outputs, nothing written on failure, nothing to reconstruct


def _maps_and_mask(h: int = 40, w: int = 36) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:h, 0:w]
    maps = np.stack([0.3 + 0.2 * np.sin(0.07 * yy + k) * np.cos(0.05 * xx - k) for k in range(9)], -1)
    maps[..., 6:] -= 0.3  # CP in [-0.2, 0.2]
    mask = (yy - h / 2) ** 2 + (xx - w / 2) ** 2 < (h / 3) ** 2
    return maps.astype(np.float32), mask


def _nan_model():
    model = make_model()
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(float("nan"))
    return model


class TestPredictRanges:
    @pytest.mark.parametrize(("dtype", "peak"), [(np.float32, 3e38), (np.float64, 1e300)])
    def test_huge_radiance_predicts_as_at_unit_scale(self, dtype, peak):
        # 3e38 radiance maps overflowed the float32 sums of the normalisation (NaN albedo, a traceback after
        # _normal.exr was written); they are scaled down by a power of two first, which changes nothing else.
        model = make_model()
        maps, mask = _maps_and_mask()
        huge = maps.astype(dtype)
        huge[..., :6] = (huge[..., :6] * (peak / np.abs(maps[..., :6]).max())).astype(dtype)
        assert np.isfinite(huge).all() and np.abs(huge).max() > peak / 3
        ref, got = predict(model, maps, mask), predict(model, huge, mask)
        for key in KEYS:
            assert np.isfinite(got[key]).all()
            np.testing.assert_allclose(got[key], ref[key], rtol=1e-5, atol=1e-5, err_msg=key)

    @pytest.mark.parametrize(
        ("edit", "match"),
        [
            (lambda m, k: m.__setitem__((..., 6), 3e38), r"CP maps .* must lie in \[-1, 1\]; got \|CP\| up to 3e\+38"),
            (lambda m, k: m.__setitem__((..., 8), -1.5), r"got \|CP\| up to 1.5"),
            (lambda m, k: m.__setitem__(k, 0.0), "maps are zero on every mask pixel"),
            (lambda m, k: m.__setitem__((0, 0, 0), np.inf), "NaN or Inf"),
            (lambda m, k: k.__setitem__(..., False), "the mask is empty"),
        ],
        ids=["CP 3e38", "CP -1.5", "zero maps", "Inf", "empty mask"],
    )
    def test_bad_maps_are_refused(self, edit, match):
        maps, mask = _maps_and_mask()
        edit(maps, mask)
        with pytest.raises(ValueError, match=match):
            predict(make_model(), maps, mask)

    def test_cp_rounding_slack_is_accepted(self):
        maps, mask = _maps_and_mask()
        maps[0, 0, 6] = 1.0005
        assert np.isfinite(predict(make_model(), maps, mask)["albedo"]).all()

    def test_non_finite_network_output_is_an_error(self):
        maps, mask = _maps_and_mask()
        with pytest.raises(ValueError, match="the network predicted NaN or Inf (normal|albedo)"):
            predict(_nan_model(), maps, mask)


class TestWritePredictions:
    def _pred(self):
        maps, mask = _maps_and_mask(16, 16)
        return predict(make_model(), maps, mask)

    def test_writes_every_map(self, tmp_path):
        paths = write_predictions(tmp_path / "o" / "deep", "x", self._pred())
        names = sorted(p.name for p in paths)
        assert names == sorted(f"x_{k}.{ext}" for k in (*KEYS, "mask") for ext in ("exr", "png"))
        assert sorted(p.name for p in (tmp_path / "o" / "deep").iterdir()) == names  # no temporary folder left

    def test_nan_map_writes_nothing(self, tmp_path):
        pred = self._pred()
        pred["albedo"][3, 3, 0] = np.nan  # the third map: _normal.exr/.png used to be written already
        with pytest.raises(ValueError, match="predicted albedo map is not a finite"):
            write_predictions(tmp_path / "o", "x", pred)
        assert not (tmp_path / "o").exists()

    @pytest.mark.parametrize("existing", [False, True])
    def test_write_failure_leaves_nothing(self, tmp_path, monkeypatch, existing):
        out = tmp_path / "o"
        if existing:
            out.mkdir()
            (out / "keep.txt").write_text("x")
        calls = []
        write_exr = exr.write_exr

        def failing(path, channels, **kw):
            calls.append(path)
            if len(calls) == 3:
                raise OSError("disk full (simulated)")
            return write_exr(path, channels, **kw)

        monkeypatch.setattr(exr, "write_exr", failing)  # write_predictions imports it when it runs
        with pytest.raises(OSError, match="disk full"):
            write_predictions(out, "x", self._pred())
        if existing:
            assert [p.name for p in out.iterdir()] == ["keep.txt"]
        else:
            assert not out.exists()


class TestLoadInputRequireObject:
    def test_dark_capture(self, tmp_path):
        m = camera.CameraModel()
        folder = capture.save_capture(tmp_path / "dark", np.full((4, 32, 32), 16, np.uint16), m)
        mask = load_input(folder).mask  # the library call still returns (network.evaluation scores such scenes)
        assert not mask.any()
        with pytest.raises(ValueError, match=f"{folder}: nothing usable: every raw value is at or below black_level"):
            load_input(folder, require_object=True)

    def test_noise_only_capture(self, tmp_path):
        m = camera.CameraModel()
        raws = camera.simulate_capture(np.zeros((32, 32, 3, 4)), m, rng=np.random.default_rng(0))
        folder = capture.save_capture(tmp_path / "noise", raws, m)
        with pytest.raises(ValueError, match=f"{folder}: nothing to reconstruct: no object stands out"):
            load_input(folder, require_object=True)

    def test_sample_with_empty_mask(self, tmp_path, rng):
        from pbrdf.data import sample as psample
        from tests.helpers import make_sample

        sample, meta = make_sample(rng)
        for key in ("mask", "normal", "depth"):
            sample[key][:] = 0  # the ground truth is 0 outside the (now empty) mask
        psample.write_sample(tmp_path, 0, sample, meta)
        path = psample.sample_paths(tmp_path, 0).exr
        with pytest.raises(ValueError, match="the sample's mask is empty: nothing to reconstruct"):
            load_input(path, require_object=True)


# ----------------------------------------------------------------------------------------------------------
# Input scale: calibrated checkpoints read the display radiance, relative captures fall back


def test_calibrated_predict_reads_the_radiance_and_huge_maps_scale_with_it():
    model = make_model()
    maps, mask = _maps_and_mask()
    one = predict(model, maps, mask, input_scale="calibrated", radiance=1.0)
    two = predict(model, maps, mask, input_scale="calibrated", radiance=2.0)
    assert not np.allclose(one["albedo"], two["albedo"])  # the network sees absolute brightness
    # Radiance units scaled by 2^70 (past the float32-safe peak) with the radiance alike: the same input.
    big = maps.astype(np.float64)
    big[..., :6] *= 2.0**70
    same = predict(model, big, mask, input_scale="calibrated", radiance=2.0**70)
    for key in KEYS:
        np.testing.assert_allclose(same[key], one[key], rtol=1e-5, atol=1e-6)
    # An exposure-invariant checkpoint ignores the radiance.
    inv = predict(model, maps, mask, radiance=2.0)
    np.testing.assert_array_equal(inv["albedo"], predict(model, maps, mask)["albedo"])


def test_relative_capture_falls_back_with_one_warning(tmp_path):
    root = Path(__file__).resolve().parents[2]
    torch.manual_seed(0)
    model = PolarInverseModel(get_config("toy"))
    ckpt = tmp_path / "model.pt"
    torch.save({"config": model.config.to_dict(), "model": model.state_dict(), "input_scale": "calibrated"}, ckpt)
    s = np.zeros((48, 64, 3, 4))
    s[12:36, 16:48, :, 0] = 0.3
    s[12:36, 16:48, :, 1] = -0.1
    m = camera.CameraModel()
    raws = camera.simulate_capture(s, m, rng=np.random.default_rng(0))
    rel = capture.save_capture(tmp_path / "rel", raws, m, extra={"radiometry": "relative"})
    assert capture.read_capture_meta(rel).radiance is None
    cmd = [
        sys.executable,
        "headless/infer.py",
        "--checkpoint",
        str(ckpt),
        "--input",
        str(rel),
        "--out",
        str(tmp_path / "o"),
    ]
    proc = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("warning:") == 1 and "albedo is relative" in proc.stderr
    inp = load_input(rel)
    maps, mask = inp.maps, inp.mask
    want = predict(model, maps, mask)  # the exposure-invariant scale
    got = exr.read_exr(tmp_path / "o" / "rel_albedo.exr")
    np.testing.assert_allclose(got["albedo.R"], want["albedo"][..., 0], rtol=1e-5, atol=1e-6)
    bad = capture.save_capture(tmp_path / "bad", raws, m, extra={"radiometry": "absolute"})
    proc = subprocess.run([*cmd[:5], str(bad), "--out", str(tmp_path / "o2"), "--quiet"], cwd=root,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "radiometry must be one of" in proc.stderr
    assert not (tmp_path / "o2").exists()


class TestResolution:
    def test_full_equals_network_when_the_crop_is_the_input_size(self):
        """Full-frame mask of exactly the input size: both routes decode the same pixels the same way."""
        model = make_model()
        size = model.config.image_size
        yy, xx = np.mgrid[0:size, 0:size]
        maps = np.stack([0.3 + 0.2 * np.sin(0.11 * yy + k) * np.cos(0.07 * xx - k) for k in range(9)], -1)
        maps = maps.astype(np.float32)
        mask = np.ones((size, size), bool)
        full = predict(model, maps, mask, resolution="full")
        net = predict(model, maps, mask, resolution="network")
        for key in KEYS:
            np.testing.assert_allclose(full[key], net[key], atol=2e-4)
        with pytest.raises(ValueError, match="resolution must be one of full, network"):
            predict(model, maps, mask, resolution="half")

    def test_shipped_model_at_twice_the_capture_resolution(self):
        """examples/capture upsampled 2x: full-resolution maps at 2x match the 1x ones and the truth."""
        from network.checkpoint import load_checkpoint
        from network.infer import DEFAULT_CHECKPOINT

        root = Path(__file__).resolve().parents[2]
        model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
        inp = load_input(root / "examples" / "capture")
        maps, mask, radiance = inp.maps, inp.mask, inp.radiance
        kw = {"inputs": ckpt["inputs"], "input_scale": ckpt["input_scale"], "radiance": radiance}
        one = predict(model, maps, mask, **kw)
        up = predict(model, maps.repeat(2, 0).repeat(2, 1), mask.repeat(2, 0).repeat(2, 1), **kw)
        assert up["normal"].shape == (2 * mask.shape[0], 2 * mask.shape[1], 3)
        truth = np.load(root / "examples" / "capture_truth.npz")
        inside = mask & truth["mask"].astype(bool)

        def angles(a, b):
            return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1, 1)))[inside]

        sub = up["normal"][::2, ::2]  # the top-left copy of each pixel
        assert np.median(angles(sub, one["normal"])) < 2.0
        mae_one, mae_up = angles(one["normal"], truth["normal"]).mean(), angles(sub, truth["normal"]).mean()
        assert abs(mae_up - mae_one) < 1.0 and mae_up < 20.0, (mae_one, mae_up)  # 16.5 deg at 1x (2026-11-24)
