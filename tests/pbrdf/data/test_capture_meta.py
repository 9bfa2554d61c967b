"""Tests for pbrdf.data.capture_meta (the radiometry and geometry keys of a capture)."""

from __future__ import annotations

import numpy as np
import pytest

from pbrdf.data import capture as cap
from pbrdf.data.capture_meta import CaptureMeta, display_radiance, parse_capture_meta
from pbrdf.sensor.camera import CameraModel, simulate_capture


def test_display_radiance_reads_radiometry_and_rig(tmp_path):
    assert display_radiance({}) == 1.0  # calibrated by default, the default rig's display
    assert display_radiance({"radiometry": "calibrated", "rig": {"display": {"radiance": 0.25}}}) == 0.25
    assert display_radiance({"radiometry": "relative", "rig": {"display": {"radiance": 0.25}}}) is None
    with pytest.raises(ValueError, match=r"^x/capture.json: radiometry must be one of \['calibrated', 'relative'\]"):
        display_radiance({"radiometry": "absolute"}, "x/capture.json")
    with pytest.raises(ValueError, match=r"^x/capture.json: invalid rig: display.radiance must be > 0"):
        display_radiance({"rig": {"display": {"radiance": 0}}}, "x/capture.json")
    # The keys travel through a saved capture folder as metadata.
    model = CameraModel(exposures=(0.01, 0.1))
    raws = simulate_capture(np.full((8, 8, 3, 4), 0.0) + [0.1, 0, 0, 0], model, noise=False)
    folder = cap.save_capture(tmp_path / "c", raws, model, extra={"radiometry": "relative"})
    assert display_radiance(cap.load_capture(folder).metadata) is None


def test_parse_capture_meta_defaults_and_values():
    """Absent keys give the defaults; given keys come back as given (a 2x focal length halves on the half grid)."""
    assert parse_capture_meta({}, "c.json") == CaptureMeta()
    k = [[200.0, 0.0, 40.0], [0.0, 200.0, 30.0], [0.0, 0.0, 1.0]]
    meta = parse_capture_meta({"intrinsics": k, "distance_m": 0.5, "radiometry": "relative"}, "c.json")
    assert (meta.distance_m, meta.radiance) == (0.5, None)
    np.testing.assert_array_equal(meta.grid_intrinsics((60, 80), (30, 40)), [[100, 0, 20], [0, 100, 15], [0, 0, 1]])
    with pytest.raises(ValueError, match=r"^c.json: distance_m must be a number; got True"):
        parse_capture_meta({"distance_m": True}, "c.json")
