"""pbrdf/sensor/irradiance.py: Lambert's polygon formula against brute-force quadrature."""

import numpy as np
import pytest

from pbrdf.sensor import irradiance
from pbrdf.sensor.patches import constant_patches
from pbrdf.sensor.rig import DisplaySpec
from tests.helpers import display_quadrature


@pytest.mark.parametrize("curved", [False, True])
def test_irradiance_vectors_match_quadrature(curved):
    display = DisplaySpec(curvature_radius=1.0 if curved else None)
    patches = constant_patches(display)
    verts, rad = patches.vertices, patches.radiance
    point = np.array([0.08, -0.05, -0.6])
    phi = irradiance.irradiance_vectors(verts, rad, point[None])[0]
    np.testing.assert_allclose(phi, display_quadrature(display, point), rtol=2e-3, atol=2e-4)
    # Tilted so that part of the display is below the horizon: the clipped model is exact.
    for normal in ([0.9, 0.0, 0.3], [-0.3, -0.9, 0.2], [0.0, 0.0, 1.0]):
        n = np.asarray(normal) / np.linalg.norm(normal)
        e = np.einsum("ck,k->c", irradiance.irradiance_vectors(verts, rad, point[None], n[None])[0], n)
        np.testing.assert_allclose(e, display_quadrature(display, point, n), rtol=3e-3, atol=2e-4)


def test_region_directions_are_ill_conditioned_but_correct():
    """The three regions lie near the viewing axis: the 3x3 system has a condition number near 10."""
    dirs, mag = irradiance.region_light_directions(DisplaySpec(), [0.0, 0.0, -0.7])
    assert dirs[0, 0] < 0 < dirs[1, 0] and dirs[2, 1] > 0 and np.all(dirs[:, 2] > 0.9)
    assert 5 < np.linalg.cond(dirs * mag[:, None]) < 20


# --------------------------------------------------------------------------- the solve on its own model
