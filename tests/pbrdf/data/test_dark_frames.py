"""pbrdf/data/dark_frames.py without a render: the dark bracket's signal, its streams and its float type.

The run over a rendered dataset (``add_dark_frames``) is tested on rendered captures in
tests/network/test_pseudo_real.py and through its command line in tests/headless/test_dark_frames.py.
"""

import numpy as np
import pytest

from pbrdf.data.dark_frames import DARK_STREAM, dark_frames
from pbrdf.sensor.camera import CameraModel

MODEL = CameraModel(ambient=(0.005, 0.005, 0.005))  # the engine's largest drawn room light at F = 1


def test_dark_signal_grows_linearly_with_exposure_and_is_black_without_ambient():
    frames = dark_frames(MODEL, (64, 64), sample_seed=3)
    assert frames.shape == (len(MODEL.exposures), 64, 64) and frames.dtype == np.uint16
    black = MODEL.sensor.black_level
    per_second = [(f.mean(dtype=np.float64) - black) / t for f, t in zip(frames, MODEL.exposures, strict=True)]
    # Photon counts are linear in time: the same rate at 10 ms and 200 ms (the shortest is noisiest: ~2 %).
    np.testing.assert_allclose(per_second, np.median(per_second), rtol=0.03)
    assert min(per_second) > 0
    dark = dark_frames(CameraModel(), (64, 64), sample_seed=3)
    assert abs(dark.mean(dtype=np.float64) - black) < 0.5  # no room light: the offset and noise only


def test_frames_are_a_pure_function_of_seed_and_stream():
    a = dark_frames(MODEL, (32, 32), sample_seed=5)
    np.testing.assert_array_equal(a, dark_frames(MODEL, (32, 32), sample_seed=5, stream=DARK_STREAM))
    assert not np.array_equal(a, dark_frames(MODEL, (32, 32), sample_seed=6))
    assert not np.array_equal(a, dark_frames(MODEL, (32, 32), sample_seed=5, stream=2))  # another stream


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_any_float_type(dtype):
    frames = dark_frames(MODEL, (16, 32), sample_seed=1, dtype=dtype)
    assert frames.shape == (len(MODEL.exposures), 16, 32) and frames.dtype == np.uint16
