"""network/demo/relight_compare.py: the truth as a map set, and the scores of relit frames."""

import numpy as np
import pytest

from network.demo.relight_compare import compare_relit, frame_scores, truth_maps


def _frame(value: float, cover: slice = slice(2, 6)) -> np.ndarray:
    f = np.zeros((8, 8, 4))
    f[cover, cover] = value, value, value, 1.0
    return f


def test_psnr_over_the_pixels_either_frame_covers():
    truth = _frame(0.5)
    assert frame_scores(truth, truth, lpips=False)["psnr"] > 100
    # 16 covered pixels off by 0.1 in every channel: MSE 0.01, 20 dB
    assert frame_scores(_frame(0.6), truth, lpips=False)["psnr"] == pytest.approx(20.0, abs=1e-9)
    # a prediction missing half the object is scored on the truth's pixels too: 8 of 16 pixels off by 0.5
    half = truth.copy()
    half[2:4] = 0.0
    assert frame_scores(half, truth, lpips=False)["psnr"] == pytest.approx(10 * np.log10(1 / (0.25 / 2)), abs=1e-9)
    # nothing covered: no score rather than a made-up one
    empty = np.zeros((8, 8, 4))
    assert frame_scores(empty, empty, lpips=False) == {"psnr": None, "lpips": None}
    with pytest.raises(ValueError, match="RGBA"):
        frame_scores(truth[..., :3], truth[..., :3])


def test_lpips_orders_a_small_and_a_large_error():
    truth = _frame(0.5, slice(0, 8))
    rng = np.random.default_rng(0)
    truth[..., :3] = rng.uniform(0.2, 0.8, (8, 8, 3))
    small, large = truth.copy(), truth.copy()
    small[..., :3] += 0.02
    large[..., :3] = 1.0 - large[..., :3]
    s, l_ = frame_scores(small, truth)["lpips"], frame_scores(large, truth)["lpips"]
    assert 0 <= s < l_


def test_frames_are_paired_by_name(tmp_path):
    from PIL import Image

    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        Image.fromarray((_frame(0.5) * 255).astype(np.uint8)).save(tmp_path / folder / "point_0001.png")
    (tmp_path / "b" / "point_0001.png").rename(tmp_path / "b" / "point_0002.png")
    with pytest.raises(ValueError, match="same frames"):
        compare_relit([tmp_path / "a" / "point_0001.png"], [tmp_path / "b" / "point_0002.png"], lpips=False)
    rows = compare_relit([tmp_path / "a" / "point_0001.png"], [tmp_path / "a" / "point_0001.png"], lpips=False)
    assert rows[0]["frame"] == "point_0001.png" and rows[0]["psnr"] > 100


def test_truth_maps_are_zero_outside_the_region_with_a_mask():
    gt = {"normal": np.ones((4, 4, 3)), "albedo": np.full((4, 4, 3), 0.5), "roughness": np.full((4, 4), 0.3),
          "metallic": np.zeros((4, 4, 1)), "depth": np.full((4, 4), 0.8)}  # fmt: skip
    region = np.zeros((4, 4), bool)
    region[1:3, 1:3] = True
    out = truth_maps(gt, region)
    assert set(out) == {"normal", "albedo", "roughness", "metallic", "depth", "mask"}
    assert all(v.ndim == 3 and v.dtype == np.float32 for v in out.values())
    assert out["roughness"][1, 1, 0] == pytest.approx(0.3) and out["roughness"][0, 0, 0] == 0
    assert out["mask"].sum() == 4 and out["depth"][~region].max() == 0
