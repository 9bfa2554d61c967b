"""The shipped checkpoint: small enough to commit, loads, and beats photometric stereo on normals."""

import numpy as np
import pytest
import torch

from network.checkpoint import load_checkpoint
from network.infer import DEFAULT_CHECKPOINT, predict


@pytest.fixture(scope="module")
def fixed_set(tmp_path_factory):
    """Three scenes never seen in training (the shipped model trained on seed 100)."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("heldout")
    generate(GenerateConfig(out=root, count=3, resolution=64, spp=8, seed=4242), progress=False)
    return root


def test_checkpoint_is_small_and_loads():
    assert DEFAULT_CHECKPOINT.is_file(), "models/small/model.pt is missing (make ship-engine-model)"
    assert DEFAULT_CHECKPOINT.stat().st_size <= 20 * 2**20
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    assert set(ckpt) >= {"config", "model"}
    assert not model.training
    assert all(torch.isfinite(p).all() for p in model.parameters())


@pytest.mark.slow
@pytest.mark.mitsuba
def test_shipped_model_beats_photometric_stereo(fixed_set):
    from network.constant import STATS_FILE, load_statistics
    from network.evaluation import evaluate_dataset

    torch.set_num_threads(2)
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    stats = load_statistics(DEFAULT_CHECKPOINT.parent / STATS_FILE)
    result = evaluate_dataset(model, ckpt, fixed_set, stats, lpips=False)
    ours = result["methods"]["ours"]["normal_mae"]["weighted_mean"]
    baseline = result["methods"]["baseline"]["normal_mae"]["weighted_mean"]
    assert np.isfinite(ours) and np.isfinite(baseline)
    assert ours < baseline, (ours, baseline)


def test_predict_covers_thin_mask_parts():
    """Mask pixels lost by the network's downsampling still get unit normals (nearest-valid fill)."""
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    rng = np.random.default_rng(0)
    h, w = 200, 200
    mask = np.zeros((h, w), bool)
    mask[60:140, 60:140] = True
    mask[20:180, 100] = True  # a one-pixel line: vanishes at the network's input size
    maps = (rng.random((h, w, 9)) * mask[..., None]).astype(np.float32)
    maps[..., 6:] -= 0.5 * mask[..., None]
    pred = predict(model, maps, mask, inputs=ckpt.get("inputs", "full"))
    norms = np.linalg.norm(pred["normal"][mask], axis=-1)
    np.testing.assert_allclose(norms, 1.0, atol=1e-4)
    assert np.all(pred["normal"][~mask] == 0)
    for key in ("albedo", "roughness", "metallic"):
        assert np.all(np.isfinite(pred[key])) and pred[key][mask].min() >= 0 and pred[key][mask].max() <= 1
