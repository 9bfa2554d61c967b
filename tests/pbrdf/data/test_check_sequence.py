"""pbrdf/data/capture_decode.check_sequence: frames that do not belong together, refused from their headers."""

import numpy as np
import pytest

from pbrdf.data import capture
from pbrdf.data.capture_decode import check_sequence
from pbrdf.sensor import camera


def _frame(folder, size=(32, 48), exposures=(0.01, 0.02, 0.1, 0.2), file_format="png"):
    model = camera.CameraModel(exposures=exposures)
    raws = np.full((len(exposures), *size), 500, np.uint16)
    return capture.save_capture(folder, raws, model, file_format=file_format)


def test_matching_frames_pass_and_mismatches_name_both_frames(tmp_path):
    a, b = _frame(tmp_path / "t000"), _frame(tmp_path / "t001", file_format="npy")
    check_sequence([a, b])
    other = _frame(tmp_path / "t002", exposures=(0.01, 0.02, 0.1, 0.3))
    with pytest.raises(ValueError, match=r"t002: exposures_s .* differ from .* first frame t000"):
        check_sequence([a, b, other])
    big = _frame(tmp_path / "t003", size=(32, 52))
    with pytest.raises(ValueError, match=r"t003: raw size 52x32 differs from 48x32 of the sequence's first frame t000"):
        check_sequence([a, big])
    (b / sorted(p.name for p in b.glob("raw_*"))[1]).unlink()
    with pytest.raises(FileNotFoundError, match="raw file listed in capture.json does not exist"):
        check_sequence([a, b])


def test_a_raw_larger_than_the_sensor_is_refused(tmp_path):
    from pbrdf.data.capture_decode import decode_capture

    model = camera.CameraModel()
    raws = np.full((4, 2052, 16), 500, np.uint16)  # 4 rows more than the IMX250's 2048
    folder = capture.save_capture(tmp_path / "tall", raws, model)
    with pytest.raises(ValueError, match=r"tall: raw frames are 16x2052, larger than the camera's 2448x2048 sensor"):
        decode_capture(folder)
    small = capture.save_capture(tmp_path / "small", raws[:, :2048], model)
    assert decode_capture(small).maps.shape == (1024, 8, 9)
