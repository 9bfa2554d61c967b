"""network.demo.pipeline: the demo's configuration and its small helpers (the full run: tests/headless/test_demo.py)."""

import numpy as np
import pytest

from network.demo import DemoConfig, pipeline


@pytest.mark.parametrize(
    "changes",
    [{"scenes": 0}, {"scenes": 2, "measured_scenes": 3}, {"resolution": 8}, {"spp": 0}, {"relight_frames": -1}],
)
def test_config_rejects_bad_sizes(changes):
    with pytest.raises(ValueError):
        DemoConfig(**changes)


def test_relight_script_exists_beside_the_package():
    assert (pipeline.ROOT / "headless" / "relight.py").is_file()


def test_mask_weighted_mean():
    rows = [{"pixels": 1, "ours": {"mae": 1.0}}, {"pixels": 3, "ours": {"mae": 3.0}}, {"pixels": 5, "ours": {}}]
    assert pipeline._mean(rows, "ours", "mae") == pytest.approx(2.5)
    assert np.isnan(pipeline._mean(rows, "ours", "missing"))


def test_angle_map_degrees():
    a = np.array([[[1.0, 0, 0], [0, 1.0, 0]]])
    b = np.array([[[0, 1.0, 0], [0, 2.0, 0]]])
    out = pipeline._angle_map(a, b, np.array([[True, True]]))
    np.testing.assert_allclose(out, [[90.0, 0.0]], atol=1e-6)
