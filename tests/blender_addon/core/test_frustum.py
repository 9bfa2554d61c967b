"""Blender camera frustum and depth meshes (blender_addon/core/frustum.py)."""

import numpy as np
import pytest

from blender_addon.core import frustum


class TestFrustum:
    def test_docstring_example(self):
        f = frustum.blender_frustum(4, 2, lens=36, sensor_width=36, sensor_height=24)
        assert (f.half_width, f.half_height) == (0.5, 0.25)
        np.testing.assert_allclose(f.pixel_xy()[0, 0], [-0.375, 0.125])

    def test_projection_matches_pinhole_intrinsics(self, rng):
        # independent pinhole model: f_px = lens / sensor_width * W, principal point at the centre
        w, h, lens, sw = 640, 480, 35.0, 36.0
        f = frustum.blender_frustum(w, h, lens=lens, sensor_width=sw, sensor_height=24.0)
        fpx = lens / sw * w
        p = rng.uniform([-1, -1, -5], [1, 1, -1], (50, 3))
        expected = np.stack([w / 2 + fpx * p[:, 0] / -p[:, 2], h / 2 - fpx * p[:, 1] / -p[:, 2]], -1)
        np.testing.assert_allclose(f.project(p), expected, rtol=1e-12)
        xy = f.pixel_xy()
        pts = np.concatenate([xy, -np.ones((h, w, 1))], -1) * 2.5
        np.testing.assert_allclose(f.project(pts)[10, 20], [20.5, 10.5], atol=1e-9)

    def test_fit_modes_and_shift(self):
        portrait = frustum.blender_frustum(2, 4, lens=36, sensor_width=36, sensor_height=24)  # AUTO: width spans height
        assert (portrait.half_width, portrait.half_height) == (0.25, 0.5)
        vert = frustum.blender_frustum(4, 2, lens=24, sensor_width=36, sensor_height=24, sensor_fit="VERTICAL")
        assert (vert.half_width, vert.half_height) == (1.0, 0.5)
        shifted = frustum.blender_frustum(4, 2, lens=36, sensor_width=36, sensor_height=24, shift_x=0.1, shift_y=-0.2)
        assert (shifted.center_x, shifted.center_y) == pytest.approx((0.1, -0.2))  # units of the 1.0-wide axis
        with pytest.raises(ValueError, match="sensor_fit"):
            frustum.blender_frustum(4, 2, lens=36, sensor_width=36, sensor_height=24, sensor_fit="FILL")


class TestDepthMesh:
    def test_constant_depth_is_a_camera_facing_grid(self):
        f = frustum.blender_frustum(6, 4, lens=50, sensor_width=36, sensor_height=24)
        v, faces, uv = frustum.depth_mesh(np.full((4, 6), 3.0), np.ones((4, 6), bool), f)
        assert v.shape == (24, 3) and faces.shape == (2 * 3 * 5, 3)
        np.testing.assert_allclose(v[:, 2], -3.0)
        np.testing.assert_allclose(v[:, :2], f.pixel_xy().reshape(-1, 2) * 3.0)
        e1, e2 = v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]
        assert (np.cross(e1, e2)[:, 2] > 0).all()  # counter-clockwise seen from the camera: normals toward it
        np.testing.assert_allclose(uv[0], [0.5 / 6, 1 - 0.5 / 4])

    def test_holes_and_jumps(self):
        f = frustum.blender_frustum(3, 3, lens=50, sensor_width=36, sensor_height=24)
        valid = np.ones((3, 3), bool)
        valid[0, 0] = False  # top-left block keeps one triangle
        d = np.full((3, 3), 1.0)
        d[:, 2] = 2.0  # right column far away: no triangles across the jump
        v, faces, _ = frustum.depth_mesh(d, valid, f)
        assert len(v) == 8 and len(faces) == 1 + 2
        _, faces, _ = frustum.depth_mesh(d, valid, f, max_jump=2.0)
        assert len(faces) == 1 + 2 + 2 + 2
