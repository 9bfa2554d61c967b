"""Tests of the automatic object mask (pbrdf.sensor.foreground).

Expected masks come from the scenes themselves (the disc drawn into the Stokes images, the ground
truth of examples/capture written by tools/make_example_capture.py), and the noise floor from the
empirical spread of decoded dark captures; never from earlier runs of the code.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from pbrdf.data import capture as pcapture
from pbrdf.data import capture_decode as pdecode_capture
from pbrdf.sensor import foreground as fg
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.decode import decode
from tests.helpers import disc_stokes

REPO = Path(__file__).resolve().parents[3]
EXAMPLE = REPO / "examples" / "capture"
EXAMPLE_TRUTH = REPO / "examples" / "capture_truth.npz"


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def _disc_truth(h: int, w: int, radius: float) -> np.ndarray:
    """The disc on the half grid: half-grid pixel k sits at raw coordinate 2k + 0.5."""
    y, x = np.mgrid[0 : h // 2, 0 : w // 2] * 2 + 0.5
    return np.hypot(y - h / 2, x - w / 2) < radius


# --------------------------------------------------------------------------------------------
# Noise floor


class TestNoiseFloor:
    @pytest.mark.parametrize("grid", ["half", "full"])
    def test_matches_the_spread_of_a_dark_capture(self, rng, grid):
        model = CameraModel()
        raws = simulate_capture(np.zeros((256, 256, 3, 4)), model, rng=rng)
        signal = fg.capture_signal(decode(raws, model, grid=grid).stokes)
        interior = signal[8:-8, 8:-8]  # away from the border, where the demosaic repeats samples
        assert interior.std() == pytest.approx(fg.noise_floor(model, grid=grid), rel=0.05)
        assert abs(interior.mean()) < 0.1 * interior.std()

    def test_scales_with_read_noise_and_exposure(self):
        base = CameraModel()
        noisy = base.replace(sensor=base.sensor.__class__(read_noise=2 * base.sensor.read_noise))
        longer = base.replace(exposures=tuple(2 * t for t in base.exposures))
        assert fg.noise_floor(noisy) > 1.9 * fg.noise_floor(base)
        assert fg.noise_floor(longer) == pytest.approx(fg.noise_floor(base) / 2)

    def test_bad_grid(self):
        with pytest.raises(ValueError, match="grid must be"):
            fg.noise_floor(CameraModel(), grid="quarter")


class TestBackgroundLevel:
    def test_level_and_noise_of_a_shifted_background(self, rng):
        img = rng.normal(5.0, 2.0, (256, 256))
        img[64:192, 64:192] += 1000.0  # the object is outside the candidate window
        level, noise = fg.background_level(img, 1.0)
        assert level == pytest.approx(5.0, abs=0.1)
        assert noise == pytest.approx(2.0, rel=0.05)

    def test_noise_never_below_the_model(self, rng):
        assert fg.background_level(rng.normal(0.0, 0.5, (128, 128)), 1.0)[1] == 1.0

    def test_no_background_falls_back_to_the_model(self):
        assert fg.background_level(np.full((64, 64), 50.0), 1.0) == (0.0, 1.0)

    def test_bad_sigma(self):
        with pytest.raises(ValueError, match="sigma must be positive"):
            fg.background_level(np.zeros((8, 8)), 0.0)


# --------------------------------------------------------------------------------------------
# The mask on images


class TestForegroundMask:
    def test_blurred_square_with_a_dark_hole(self, rng):
        truth = np.zeros((96, 96), bool)
        truth[24:72, 20:76] = True
        img = np.where(truth, 50.0, 0.0)
        img[40:56, 40:56] = 0.0  # dark inside
        img = ndimage.uniform_filter(img, size=3) + rng.normal(0.0, 1.0, img.shape)  # a one-pixel blur
        mask = fg.foreground_mask(img, 1.0)
        assert mask[40:56, 40:56].all()
        # The silhouette is found to within one pixel of the blur.
        assert not (mask & ~ndimage.binary_dilation(truth, np.ones((3, 3)))).any()
        assert not (ndimage.binary_erosion(truth, np.ones((3, 3))) & ~mask).any()
        np.testing.assert_array_equal(mask, fg.foreground_mask(img, 1.0))  # deterministic

    def test_fill_holes_off_keeps_the_hole(self):
        img = np.zeros((64, 64))
        img[16:48, 16:48] = 100.0
        img[28:36, 28:36] = 0.0
        assert not fg.foreground_mask(img, 1.0, fill_holes=False)[32, 32]
        assert fg.foreground_mask(img, 1.0)[32, 32]

    def test_small_and_relatively_small_components_are_dropped(self):
        img = np.zeros((128, 128))
        img[20:100, 20:100] = 100.0  # 6400 px
        img[110:113, 110:113] = 100.0  # 9 px: under min_area (a hot pixel blob)
        img[2:17, 2:17] = 100.0  # 225 px: above min_area, under 5 % of the largest
        img[105:125, 2:22] = 100.0  # 400 px: kept
        mask = fg.foreground_mask(img, 1.0)
        assert mask[60, 60] and mask[115, 10]
        assert not mask[111, 111] and not mask[10, 10]
        assert fg.foreground_mask(img, 1.0, min_fraction=0.0)[10, 10]

    def test_opening_removes_thin_spurs(self):
        img = np.zeros((64, 64))
        img[16:48, 16:48] = 100.0
        img[30, 48:60] = 100.0  # a one-pixel-wide spur
        mask = fg.foreground_mask(img, 1.0)
        assert not mask[30, 55]
        assert mask[16:48, 16:48].all()

    def test_object_touching_the_border(self):
        img = np.zeros((64, 64))
        img[:40, :30] = 100.0
        np.testing.assert_array_equal(fg.foreground_mask(img, 1.0), img > 0)

    def test_edge_test_removes_the_halo(self):
        img = np.zeros((64, 64))
        img[16:48, 16:48] = 100.0
        img[14:16, 16:48] = img[48:50, 16:48] = 10.0  # a dim fringe, far above the noise
        assert not fg.foreground_mask(img, 1.0)[15, 30]
        assert fg.foreground_mask(img, 1.0, edge_fraction=0.0)[15, 30]

    def test_highlight_does_not_carve_the_object(self):
        img = np.zeros((64, 64))
        img[16:48, 16:48] = 10.0
        img[28:36, 24:40] = 1000.0  # a highlight well inside the silhouette (> edge_radius + 2)
        mask = fg.foreground_mask(img, 1.0)
        np.testing.assert_array_equal(mask, img > 0)

    def test_nothing_above_the_noise(self, rng):
        assert not fg.foreground_mask(rng.normal(0.0, 1.0, (64, 64)), 1.0).any()

    def test_non_finite_pixels_count_as_dark(self):
        img = np.zeros((32, 32))
        img[8:24, 8:24] = 100.0
        img[0, 0], img[1, 1], img[16, 16] = np.nan, np.inf, np.nan
        mask = fg.foreground_mask(img, 1.0)
        assert not mask[0, 0] and not mask[1, 1] and mask[16, 16]  # the inner one is a hole, filled

    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"signal": np.zeros(5)}, "2-D"),
            ({"sigma": -1.0}, "sigma must be positive"),
            ({"sigma": np.nan}, "sigma must be positive"),
            ({"edge_fraction": 1.0}, "edge_fraction"),
            ({"min_area": -1}, "min_area"),
            ({"min_fraction": 2.0}, "min_fraction"),
        ],
    )
    def test_bad_arguments(self, kwargs, match):
        args = {"signal": np.zeros((8, 8)), "sigma": 1.0, **kwargs}
        with pytest.raises(ValueError, match=match):
            fg.foreground_mask(args.pop("signal"), args.pop("sigma"), **args)

    @pytest.mark.parametrize("radius", [1, 2, 4])
    def test_edge_test_paths_agree(self, rng, radius):
        """The gathered (narrow band) and the filtered (wide band) edge tests are the same test."""
        above = rng.random((40, 56)).astype(np.float32)
        wide = rng.random(above.shape) < 0.9
        narrow = np.zeros_like(wide)
        narrow[[0, 5, 39], [0, 30, 55]] = True
        ref = ndimage.maximum_filter(above, size=2 * radius + 1, mode="nearest")
        for band in (wide, narrow):
            expected = band & (above >= np.float32(0.5) * ref)
            np.testing.assert_array_equal(fg._edge_test(above, band, 0.5, radius), expected)

    @pytest.mark.parametrize("shape", [(7, 9), (64, 50), (3, 40), (1, 5)])
    @pytest.mark.parametrize("radius", [0, 1, 2, 3, 6])
    def test_square_filters_equal_scipy(self, rng, shape, radius):
        a = rng.random(shape).astype(np.float32)
        size = 2 * radius + 1
        ref = ndimage.maximum_filter(a, size=size, mode="constant", cval=-1.0)
        np.testing.assert_array_equal(fg._square_filter(a, radius, np.maximum), ref)
        b = a > 0.3
        ref = ndimage.minimum_filter(b.view(np.uint8), size=size, mode="constant", cval=1).astype(bool)
        np.testing.assert_array_equal(fg._square_filter(b, radius, np.logical_and), ref)


# --------------------------------------------------------------------------------------------
# The mask on captures


class TestCaptureForeground:
    def test_example_capture(self):
        """examples/capture (rendered scene, camera model noise): IoU >= 0.9 against its truth."""
        truth = np.load(EXAMPLE_TRUTH)["mask"].astype(bool)
        cap = pcapture.load_capture(EXAMPLE)
        dec = pdecode_capture.decode_capture(cap)
        assert dec.foreground_source == "auto"
        assert _iou(dec.foreground, truth) >= 0.9
        assert _iou(dec.mask, truth) < 0.8  # the bare decode validity keeps noisy background
        full = pdecode_capture.decode_capture(cap, grid="full")
        assert _iou(full.foreground, np.repeat(np.repeat(truth, 2, 0), 2, 1)) >= 0.9

    @pytest.mark.parametrize("dark_patch", [False, True])
    def test_synthetic_disc(self, rng, dark_patch):
        h, w, radius = 256, 320, 90.0
        model = CameraModel()
        raws = simulate_capture(disc_stokes(h, w, radius, dark_patch=dark_patch), model, rng=rng)
        dec = decode(raws, model)
        mask = fg.capture_foreground(dec, model)
        truth = _disc_truth(h, w, radius)
        assert _iou(mask, truth) >= 0.9
        assert _iou(dec.mask, truth) < 0.6
        assert mask[h // 4, w // 4]  # the dark patch (and everything else in the middle) is kept

    def test_dim_object_and_hot_pixels(self, rng):
        h, w, radius = 256, 320, 90.0
        model = CameraModel()
        raws = simulate_capture(disc_stokes(h, w, radius, level=0.002), model, rng=rng)
        raws[:, [10, 200, 250], [300, 20, 300]] = 4000  # hot pixels in the background
        mask = fg.capture_foreground(decode(raws, model), model)
        assert _iou(mask, _disc_truth(h, w, radius)) >= 0.9
        for y, x in ((5, 150), (100, 10), (125, 150)):  # the hot pixels on the half grid
            assert not mask[y - 4 : y + 5, x - 4 : x + 5].any()

    def test_all_dark_capture_gives_an_empty_mask(self, rng):
        model = CameraModel()
        dec = decode(simulate_capture(np.zeros((64, 96, 3, 4)), model, rng=rng), model)
        mask = fg.capture_foreground(dec, model)
        assert mask.shape == (32, 48) and mask.dtype == bool and not mask.any()

    def test_bad_grid(self, rng):
        model = CameraModel()
        dec = decode(simulate_capture(np.zeros((16, 16, 3, 4)), model, rng=rng), model)
        with pytest.raises(ValueError, match="grid must be"):
            fg.capture_foreground(dec, model, grid="quarter")
