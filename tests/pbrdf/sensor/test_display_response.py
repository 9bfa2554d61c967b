"""The display's emission profile and tone response: fields, checks, and every closed form that honours them.

Independent references: brute-force quadrature over the display surface with ``cos^(1+p)`` written
out (``tests.helpers.display_quadrature``), and ``v ** gamma`` written out for the tone response.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from network.light_input import LIGHT_GAIN, light_channels
from network.rerender import display_patches, rerender
from pbrdf.sensor import projection
from pbrdf.sensor.display_response import check_emission_exponent, check_tone_gamma, emission_profile
from pbrdf.sensor.irradiance import irradiance_vectors, subdivide_quads
from pbrdf.sensor.patches import constant_patches
from pbrdf.sensor.rig import DisplaySpec, Rig
from tests.helpers import display_quadrature


def test_fields_default_to_the_flat_linear_display_and_round_trip():
    d = DisplaySpec()
    assert d.emission_exponent == 0.0 and d.tone_gamma == (1.0, 1.0, 1.0)
    rig = Rig.from_dict({"display": {"emission_exponent": 1.5, "tone_gamma": [2.2, 2.0, 1.8]}})
    assert Rig.from_dict(json.loads(json.dumps(rig.to_dict()))) == rig
    assert (
        rig.display.tone_gamma == (2.2, 2.0, 1.8)
        and Rig.from_dict({"display": {"tone_gamma": 2.2}}).display.tone_gamma == (2.2,) * 3
    )


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"emission_exponent": -0.5}, r"display.emission_exponent must be in \[0, 8\]; got -0.5"),
        ({"emission_exponent": float("nan")}, "display.emission_exponent must be in"),
        ({"emission_exponent": "2"}, "display.emission_exponent must be a number"),
        ({"tone_gamma": [2.2, 0.0, 2.2]}, r"display.tone_gamma\[G\] must be in \[0.2, 5\]; got 0"),
        ({"tone_gamma": [1.0, 1.0]}, "display.tone_gamma must be one number or three"),
    ],
)
def test_out_of_range_fields_are_refused_naming_the_field(override, message):
    with pytest.raises(ValueError, match=message):
        Rig.from_dict({"display": override})
    assert check_emission_exponent(8) == 8.0 and check_tone_gamma(0.2) == (0.2, 0.2, 0.2)


def test_tone_response_maps_commanded_levels_of_an_image_pattern(tmp_path):
    from PIL import Image

    levels = np.array([[[0, 64, 128], [191, 255, 32]]], dtype=np.uint8)  # (1, 2, 3) commanded, 8 bit
    path = tmp_path / "pattern.png"
    Image.fromarray(levels).save(path)
    linear = DisplaySpec(pattern=str(path)).pattern_image()
    gamma = (2.2, 1.0, 0.5)
    emitted = DisplaySpec(pattern=str(path), tone_gamma=gamma).pattern_image()
    np.testing.assert_array_equal(linear, levels / np.float32(255.0))  # nominal: the commanded values as before
    np.testing.assert_allclose(emitted, (levels / 255.0) ** np.array(gamma), rtol=1e-6)
    assert emitted.dtype == np.float32
    # Binary patterns are fixed points of any tone response.
    for pattern in ("rgb_halves", "white"):
        np.testing.assert_array_equal(DisplaySpec(pattern=pattern, tone_gamma=gamma).pattern_image(),
                                      DisplaySpec(pattern=pattern).pattern_image())  # fmt: skip


def test_emission_profile_is_finite_and_zero_behind_the_panel():
    cos = np.array([-1.0, 0.0, 1e-300, 0.5, 1.0, 2.0])
    for p in (0.0, 0.3, 2.0, 8.0):
        v = emission_profile(cos, p)
        assert np.all(np.isfinite(v)) and v[0] == 0 and v[-2] == 1 and np.all((v >= 0) & (v <= 1))
    assert emission_profile(0.5, 2.0) == pytest.approx(0.25)


def test_subdivided_quads_tile_the_quad():
    quad = np.array([[[0.0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]]])
    sub = subdivide_quads(quad, 3)
    edges = sub - np.roll(sub, -1, axis=1)
    area = np.abs(np.cross(edges[:, 0], -edges[:, 3])[:, 2]).sum()
    assert sub.shape == (9, 4, 3) and area == pytest.approx(2.0)


@pytest.mark.parametrize("curved", [False, True])
@pytest.mark.parametrize("exponent", [1.0, 3.0])
def test_profiled_irradiance_matches_quadrature(curved, exponent):
    display = DisplaySpec(curvature_radius=1.0 if curved else None, emission_exponent=exponent)
    p = constant_patches(display)
    for point in ([0.08, -0.05, -0.6], [0.3, 0.2, -0.35]):
        point = np.array(point)
        phi = irradiance_vectors(p.vertices, p.radiance, point[None], exponent=exponent)[0]
        ref = display_quadrature(display, point, n=600)
        np.testing.assert_allclose(phi, ref, rtol=0, atol=2e-3 * np.abs(ref).max())
        n = np.array([0.6, -0.2, 0.77]) / np.linalg.norm([0.6, -0.2, 0.77])  # part of the display below the horizon
        e = np.einsum(
            "ck,k->c", irradiance_vectors(p.vertices, p.radiance, point[None], n[None], exponent=exponent)[0], n
        )
        ref_e = display_quadrature(display, point, n, n=600)
        np.testing.assert_allclose(e, ref_e, rtol=0, atol=3e-3 * ref_e.max())
        # A wrong exponent (10 % off) misses the reference by more than the tolerance.
        wrong = irradiance_vectors(p.vertices, p.radiance, point[None], exponent=1.1 * exponent)[0]
        assert np.abs(wrong - ref).max() > 5e-3 * np.abs(ref).max()


def test_rerender_and_light_input_see_the_profiled_display():
    """The re-renderer's patch quadrature and the light input against the profiled closed form."""
    k = projection.pinhole_intrinsics(40.0, 16, 16)
    for exponent in (0.0, 2.0):
        rig = Rig.from_dict({"display": {"emission_exponent": exponent}})
        light = light_channels(rig, k, (16, 16), 0.6, grid=None)  # (9, H, W)
        ray = projection.pixel_rays(k, 16, 16)[3, 12]
        ref = display_quadrature(rig.display, 0.6 * ray, n=600)  # (3 regions, xyz); camera frame = world
        np.testing.assert_allclose(light[:, 3, 12].reshape(3, 3) / LIGHT_GAIN, ref, atol=3e-3 * np.abs(ref).max())
    # Re-rendered diffuse light ("fresnel": Lambert times nearly constant transmissions) under p = 2 over p = 0.
    n, pt = torch.tensor([[[0.0], [0.0], [1.0]]]), torch.tensor([[[0.05], [-0.02], [-0.6]]])
    args = (n, torch.full((1, 3, 1), 0.5), torch.ones(1, 1, 1), torch.zeros(1, 1, 1), pt)
    out = {p: rerender(*args, display_patches(Rig.from_dict({"display": {"emission_exponent": p}}), (12, 12)),
                       diffuse="fresnel")["unpol"][0, :, 0].double().numpy() for p in (0.0, 2.0, 2.4)}  # fmt: skip
    normal = np.array([0.0, 0.0, 1.0])
    e = {
        p: display_quadrature(DisplaySpec(emission_exponent=p), pt[0, :, 0].numpy(), normal, n=600) for p in (0.0, 2.0)
    }
    np.testing.assert_allclose(out[2.0] / out[0.0], e[2.0] / e[0.0], rtol=0.01)
    assert np.all(np.abs(out[2.4] / out[0.0] / (e[2.0] / e[0.0]) - 1) > 0.02)  # a wrong exponent fails


def test_white_radiance_spline_matches_the_exact_evaluation():
    """A pixel grid is evaluated on WHITE_GRID^2 rays and splined; single rays are exact."""
    from pbrdf.sensor.calibration_display import white_radiance

    rays = projection.pixel_rays(projection.pinhole_intrinsics(60.0, 64, 64), 64, 64)
    rig = Rig.from_dict({"display": {"emission_exponent": 1.8}})
    grid = white_radiance(rig, rays, 0.4, 0.9, channel=1, level=0.5)
    pick = (np.arange(0, 64, 7)[:, None], np.arange(3, 64, 9)[None, :])
    exact = white_radiance(rig, rays[pick].reshape(-1, 3), 0.4, 0.9, channel=1, level=0.5).reshape(grid[pick].shape)
    np.testing.assert_allclose(grid[pick], exact, rtol=1e-4)
