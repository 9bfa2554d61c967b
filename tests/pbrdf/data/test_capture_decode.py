"""pbrdf.data.capture_decode.check_usable: the warning for an automatic mask that swallows the frame.

Room light on the background, with no dark frames to remove it, lifts the whole frame above the
noise floor, and the automatic mask takes the wall for the object. The scenes are simulated through
the camera model (its ``ambient`` term is that room light) and the expected masks come from the
scene itself: a disc of radius r on an h x w frame covers pi r^2 / (h w) of it.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from PIL import Image

from pbrdf.data import capture as cap
from pbrdf.data import capture_decode as capdec
from pbrdf.data.dark_frames import dark_frames
from pbrdf.sensor.camera import CameraModel, simulate_capture
from tests.helpers import disc_stokes

H, W, RADIUS = 32, 48, 10.0
#: The disc's share of the frame (20.5 %).
DISC_FRACTION = math.pi * RADIUS**2 / (H * W)


def _room_lit(rng: np.random.Generator, ambient: float = 0.001) -> tuple[np.ndarray, CameraModel]:
    """A disc on a background lit by room light at ``ambient`` of the display's radiance (no dark frames)."""
    model = CameraModel(ambient=(ambient,) * 3)
    return simulate_capture(disc_stokes(H, W, RADIUS), model, rng=rng), model


def _load(tmp_path, raws, model, dark=None, name="c") -> cap.Capture:
    return cap.load_capture(cap.save_capture(tmp_path / name, raws, model, file_format="npy", dark=dark))


def _check_silently(capture: cap.Capture) -> capdec.DecodedCapture:
    decoded = capdec.decode_capture(capture)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        capdec.check_usable(decoded, capture, need_object=True)
    return decoded


class TestFullFrameMask:
    @pytest.mark.parametrize("ambient", [0.001, 0.01])
    def test_room_light_without_dark_frames_warns_once(self, tmp_path, rng, ambient):
        capture = _load(tmp_path, *_room_lit(rng, ambient))
        decoded = capdec.decode_capture(capture)
        assert decoded.foreground.mean() > 0.99  # the wall passes as object: the failure being warned about
        for need_object in (False, True):  # headless/decode.py, and inference (which must not refuse it)
            with pytest.warns(capdec.CaptureWarning) as record:
                capdec.check_usable(decoded, capture, need_object=need_object)
            assert len(record) == 1
            message = str(record[0].message)
            assert message.startswith(f"{capture.folder}: the automatic object mask covers 100% of the frame "), message
            assert "no dark frames" in message and "dark_files" in message and "\n" not in message

    def test_dark_frames_remove_the_room_light_and_the_warning(self, tmp_path, rng):
        raws, model = _room_lit(rng, 0.01)
        capture = _load(tmp_path, raws, model, dark=dark_frames(model, (H, W), sample_seed=1))
        decoded = _check_silently(capture)
        assert abs(decoded.foreground.mean() - DISC_FRACTION) < 0.03  # the disc again (measured 22.1 %)

    def test_disc_on_black_is_silent(self, tmp_path, disc_capture):
        decoded = _check_silently(_load(tmp_path, *disc_capture))
        assert abs(decoded.foreground.mean() - DISC_FRACTION) < 0.03  # measured 21.6 %

    def test_frame_filling_object_warns_only_without_dark_frames(self, tmp_path, rng):
        # An object that does fill the frame looks like room light without dark frames (warned); its dark frames
        # say the room was dark, so the full mask is believed.
        model = CameraModel()
        raws = simulate_capture(np.full((H, W, 3, 4), 0.0) + [0.2, -0.05, 0.0, 0.0], model, rng=rng)
        bare = _load(tmp_path, raws, model)
        with pytest.warns(capdec.CaptureWarning, match="covers 100% of the frame and the capture has no dark frames"):
            capdec.check_usable(capdec.decode_capture(bare), bare)
        dark = dark_frames(model, (H, W), sample_seed=1)
        assert _check_silently(_load(tmp_path, raws, model, dark=dark, name="d")).foreground.all()

    def test_a_mask_file_is_believed(self, tmp_path, rng):
        raws, model = _room_lit(rng)
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        Image.fromarray(np.full((H // 2, W // 2), 255, np.uint8)).save(folder / capdec.MASK_FILE)
        _check_silently(cap.load_capture(folder))
