"""network/constant.py: training means, their file, and the constant prediction."""

import json

import numpy as np
import pytest

from network import constant
from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample


def test_train_statistics_are_pixel_weighted_means(tiny_dataset, tmp_path):
    stats = constant.train_statistics(tiny_dataset)
    # Independent: pool every masked pixel of every sample, then average.
    pooled = {"albedo": [], "roughness": [], "metallic": []}
    for i in sorted(pdataset.completed_indices(tiny_dataset)):
        s, _ = psample.read_sample(tiny_dataset, i)
        for k in pooled:
            pooled[k].append(s[k][s["mask"]].astype(np.float64))
    np.testing.assert_allclose(stats["albedo"], np.concatenate(pooled["albedo"]).mean(0), rtol=1e-6)
    assert stats["roughness"] == pytest.approx(np.concatenate(pooled["roughness"]).mean(), rel=1e-6)
    assert stats["metallic"] == pytest.approx(np.concatenate(pooled["metallic"]).mean(), rel=1e-6, abs=1e-9)
    assert stats["samples"] == 3
    path = constant.save_statistics(stats, tmp_path / "s.json")
    assert constant.load_statistics(path) == stats


def test_statistics_refuse_a_test_split(tmp_path):
    (tmp_path / "samples").mkdir()
    (tmp_path / "manifest.json").write_text(json.dumps({"split": "test-procedural"}))
    with pytest.raises(ValueError, match="not 'test-procedural'"):
        constant.train_statistics(tmp_path)


def test_bad_statistics_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="--write-train-stats"):
        constant.load_statistics(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": constant.STATS_FORMAT, "albedo": [0.5, 2.0, 0.1], "roughness": 0.1,
                               "metallic": 0.0}))  # fmt: skip
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        constant.load_statistics(bad)


def test_constant_prediction():
    mask = np.zeros((3, 4), bool)
    mask[1, 1:3] = True
    pred = constant.constant_predict({"albedo": [0.1, 0.2, 0.3], "roughness": 0.5, "metallic": 0.25}, mask)
    np.testing.assert_array_equal(pred["normal"][1, 1], [0, 0, 1])
    np.testing.assert_allclose(pred["albedo"][1, 2], [0.1, 0.2, 0.3])
    assert pred["roughness"][1, 1, 0] == 0.5 and pred["metallic"][1, 2, 0] == 0.25
    assert not pred["normal"][~mask].any()
