"""Tests of network/baseline.py: photometric stereo against its own physics."""

import numpy as np
import pytest

from network import baseline, metrics


def test_photometric_stereo_inverts_its_own_model():
    """With distant lights and a grey Lambertian sphere, the baseline recovers normals exactly."""
    rig = pytest.importorskip("pbrdf.sensor.rig")
    display = rig.DisplaySpec()
    dirs, scale = baseline.region_light_directions(display, np.array([0.0, 0.0, -0.7]))
    # Red lights from the display's right half (world -x), green from world +x, blue from above.
    assert dirs[0, 0] < 0 < dirs[1, 0] and dirs[2, 1] > 0 and np.all(dirs[:, 2] > 0)
    yy, xx = np.mgrid[0:32, 0:32]
    x, y = (xx + 0.5) / 16 - 1, 1 - (yy + 0.5) / 16
    inside = x**2 + y**2 < 0.8
    n = np.stack([x, y, np.sqrt(np.clip(1 - x**2 - y**2, 0, 1))], -1)
    rho = 0.6
    unpol = rho / np.pi * scale * np.clip(n @ dirs.T, 0, None)
    lit = inside & np.all(n @ dirs.T > 0.05, axis=-1)
    out = baseline.photometric_stereo(unpol, lit, dirs, scale)
    assert metrics.normal_mae_deg(out["normal"], n, lit) < 1e-3
    np.testing.assert_allclose(out["albedo"][lit], rho, atol=1e-4)
