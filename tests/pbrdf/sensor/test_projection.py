import math

import numpy as np
import pytest

from pbrdf.sensor import projection as pj


def test_rays_project_back_to_pixel_centres(rng):
    k = pj.pinhole_intrinsics(123.4, 64, 48, cx=30.2, cy=25.7)
    rays = pj.pixel_rays(k, 48, 64)
    depth = rng.uniform(0.3, 2.0, size=(48, 64, 1))
    uv, d = pj.camera_to_pixel(rays * depth, k)
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5, indexing="xy")
    np.testing.assert_allclose(uv[..., 0], jj, atol=1e-9)
    np.testing.assert_allclose(uv[..., 1], ii, atol=1e-9)
    np.testing.assert_allclose(d, depth[..., 0], rtol=1e-12)


def test_field_of_view_of_the_rig_camera():
    # FLIR BFS-U3-51S5PC-C: 2448 px at 3.45 um behind an 8 mm lens; the left edge's ray makes
    # half the horizontal FOV, 2 atan(8.4456 / 16) / 2 = 27.83 deg, with the optical axis.
    f_px = 8e-3 / 3.45e-6
    k = pj.pinhole_intrinsics(f_px, 2448, 2048)
    edge = np.array([-(2448 / 2) / f_px, 0.0, -1.0])
    uv, _ = pj.camera_to_pixel(edge, k)
    assert uv == pytest.approx([0.0, 1024.0], abs=1e-9)
    assert math.degrees(math.atan(-edge[0])) == pytest.approx(math.degrees(math.atan(8.4456 / 16)), abs=1e-9)


def test_points_behind_the_camera_are_nan():
    k = pj.pinhole_intrinsics(100.0, 10, 10)
    uv, d = pj.camera_to_pixel([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]], k)
    assert np.all(np.isnan(uv)) and np.all(d <= 0)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        pj.camera_to_pixel([1.0, 2.0], k)


def test_crop_and_resize_keeps_pixel_centres():
    k = np.array([[100.0, 0, 32.0], [0, 100.0, 24.0], [0, 0, 1]])
    rays = pj.pixel_rays(k, 48, 64)
    # Cropping rows 8..40, cols 16..48 and resizing 32 -> 16: the new pixel (i, j) covers old pixels
    # 2i..2i+1 of the crop, so its ray is the mean of those four rays' (linear) positions.
    k2 = pj.crop_intrinsics(k, (8, 16, 40, 48), (16, 16))
    small = pj.pixel_rays(k2, 16, 16)
    big = rays[8:40, 16:48].reshape(16, 2, 16, 2, 3).mean((1, 3))
    np.testing.assert_allclose(small, big, atol=1e-12)
    # without resizing only the principal point moves
    np.testing.assert_allclose(pj.crop_intrinsics(k, (8, 16, 40, 48)), [[100, 0, 16], [0, 100, 16], [0, 0, 1]])


def test_rigid_inverse(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    m = np.eye(4)
    m[:3, :3] = q
    m[:3, 3] = rng.normal(size=3)
    np.testing.assert_allclose(pj.rigid_inverse(m) @ m, np.eye(4), atol=1e-12)
    p = rng.normal(size=(5, 3))
    np.testing.assert_allclose(pj.transform_points(pj.rigid_inverse(m), pj.transform_points(m, p)), p, atol=1e-12)
