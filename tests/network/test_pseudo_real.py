"""The real-data branch on pseudo-real captures (issue 28 item 5): a jittered rig's raw brackets, read like real ones.

Checks that rendered samples with raw brackets go through the capture path (nominal rig, automatic
foreground after the dark frames of pbrdf/data/dark_frames.py), that nothing of their ground truth
reaches an item, and that a toy training run's real pass gives a finite, nonzero loss with the
scheduled weight.
"""

import csv
import hashlib
import json
import math
import shutil

import numpy as np
import pytest
import torch

from pbrdf.data import capture as pcapture
from pbrdf.data import capture_decode as pdecode
from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.data.dark_frames import add_dark_frames
from pbrdf.io import exr
from pbrdf.sensor.rig import Rig
from tests.helpers import toy_train_config

pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("torch_one_thread")]

GT_CHANNELS = ("normal", "albedo", "roughness", "metallic", "depth", "mask", "object")


@pytest.fixture(scope="module")
def pseudo_real(tmp_path_factory):
    """Three 64-px scenes through a rig jittered at 1.5, raw brackets kept (no dark frames yet)."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("pseudo") / "ds"
    cfg = GenerateConfig(out=root, count=3, resolution=64, spp=4, seed=11, keep_raw=True, rig_jitter=1.5)
    assert len(generate(cfg, progress=False).written) == 3
    return root


def _iou(a, b):
    return (a & b).sum() / max(1, (a | b).sum())


def test_dark_frames_give_back_the_object_under_ambient_light(pseudo_real, tmp_path):
    root = shutil.copytree(pseudo_real, tmp_path / "ds")
    paths = psample.sample_paths(root, 0)
    sample, meta = psample.read_sample(paths.sidecar, keys=("mask",))
    assert min(meta["spec"]["rig"]["camera"]["model"]["ambient"]) > 0  # the drawn rig has room light
    # Without dark frames the ambient light lifts the whole background above the noise floor.
    before = pdecode.decode_capture(pcapture.load_capture(paths.raw)).input_mask
    assert before.mean() > 0.9 > sample["mask"].mean() + 0.15
    calls = []
    assert add_dark_frames(root, progress=lambda done, total: calls.append((done, total))) == 3
    assert calls == [(1, 3), (2, 3), (3, 3)]
    assert add_dark_frames(root) == 0  # resumable: done captures are skipped
    cap = pcapture.load_capture(paths.raw)
    assert cap.dark is not None and Rig.from_dict(cap.metadata["rig"]) == Rig()  # decoded with the nominal rig
    after = pdecode.decode_capture(cap).input_mask
    assert _iou(after, sample["mask"]) > 0.85
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no raw captures"):
        add_dark_frames(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="not a folder"):
        add_dark_frames(tmp_path / "missing")


def _corrupt_ground_truth(root):
    """Scramble every ground-truth channel and drop the sidecars' scene keys (sidecars stay valid)."""
    rng = np.random.default_rng(0)
    for idx in sorted(pdataset.completed_indices(root)):
        paths = psample.sample_paths(root, idx)
        channels = exr.read_exr(paths.exr)
        for name in channels:
            if name.split(".")[0] in GT_CHANNELS:
                channels[name] = rng.random(channels[name].shape, dtype=np.float32)
        exr.write_exr(paths.exr, channels)
        meta = json.loads(paths.sidecar.read_text())
        for key in ("spec", "materials", "objects", "rig", "rig_jitter", "intrinsics", "camera_model"):
            meta.pop(key, None)
        meta["sha256"] = hashlib.sha256(paths.exr.read_bytes()).hexdigest()
        meta["exr_bytes"] = paths.exr.stat().st_size
        paths.sidecar.write_text(json.dumps(meta))
    assert len(pdataset.completed_indices(root)) == 3


def test_pseudo_real_items_never_read_the_ground_truth(pseudo_real, tmp_path):
    from network.realdata import RealDataset

    root = shutil.copytree(pseudo_real, tmp_path / "ds")
    add_dark_frames(root)
    ds = RealDataset(root, 32, patches=(4, 4), input_scale="calibrated")
    assert [p.name for p in ds.paths] == ["000000_raw", "000001_raw", "000002_raw"]  # the capture path
    items = [ds[i] for i in range(len(ds))]
    assert set(items[0]) == {"maps", "mask", "points", "patches", "intrinsics"}
    # No depth prior: every point on the fronto-parallel plane at the default distance.
    for item in items:
        z = item["points"][2][item["mask"][0] > 0]
        torch.testing.assert_close(z, torch.full_like(z, -ds.distance))
    _corrupt_ground_truth(root)
    again = RealDataset(root, 32, patches=(4, 4), input_scale="calibrated")
    for a, b in zip(items, (again[i] for i in range(len(again))), strict=True):
        for key in a:
            torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)


def test_real_branch_trains_on_pseudo_real_with_the_ramped_weight(pseudo_real, tmp_path):
    from network.train import train

    real = shutil.copytree(pseudo_real, tmp_path / "real")
    add_dark_frames(real)
    cfg = toy_train_config(
        pseudo_real, tmp_path / "run", steps=3, batch_size=2, real=real, real_weight=0.1, real_start=0, real_warmup=2
    )
    stats = {}
    losses = train(cfg, progress=False, stats=stats)
    assert len(losses) == 3 and stats["real_passes"] == 2  # the real pass is skipped at weight 0
    with open(tmp_path / "run" / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["real_weight"]) for r in rows] == [0.0, 0.05, 0.1]
    for r in rows[1:]:
        value = float(r["real"])
        assert math.isfinite(value) and 0.0 < value <= 1.0  # scale-invariant: 1 = nothing explained
        assert float(r["loss"]) == pytest.approx(float(r["synthetic"]) + float(r["real_weight"]) * value, rel=1e-6)
