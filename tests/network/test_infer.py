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
    maps, mask = load_input(sample)
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
         str(tmp_path / "o2")], cwd=root, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.startswith("error:")
