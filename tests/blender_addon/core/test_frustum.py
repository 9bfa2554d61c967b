"""Blender camera frustum and depth meshes (blender_addon/core/frustum.py)."""

import json
import re

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

    def test_pixel_aspect_matches_blender(self):
        # pixels of lens 40, sensor 36 x 20, shift (0.1, -0.15), 32 x 24, of the point (0.2, 0.1, -2)
        # as Blender 5.0 projects it (bpy_extras.object_utils.world_to_camera_view)
        blender = {
            ("HORIZONTAL", 1.0, 1.25): (16.355554580688477, 6.7377777099609375),
            ("HORIZONTAL", 1.5, 1.0): (16.355554580688477, 2.133333206176758),
            ("VERTICAL", 1.0, 1.25): (19.0, 6.0),
            ("VERTICAL", 1.5, 1.0): (17.600000381469727, 6.0),
            ("AUTO", 1.5, 1.0): (16.355554580688477, 2.133333206176758),
        }
        for (fit, ax, ay), uv in blender.items():
            f = frustum.blender_frustum(
                32, 24, lens=40, sensor_width=36, sensor_height=20, sensor_fit=fit, shift_x=0.1, shift_y=-0.15,
                pixel_aspect_x=ax, pixel_aspect_y=ay,
            )  # fmt: skip
            np.testing.assert_allclose(f.project(np.array([0.2, 0.1, -2.0])), uv, atol=1e-5, err_msg=fit)


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


def _k_project(k, p):
    """Independent pinhole projection: OpenCV pixels (v down) of Blender camera-frame points (y up, -z ahead)."""
    depth = -p[..., 2]
    return np.stack([k[0, 0] * p[..., 0] / depth + k[0, 2], k[1, 2] - k[1, 1] * p[..., 1] / depth], -1)


# off-centre principal points, non-square images (landscape and portrait)
K_CASES = {
    "landscape": (np.array([[90.5, 0.0, 35.3], [0.0, 90.5, 17.9], [0.0, 0.0, 1.0]]), 64, 40),
    "portrait": (np.array([[120.0, 0.0, 20.2], [0.0, 120.0, 33.7], [0.0, 0.0, 1.0]]), 48, 56),
}


class TestCameraFromIntrinsics:
    @pytest.mark.parametrize("case", K_CASES)
    def test_blender_frustum_of_the_camera_reproduces_k(self, case, rng):
        k, w, h = K_CASES[case]
        cam = frustum.camera_from_intrinsics(k, w, h)
        assert (cam.sensor_width, cam.sensor_fit) == (36.0, "HORIZONTAL")
        assert cam.lens == pytest.approx(36.0 * k[0, 0] / w) and cam.fy_over_fx == 1.0
        f = frustum.blender_frustum(
            w, h, lens=cam.lens, sensor_width=cam.sensor_width, sensor_height=cam.sensor_height,
            sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
        )  # fmt: skip
        p = rng.uniform([-1, -1, -5], [1, 1, -0.5], (200, 3))
        np.testing.assert_allclose(f.project(p), _k_project(k, p), atol=1e-6, rtol=0)
        np.testing.assert_allclose(f.intrinsics(), k, atol=1e-9)
        # the same sensor height fitted vertically is the same camera up to the shift's units
        vert = frustum.blender_frustum(
            w, h, lens=cam.lens, sensor_width=36, sensor_height=cam.sensor_height, sensor_fit="VERTICAL"
        )  # fmt: skip
        assert (vert.half_width, vert.half_height) == pytest.approx((f.half_width, f.half_height))

    def test_principal_point_right_and_below_centre_shifts_left_and_down(self):
        k = np.array([[80.0, 0.0, 34.0], [0.0, 80.0, 26.0], [0.0, 0.0, 1.0]])  # 64 x 48: 2 px right, 2 px down
        cam = frustum.camera_from_intrinsics(k, 64, 48)
        assert cam.shift_x == pytest.approx(-2 / 64) and cam.shift_y == pytest.approx(2 / 64)
        # the optical axis (0, 0, -1) projects onto the principal point
        np.testing.assert_allclose(cam.frustum(64, 48).project(np.array([0.0, 0.0, -1.0])), [34.0, 26.0])

    def test_unequal_focal_lengths_use_fx(self):
        # square pixels only (Blender's pixel aspect breaks multilayer EXR output): fx for both axes
        k = np.array([[60.0, 0.0, 19.3], [0.0, 54.0, 9.8], [0.0, 0.0, 1.0]])
        cam = frustum.camera_from_intrinsics(k, 32, 24)
        assert cam.fy_over_fx == pytest.approx(0.9)
        np.testing.assert_allclose(cam.frustum(32, 24).intrinsics(), [[60, 0, 19.3], [0, 60, 9.8], [0, 0, 1]])

    @pytest.mark.parametrize("case", K_CASES)
    def test_depth_mesh_vertices_project_onto_pixel_centres(self, case, rng):
        k, w, h = K_CASES[case]
        depth = rng.uniform(0.5, 0.6, (h, w))
        valid = rng.uniform(size=(h, w)) > 0.2
        v, faces, _ = frustum.depth_mesh(depth, valid, frustum.camera_from_intrinsics(k, w, h).frustum(w, h))
        rows, cols = np.nonzero(valid)
        np.testing.assert_allclose(_k_project(k, v), np.stack([cols + 0.5, rows + 0.5], -1), atol=1e-6, rtol=0)
        np.testing.assert_allclose(-v[:, 2], depth[valid])
        assert len(faces) > 0

    @pytest.mark.parametrize(
        ("k", "w", "h", "match"),
        [
            ([[80, 0.5, 32], [0, 80, 24], [0, 0, 1]], 64, 48, "intrinsics: not a pinhole matrix"),
            ([[80, 0, 32], [0, 80, 24], [0, 0.1, 1]], 64, 48, "intrinsics: not a pinhole matrix"),
            ([[80, 0, 32], [0, -80, 24], [0, 0, 1]], 64, 48, "intrinsics: focal lengths must be positive"),
            ([[80, 0, 32], [0, 80, float("nan")], [0, 0, 1]], 64, 48, "intrinsics: must be a finite 3x3"),
            ([[80, 0, 32], [0, 80, 24]], 64, 48, "intrinsics: must be a finite 3x3"),
            ([[1.0, 0, 32], [0, 1.0, 24], [0, 0, 1]], 64, 48, r"intrinsics: outside .*\(lens 0.5625 mm"),
            ([[80, 0, 32], [0, 80, 24], [0, 0, 1]], 0, 48, "width: must be a positive integer"),
            ([[80, 0, 32], [0, 80, 24], [0, 0, 1]], 64, 2.5, "height: must be a positive integer"),
        ],
    )
    def test_refuses_what_blender_cannot_hold(self, k, w, h, match):
        with pytest.raises(ValueError, match=match):
            frustum.camera_from_intrinsics(k, w, h)


