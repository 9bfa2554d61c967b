"""network.demo.optics: the analytic two-sphere scene and its round trip through camera and decoder."""

import numpy as np
import pytest

from network.demo import optics


def test_pattern_regions():
    # Camera -x is the display's right (red); +y is its upper half (blue); outside: dark.
    np.testing.assert_array_equal(optics.pattern_rgb(np.array([-0.1, 0.1, 5.0]), np.array([0.1, -0.1, 0.0])),
                                  [[1, 0, 1], [0, 1, 0], [0, 0, 0]])  # fmt: skip


def test_scene_is_physical_and_has_both_spheres():
    scene = optics.render_stokes(48, 64)
    s, mask = scene["stokes"], scene["mask"]
    assert s.shape == (48, 64, 3, 4) and mask.shape == (48, 64)
    assert mask[:, :32].any() and mask[:, 32:].any() and not mask.all()
    assert np.all(s[..., 0] >= np.linalg.norm(s[..., 1:], axis=-1) - 1e-9)
    np.testing.assert_allclose(np.linalg.norm(scene["normal"][mask], axis=-1), 1.0, atol=1e-9)
    assert np.all(s[~mask] == 0)


def test_round_trip_recovers_the_maps(tmp_path):
    metrics = optics.run_optics_check(tmp_path, height=96, width=128, seed=1)
    assert metrics["decoded_shape"] == [48, 64, 9] and metrics["mask_iou_vs_lit_truth"] > 0.8
    for name in ("R_unpol", "G_unpol", "B_unpol"):
        m = metrics["maps"][name]
        # Noise, 12-bit steps and demosaicing across mirrored pattern edges: about 5-12 % here.
        assert m["mae"] < 0.2 * m["truth_mean"], (name, m)
    assert set(metrics["timings"]) == {"shade_scene_s", "camera_model_s", "decode_s", "write_s"}
    assert (tmp_path / "capture" / "capture.json").is_file() and (tmp_path / "metrics.json").is_file()


def test_bad_size():
    with pytest.raises(ValueError, match="multiples of 4"):
        optics.round_trip(30, 64)
