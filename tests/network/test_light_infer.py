"""The light input through inference: predict() with a LightGeometry, and headless/infer.py --distance."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from network.checkpoint import CHECKPOINT_FORMAT, init_from_checkpoint, save_checkpoint
from network.config import get_config
from network.infer import load_input, predict
from network.light_input import LightGeometry
from network.model import PolarInverseModel
from pbrdf.data import sample as psample
from pbrdf.sensor import projection
from pbrdf.sensor.rig import Rig

ROOT = Path(__file__).resolve().parents[2]


pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py


def _maps(h: int = 24, w: int = 32):
    rng = np.random.default_rng(0)
    maps = rng.uniform(0.05, 1.0, (h, w, 9)).astype(np.float32)
    maps[..., 6:] -= 0.5
    mask = np.zeros((h, w), bool)
    mask[4:20, 6:26] = True
    return maps, mask


def _models(tmp_path):
    torch.manual_seed(0)
    blind = PolarInverseModel(get_config("toy")).eval()
    path = tmp_path / "blind.pt"
    save_checkpoint(path, {"format": CHECKPOINT_FORMAT, "config": blind.config.to_dict(), "model": blind.state_dict()})
    light = PolarInverseModel(get_config("toy", light_input=True)).eval()
    init_from_checkpoint(light, path)
    return blind, light


@pytest.mark.parametrize("resolution", ["full", "network"])
def test_predict_with_zero_light_weights_equals_the_blind_model(tmp_path, resolution):
    blind, light = _models(tmp_path)
    maps, mask = _maps()
    geo = LightGeometry(Rig(), projection.pinhole_intrinsics(40.0, 32, 24), 0.6)
    want = predict(blind, maps, mask, input_scale="calibrated", radiance=1.0, resolution=resolution)
    got = predict(light, maps, mask, input_scale="calibrated", radiance=1.0, resolution=resolution, light=geo)
    for k in ("normal", "albedo", "roughness", "metallic"):
        np.testing.assert_array_equal(got[k], want[k])
    with pytest.raises(ValueError, match="^light: a light_input model needs"):
        predict(light, maps, mask, input_scale="calibrated", radiance=1.0)
    with torch.no_grad():
        light.decoder.chi.weight.normal_(0, 0.5)
    near = predict(light, maps, mask, input_scale="calibrated", radiance=1.0, light=geo)
    far = predict(
        light, maps, mask, input_scale="calibrated", radiance=1.0, light=LightGeometry(Rig(), geo.intrinsics, 2.0)
    )
    assert np.abs(near["albedo"] - far["albedo"]).max() > 1e-4  # the distance now reaches the prediction
    assert all(np.isfinite(v).all() for v in near.values())


def test_light_geometry_resolves_the_fallback_with_a_warning():
    with pytest.warns(UserWarning, match="no object distance"):
        geo = LightGeometry.resolve(Rig(), np.eye(3), None, "capture.json", "cap")
    assert geo.to_dict() == {"distance_m": 0.75, "measured": False, "source": "default"}
    with pytest.raises(ValueError, match="^cap: distance_m must be a distance in metres within 0.2-3 m"):
        LightGeometry.resolve(Rig(), np.eye(3), 75.0, "capture.json", "cap")


def _sample(root: Path) -> Path:
    maps, mask = _maps()
    h, w = mask.shape
    normal = np.zeros((h, w, 3), np.float32)
    normal[mask, 2] = 1.0
    sample = {
        "maps": maps, "mask": mask, "normal": normal, "albedo": np.full((h, w, 3), 0.5, np.float32) * mask[..., None],
        "roughness": np.full((h, w), 0.5, np.float32) * mask, "metallic": np.zeros((h, w), np.float32),
        "depth": np.where(mask, 0.7, 0.0).astype(np.float32),
    }  # fmt: skip
    psample.write_sample(root, 0, sample, {"intrinsics": projection.pinhole_intrinsics(40.0, w, h).tolist()})
    return psample.sample_paths(root, 0).exr


def _infer(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "headless/infer.py", *args, "--quiet"]
    return subprocess.run(
        cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"}
    )


def test_headless_distance_flag_and_light_record(tmp_path):
    _, light = _models(tmp_path)
    ckpt = tmp_path / "light.pt"
    save_checkpoint(ckpt, {"format": CHECKPOINT_FORMAT, "config": light.config.to_dict(), "model": light.state_dict()})
    exr = _sample(tmp_path / "ds")
    assert load_input(exr).rig == Rig()
    proc = _infer("--checkpoint", str(ckpt), "--input", str(exr), "--out", str(tmp_path / "o"), "--distance", "0.9")
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / "o" / "000000_light.json").read_text())
    assert record == {"distance_m": 0.9, "measured": True, "source": "--distance"}
    assert json.loads((tmp_path / "o" / "000000_camera.json").read_text())["distance_m"] == 0.9
    proc = _infer("--checkpoint", str(ckpt), "--input", str(exr), "--out", str(tmp_path / "d"))
    assert proc.returncode == 0 and "warning:" in proc.stderr and "albedo is relative" in proc.stderr, proc.stderr
    assert json.loads((tmp_path / "d" / "000000_light.json").read_text())["measured"] is False
    proc = _infer("--checkpoint", str(ckpt), "--input", str(exr), "--out", str(tmp_path / "x"), "--distance", "90")
    assert proc.returncode == 2 and proc.stderr.startswith("error: --distance must be a distance in metres"), (
        proc.stderr
    )
    assert len(proc.stderr.splitlines()) == 1 and not (tmp_path / "x").exists()