class TestCameraJson:
    K = [[90.5, 0.0, 35.3], [0.0, 90.5, 17.9], [0.0, 0.0, 1.0]]

    def _write(self, tmp_path, doc, name="cap_camera.json"):
        path = tmp_path / name
        path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        return path

    def test_reads_the_infer_record(self, tmp_path):
        # pbrdf.data.predictions.CameraRecord's layout
        path = self._write(tmp_path, {"intrinsics": self.K, "width": 64, "height": 40, "distance_m": 0.8})
        cam = frustum.read_camera_json(path)
        assert (cam.width, cam.height, cam.distance_m) == (64, 40, 0.8)
        np.testing.assert_array_equal(cam.intrinsics, self.K)
        assert cam.blender == frustum.camera_from_intrinsics(self.K, 64, 40)
        no_distance = self._write(tmp_path, {"intrinsics": self.K, "width": 64, "height": 40, "distance_m": None})
        assert frustum.read_camera_json(no_distance).distance_m is None

    @pytest.mark.parametrize(
        ("change", "field"),
        [
            ({"intrinsics": [[1, 2, 3]]}, "intrinsics"),
            ({"intrinsics": [[90.5, 0, 35.3], [0, 90.5, "17.9"], [0, 0, 1]]}, "intrinsics"),
            ({"intrinsics": [[90.5, 0, 35.3], [0, 90.5, 17.9], [1, 0, 1]]}, "intrinsics"),
            ({"width": "64"}, "width"),
            ({"height": 0}, "height"),
            ({"height": None}, "height"),
            ({"distance_m": -1.0}, "distance_m"),
            ({"distance_m": True}, "distance_m"),
        ],
    )
    def test_malformed_fields_are_named(self, tmp_path, change, field):
        doc = {"intrinsics": self.K, "width": 64, "height": 40, "distance_m": 0.8} | change
        path = self._write(tmp_path, doc)
        with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: {field}: ") as info:
            frustum.read_camera_json(path)
        assert "\n" not in str(info.value)

    def test_missing_field_and_bad_json(self, tmp_path):
        path = self._write(tmp_path, {"intrinsics": self.K, "height": 40})
        with pytest.raises(ValueError, match=r"cap_camera.json: width: missing$"):
            frustum.read_camera_json(path)
        for text in ("{", "[1, 2]"):
            path = self._write(tmp_path, text)
            with pytest.raises(ValueError, match=r"cap_camera.json: (invalid JSON|expected a JSON object)"):
                frustum.read_camera_json(path)
