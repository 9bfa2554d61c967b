"""Data pipeline, losses and training: a toy model overfits rendered samples, resume is exact."""

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")

from network import data, losses  # noqa: E402
from network.train import TrainConfig, gather_pixels, train  # noqa: E402


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


def test_loss_matches_hand_computation_and_skips_zero_weights():
    pred = {"normal": torch.zeros(1, 3, 2), "albedo": torch.ones(1, 3, 2), "roughness": torch.zeros(1, 1, 2),
            "metallic": torch.zeros(1, 1, 2)}  # fmt: skip
    tgt = {"normal": torch.ones(1, 3, 2), "albedo": torch.ones(1, 3, 2) * 0.5, "roughness": torch.ones(1, 1, 2),
           "metallic": torch.zeros(1, 1, 2)}  # fmt: skip
    valid = torch.tensor([[[1.0, 0.0]]])
    w = losses.LossWeights(normal=1.0, albedo=2.0, roughness=1.0, metallic=0.0, chromaticity=0.0)
    loss, parts = losses.synthetic_loss(pred, tgt, valid, w)
    # normal: 3 * 1^2 = 3; albedo: 3 * 0.5^2 = 0.75 (x2); roughness: 1; one valid pixel.
    assert float(loss) == pytest.approx(3 + 2 * 0.75 + 1)
    assert set(parts) == {"normal", "albedo", "roughness"}


def test_gather_pixels():
    maps = torch.arange(2 * 3 * 4 * 5, dtype=torch.float32).reshape(2, 3, 4, 5)
    pix = torch.tensor([[0, 7], [19, 5]])
    g = gather_pixels(maps, pix)
    assert g.shape == (2, 3, 2)
    assert float(g[1, 2, 0]) == float(maps[1, 2, 3, 4]) and float(g[0, 1, 1]) == float(maps[0, 1, 1, 2])


def test_dataset_reads_samples(tiny_dataset):
    ds = data.SampleDataset(tiny_dataset, size=64)
    item = ds[0]
    assert item["maps"].shape == (9, 64, 64) and item["mask"].shape == (1, 64, 64)
    n = item["normal"][:, item["mask"][0] > 0]
    torch.testing.assert_close(n.norm(dim=0), torch.ones(n.shape[1]), atol=1e-4, rtol=0)


def test_toy_model_overfits_and_resume_is_exact(tiny_dataset, tmp_path):
    # decay_steps fixes the cosine horizon, so the 20-step "killed" run has the 40-step run's schedule.
    common = {"data": tiny_dataset, "config": "toy", "lr": 1e-3, "seed": 0, "checkpoint_every": 10, "decay_steps": 40}
    full = train(TrainConfig(out=tmp_path / "a", steps=40, **common), progress=False)
    assert len(full) == 40 and np.all(np.isfinite(full))
    assert np.mean(full[-5:]) < 0.5 * np.mean(full[:5])  # overfits three samples
    # Stop after 20 steps ("killed"), resume to 40: the same loss curve, value for value.
    train(TrainConfig(out=tmp_path / "b", steps=20, **common), progress=False)
    resumed = train(TrainConfig(out=tmp_path / "b", steps=40, resume=True, **common), progress=False)
    np.testing.assert_allclose(resumed, full, rtol=1e-6, atol=1e-7)
    with pytest.raises(FileExistsError, match="--resume"):
        train(TrainConfig(out=tmp_path / "b", steps=41, **common), progress=False)


def test_infer_on_sample_and_capture(tiny_dataset, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from network.config import get_config
    from network.infer import load_input, predict
    from network.model import PolarInverseModel
    from pbrdf.data import capture
    from pbrdf.io import exr
    from pbrdf.sensor import camera

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
