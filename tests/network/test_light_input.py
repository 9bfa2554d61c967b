"""The light input against a brute-force quadrature of the display, and the distance rules."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from network.light_input import (
    DISTANCE_RANGE_M,
    LIGHT_GAIN,
    check_distance,
    light_channels,
    per_map_light,
    resolve_distance,
    sample_distance,
    sample_light,
)
from pbrdf.sensor import projection
from pbrdf.sensor.rig import DisplaySpec, Rig


def _quadrature(rig: Rig, points_cam: np.ndarray, n: tuple[int, int] = (480, 270)) -> np.ndarray:
    """``(P, 3, 3)`` irradiance vectors / display radiance by the midpoint rule over the display surface.

    Independent of Lambert's formula: sums ``L(y) l cos(theta_y) / r^2 dA`` over a fine grid of the
    display's surface coordinates, with the pattern read per point (:meth:`DisplaySpec.pattern_rgb_at`).
    """
    disp = rig.display
    xs = (np.arange(n[0]) + 0.5) / n[0] * disp.width - disp.width / 2
    ys = (np.arange(n[1]) + 0.5) / n[1] * disp.height - disp.height / 2
    xy = np.stack(np.meshgrid(xs, ys, indexing="xy"), -1).reshape(-1, 2)
    da = disp.width * disp.height / len(xy)  # arc length x height: exact area element on a cylinder too
    w2c = rig.camera.world_to_camera()
    y = projection.transform_points(w2c, disp.surface_points_world(xy))
    ny = disp.surface_normals_world(xy) @ w2c[:3, :3].T
    rgb = disp.pattern_rgb_at(xy).astype(np.float64)  # radiance / display radiance
    out = np.zeros((len(points_cam), 3, 3))
    for i, p in enumerate(points_cam):
        to = y - p
        r = np.linalg.norm(to, axis=-1)
        dirs = to / r[:, None]
        cos_y = np.clip(-(ny * dirs).sum(-1), 0, None)
        wgt = cos_y / r**2 * da
        out[i] = np.einsum("q,qc,qk->ck", wgt, rgb, dirs)
    return out


@pytest.mark.parametrize(
    "display",
    [DisplaySpec(), DisplaySpec(curvature_radius=1.0, yaw=0.15), DisplaySpec(pattern="white", radiance=3.0)],
    ids=["flat", "curved-yawed", "white-bright"],
)
def test_light_channels_match_quadrature(display):
    rig = Rig(display=display)
    k = projection.crop_intrinsics(rig.camera.intrinsics(), (600, 800, 1400, 1600), (48, 48))
    for d in (0.35, 1.4):
        light = light_channels(rig, k, (48, 48), d)
        pix = [(0, 0), (24, 11), (47, 47), (5, 40)]
        rays = projection.pixel_rays(k, 48, 48)
        pts = np.array([d * rays[i, j] for i, j in pix])
        ref = LIGHT_GAIN * _quadrature(rig, pts)
        for (i, j), r in zip(pix, ref, strict=True):
            got = light[:, i, j].reshape(3, 3)
            np.testing.assert_allclose(got, r, atol=2e-3 * np.abs(ref).max(), rtol=3e-3)


def test_light_falls_with_distance_like_a_far_source():
    """Far away the display is a small source: |Phi| d^2 tends to radiance x area x cos (inverse square law)."""
    rig = Rig(display=DisplaySpec(pattern="white"))
    k = projection.pinhole_intrinsics(500.0, 9, 9)
    mags = [np.linalg.norm(light_channels(rig, k, (9, 9), d)[0:3, 4, 4]) for d in (1.5, 3.0)]
    dist = [1.5 + 0.05, 3.0 + 0.05]  # the display is 5 cm behind the camera
    area = rig.display.width * rig.display.height
    expect = [LIGHT_GAIN * area / r**2 for r in dist]
    np.testing.assert_allclose(mags, expect, rtol=0.12)
    assert mags[0] / mags[1] == pytest.approx((dist[1] / dist[0]) ** 2, rel=0.1)


def test_grid_interpolation_is_close_to_every_pixel_exact():
    rig = Rig()
    k = projection.crop_intrinsics(rig.camera.intrinsics(), (724, 924, 1324, 1524), (96, 96))
    exact = light_channels(rig, k, (96, 96), 0.6, grid=None)
    coarse = light_channels(rig, k, (96, 96), 0.6)
    assert np.abs(coarse - exact).max() < 1e-3 * np.abs(exact).max()
    assert coarse.dtype == np.float32 and coarse.shape == (9, 96, 96) and np.isfinite(coarse).all()


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, 70.0, 0.1, "far", None, True])
def test_check_distance_rejects_implausible(bad):
    with pytest.raises(ValueError, match=r"^capture.json: distance_m must be a distance in metres"):
        check_distance(bad, "capture.json: distance_m")


def test_check_distance_accepts_the_range():
    lo, hi = DISTANCE_RANGE_M
    assert check_distance(lo) == lo and check_distance(hi) == hi and check_distance("0.8") == 0.8


def test_resolve_distance_warns_on_fallback():
    with pytest.warns(UserWarning, match="albedo is relative"):
        d, measured = resolve_distance(None, "cap")
    assert measured is False and d > 0
    assert resolve_distance(1.2) == (1.2, True)


def test_sample_distance_is_the_median_over_the_mask():
    depth = np.array([[0.5, 0.6, 9.0], [0.7, 0.0, 0.8]])
    mask = np.array([[1, 1, 0], [1, 0, 1]])
    assert sample_distance(depth, mask) == pytest.approx(0.65)
    with pytest.raises(ValueError, match="s.exr: depth"):
        sample_distance(depth, np.zeros_like(mask), "s.exr")


def test_sample_light_uses_the_sidecar_rig_and_resized_intrinsics():
    k = projection.pinhole_intrinsics(400.0, 64, 64)
    meta = {"intrinsics": k.tolist(), "rig": {"display": {"radiance": 2.0}}}
    depth = np.full((64, 64), 0.8)
    mask = np.ones((64, 64))
    light, dist = sample_light(meta, depth, mask, (32, 32), "s.json")
    assert dist == pytest.approx(0.8)
    direct = light_channels(Rig(), projection.crop_intrinsics(k, (0, 0, 64, 64), (32, 32)), (32, 32), 0.8)
    np.testing.assert_allclose(light.numpy(), direct, rtol=1e-6)  # radiance 2 divides out


def test_per_map_light_picks_each_maps_region():
    light = torch.arange(9.0).reshape(1, 9, 1, 1).expand(2, 9, 2, 2)
    out = per_map_light(light, (0, 1, 2, 0, 1, 2, 0, 1, 2))
    assert out.shape == (2, 9, 3, 2, 2)
    assert out[1, 4, :, 0, 1].tolist() == [3.0, 4.0, 5.0]
