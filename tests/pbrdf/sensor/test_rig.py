"""Rig geometry: camera intrinsics and projection, display pose and pattern orientation, JSON I/O."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig

# Rig defaults (FLIR BFS-U3-51S5PC-C datasheet): IMX250MYR 2448 x 2048 px at 3.45 um, 8 mm lens,
# Samsung Odyssey Ark 55" active area 1209.6 x 680.4 mm.
W, H = 2448, 2048
F_PX = 8e-3 / 3.45e-6  # 2318.84 px


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


class TestCameraDefaults:
    def test_sensor_size_and_fov(self):
        cam = CameraSpec()
        assert cam.sensor_width_m == pytest.approx(8.4456e-3, rel=1e-12)  # 2448 * 3.45 um
        assert cam.sensor_height_m == pytest.approx(7.0656e-3, rel=1e-12)  # 2048 * 3.45 um
        # 2 atan(8.4456 / 16) = 0.9713572 rad = 55.655 deg (the datasheet says about 55.6 deg)
        assert cam.fov_x == pytest.approx(0.9713572, abs=1e-7)
        assert math.degrees(cam.fov_x) == pytest.approx(55.6, abs=0.1)
        # 2 atan(7.0656 / 16) = 47.65 deg
        assert math.degrees(cam.fov_y) == pytest.approx(47.6525, abs=1e-4)

    def test_intrinsics(self):
        k = CameraSpec().intrinsics()
        np.testing.assert_allclose(k, [[F_PX, 0, W / 2], [0, F_PX, H / 2], [0, 0, 1]], rtol=1e-12)

    def test_exposures_and_qwp_come_from_the_camera_model(self):
        cam = CameraSpec()
        assert cam.model == CameraModel()
        assert cam.model.exposures == (0.010, 0.020, 0.100, 0.200)  # the default HDR brackets
        assert cam.model.qwp_angle == 0.0


class TestProject:
    def test_optical_axis_hits_the_sensor_centre(self):
        uv, depth = CameraSpec().project([0.0, 0.0, -0.7])
        np.testing.assert_allclose(uv, [W / 2, H / 2], atol=1e-9)
        assert depth == pytest.approx(0.7)

    def test_view_edges_land_on_pixel_edges(self):
        cam = CameraSpec()
        d = 0.8
        tx, ty = math.tan(cam.fov_x / 2), math.tan(cam.fov_y / 2)
        pts = [[tx * d, 0, -d], [-tx * d, 0, -d], [0, ty * d, -d], [0, -ty * d, -d]]
        uv, _ = cam.project(pts)
        np.testing.assert_allclose(uv, [[W, H / 2], [0, H / 2], [W / 2, 0], [W / 2, H]], atol=1e-9)

    def test_row_zero_is_the_top(self):
        uv, _ = CameraSpec().project([[0.0, 0.1, -0.6], [0.1, 0.0, -0.6]])
        assert uv[0, 1] < H / 2  # above the axis (y > 0) -> upper rows
        assert uv[1, 0] > W / 2  # right of the axis (x > 0) -> right columns

    def test_matches_intrinsics_on_opencv_coordinates(self, rng):
        cam = CameraSpec()
        p = np.column_stack([rng.uniform(-0.3, 0.3, (50, 2)), rng.uniform(-1.0, -0.4, 50)])
        uv, depth = cam.project(p)
        q = (cam.intrinsics() @ (p * [1, -1, -1]).T).T  # OpenGL -> OpenCV camera frame
        np.testing.assert_allclose(uv, q[:, :2] / q[:, 2:], rtol=1e-12)
        np.testing.assert_allclose(depth, -p[:, 2], rtol=0, atol=0)

    def test_behind_the_camera(self):
        cam = CameraSpec()
        uv, depth = cam.project([0.0, 0.0, 0.5])
        assert depth == pytest.approx(-0.5)
        assert np.all(np.isnan(uv))
        assert not Rig().in_view([[0.0, 0.0, 0.5]])
        assert cam.out_of_view_px([[0.0, 0.0, 0.5]]) == math.inf

    def test_posed_camera(self):
        # Camera turned 90 degrees to the left (about +y): it looks along world -x.
        m = np.eye(4)
        m[:3, :3] = _rot_y(math.pi / 2)
        m[:3, 3] = [0.1, 0.2, 0.3]
        cam = CameraSpec(to_world=m)
        uv, depth = cam.project([0.1 - 0.9, 0.2, 0.3])
        np.testing.assert_allclose(uv, [W / 2, H / 2], atol=1e-9)
        assert depth == pytest.approx(0.9)
        np.testing.assert_allclose(cam.world_to_camera() @ cam.camera_to_world(), np.eye(4), atol=1e-12)

    def test_in_view_with_margin(self):
        rig = Rig()
        d = 0.5
        x = (W / 2 - 10) / F_PX * d  # 10 px inside the right edge
        assert rig.in_view([[x, 0, -d]])
        assert rig.in_view([[x, 0, -d]], margin_px=9.5)
        assert not rig.in_view([[x, 0, -d]], margin_px=10.5)
        assert rig.camera.out_of_view_px([[x, 0, -d]]) == pytest.approx(-10.0, abs=1e-9)


class TestDisplayGeometry:
    def test_default_pose_faces_the_objects(self):
        disp = DisplaySpec()
        m = disp.display_to_world()
        # X_d -> -x, Y_d -> +y, Z_d -> -z, origin at the centre (the brief's convention).
        np.testing.assert_allclose(m[:3, :3], np.diag([-1.0, 1.0, -1.0]), atol=0)
        np.testing.assert_allclose(m[:3, 3], [0.0, 0.0, 0.05])
        n = disp.normal_world()
        assert n @ (np.zeros(3) - disp.center) > 0  # toward the camera
        assert n @ (np.array([0.0, 0.0, -0.7]) - disp.center) > 0  # toward the objects

    def test_corners_as_seen_from_the_front(self):
        disp = DisplaySpec()
        w, h = 1.2096 / 2, 0.6804 / 2
        bl, br, tr, tl = disp.corners_world()
        # Seen from the front (from -z looking toward +z), the viewer's right is world -x.
        np.testing.assert_allclose([bl, br, tr, tl], [[w, -h, 0.05], [-w, -h, 0.05], [-w, h, 0.05], [w, h, 0.05]])
        # Counter-clockwise about the front normal.
        n = np.cross(br - bl, tl - bl)
        np.testing.assert_allclose(n / np.linalg.norm(n), disp.normal_world(), atol=1e-12)

    @pytest.mark.parametrize("yaw,pitch", [(0.3, 0.0), (0.0, -0.2), (-0.7, 0.4)])
    def test_pose_is_a_rotation(self, yaw, pitch):
        disp = DisplaySpec(yaw=yaw, pitch=pitch, center=(0.1, -0.2, 0.3))
        r = disp.display_to_world()[:3, :3]
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        np.testing.assert_allclose(disp.corners_world().mean(axis=0), disp.center, atol=1e-12)

    def test_yaw_turns_about_world_y(self):
        # Right-handed yaw of 90 degrees turns the front normal (0, 0, -1) to (-1, 0, 0).
        np.testing.assert_allclose(DisplaySpec(yaw=math.pi / 2).normal_world(), [-1, 0, 0], atol=1e-12)
        np.testing.assert_allclose(DisplaySpec(pitch=math.pi / 2).normal_world(), [0, 1, 0], atol=1e-12)

    def test_polarization_direction(self):
        np.testing.assert_allclose(DisplaySpec().polarization_direction_world(), [0, 1, 0], atol=1e-12)
        # 0 rad = along display +X, which is world -x for the default pose.
        np.testing.assert_allclose(
            DisplaySpec(polarization_angle=0.0).polarization_direction_world(), [-1, 0, 0], atol=1e-12
        )

    def test_curved_corners_on_the_circle_and_arc_length(self):
        radius = 1.0  # 1000R
        disp = DisplaySpec(curvature_radius=radius)
        corners = disp.corners_world()
        axis_point = np.asarray(disp.center) + radius * disp.normal_world()  # centre of curvature
        for c in corners:
            d = c - axis_point
            d -= (d @ [0, 1, 0]) * np.array([0, 1, 0])  # distance perpendicular to the vertical axis
            assert np.linalg.norm(d) == pytest.approx(radius, abs=1e-12)
        bl, br = (corners[:2] - axis_point) * [1, 0, 1]  # horizontal components
        angle = math.acos(np.clip(bl @ br / (np.linalg.norm(bl) * np.linalg.norm(br)), -1, 1))
        assert radius * angle == pytest.approx(1.2096, abs=1e-12)  # spans the width as arc length
        assert np.linalg.norm(corners[0] - corners[1]) < 1.2096  # chord shorter than the arc
        # Concave toward the viewer: the edges come forward (toward the objects, -z).
        assert corners[0][2] < disp.center[2]
        # The centre normal still faces the objects; edge normals tilt toward the axis.
        n = disp.surface_normals_world([[0.6048, 0.0]])[0]
        np.testing.assert_allclose(n, (axis_point - corners[1]) * [1, 0, 1] / radius, atol=1e-12)

    def test_curvature_too_strong(self):
        with pytest.raises(ValueError, match="curvature_radius"):
            DisplaySpec(curvature_radius=1.2096 / math.pi - 1e-3)


class TestPattern:
    def test_quadrants_of_the_image(self):
        img = DisplaySpec().pattern_image()
        assert img.shape == (36, 64, 3) and img.dtype == np.float32
        assert set(np.unique(img)) == {0.0, 1.0}
        # Row 0 = top, column 0 = left, as seen from the front (the pattern quadrants of docs/ARCHITECTURE.md).
        np.testing.assert_array_equal(img[0, 0], [0, 1, 1])  # upper-left cyan
        np.testing.assert_array_equal(img[0, -1], [1, 0, 1])  # upper-right magenta
        np.testing.assert_array_equal(img[-1, 0], [0, 1, 0])  # lower-left green
        np.testing.assert_array_equal(img[-1, -1], [1, 0, 0])  # lower-right red
        # Exact halves.
        assert img[:, :32, 1].all() and not img[:, 32:, 1].any()
        assert img[:, 32:, 0].all() and not img[:, :32, 0].any()
        assert img[:18, :, 2].all() and not img[18:, :, 2].any()

    def test_other_sizes(self):
        img = DisplaySpec().pattern_image(height=4, width=6)
        assert img.shape == (4, 6, 3)
        np.testing.assert_array_equal(img[..., 0], [[0, 0, 0, 1, 1, 1]] * 4)
        assert DisplaySpec(pattern="white").pattern_image().min() == 1.0

    def test_red_is_on_the_right_seen_from_the_front(self):
        disp = DisplaySpec()
        w, h = disp.width / 4, disp.height / 4
        rgb = disp.pattern_rgb_at([[w, -h], [-w, -h], [w, h], [-w, h]])
        np.testing.assert_array_equal(rgb, [[1, 0, 0], [0, 1, 0], [1, 0, 1], [0, 1, 1]])
        # The red half (display +X) is on world -x: to the right of an observer at the objects
        # looking at the display (toward +z), whose right is world -x.
        assert disp.surface_points_world([[w, 0.0]])[0, 0] < 0
        # Outside the active area: black.
        np.testing.assert_array_equal(disp.pattern_rgb_at([[disp.width, 0.0], [0.0, -disp.height]]), 0)

    def test_pattern_from_an_image_file(self, tmp_path):
        # 2x2 image: top row (red, green), bottom row (blue, white).
        a = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], dtype=np.uint8)
        path = tmp_path / "p.png"
        Image.fromarray(a).save(path)
        disp = DisplaySpec(pattern=str(path))
        img = disp.pattern_image()
        np.testing.assert_array_equal(img, a / 255.0)
        assert disp.pattern_image(height=4, width=4).shape == (4, 4, 3)
        w, h = disp.width / 4, disp.height / 4
        np.testing.assert_array_equal(disp.pattern_rgb_at([[-w, h], [w, -h]]), [[1, 0, 0], [1, 1, 1]])

    def test_lit_rectangles_of_the_builtin_patterns(self):
        """rgb_halves (DESIGN.md): red the right half (+X), green the left half, blue the upper half."""
        d = DisplaySpec()
        w, h = d.width / 2, d.height / 2
        expected = [(0.0, w, -h, h), (-w, 0.0, -h, h), (-w, w, 0.0, h)]
        for c in range(3):
            assert d.lit_rectangle(c) == pytest.approx(expected[c], abs=1e-15)
            assert d.lit_rectangle(c, uniform=True) == d.lit_rectangle(c)
        assert DisplaySpec(pattern="white").lit_rectangle(1) == pytest.approx((-w, w, -h, h))

    def test_lit_rectangle_counts_every_nonzero_pixel(self, tmp_path):
        """A dim pixel is light too: the rectangle reaches it, and it is then not uniform."""
        a = np.zeros((4, 8, 3), dtype=np.uint8)
        a[0:2, 0:4] = 255  # a white upper-left block
        path = tmp_path / "p.png"
        Image.fromarray(a).save(path)
        d = DisplaySpec(pattern=str(path))
        block = (-d.width / 2, 0.0, 0.0, d.height / 2)
        assert d.lit_rectangle(0) == pytest.approx(block) and d.lit_rectangle(0, uniform=True) == pytest.approx(block)
        a[3, 7, 0] = 51  # 0.2 in the lower-right corner
        Image.fromarray(a).save(path)
        assert d.lit_rectangle(0) == pytest.approx((-d.width / 2, d.width / 2, -d.height / 2, d.height / 2))
        assert d.lit_rectangle(0, uniform=True) is None
        assert d.lit_rectangle(1, uniform=True) == pytest.approx(block)
        a[:] = 0
        Image.fromarray(a).save(path)
        assert d.lit_rectangle(2) is None

    def test_missing_pattern(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="neither a built-in pattern"):
            DisplaySpec(pattern=str(tmp_path / "nope.png")).pattern_image()
        bad = tmp_path / "bad.png"
        bad.write_text("not an image")
        with pytest.raises(ValueError, match="cannot read"):
            DisplaySpec(pattern=str(bad)).pattern_image()


class TestValidation:
    @pytest.mark.parametrize(
        "kwargs,match",
        [
            ({"width": -1.0}, "display.width"),
            ({"height": 0.0}, "display.height"),
            ({"degree_of_polarization": 1.5}, "degree_of_polarization"),
            ({"resolution": (3840,)}, "resolution"),
            ({"center": (0, 0)}, "display.center"),
            ({"radiance": "bright"}, "display.radiance"),
            ({"yaw": float("nan")}, "display.yaw"),
        ],
    )
    def test_display(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            DisplaySpec(**kwargs)

    @pytest.mark.parametrize(
        "kwargs,match",
        [
            ({"focal_length": 0.0}, "camera.focal_length"),
            ({"sensor_width_px": 10.5}, "sensor_width_px"),
            ({"pixel_pitch": "small"}, "pixel_pitch"),
            ({"to_world": np.diag([2.0, 1, 1, 1])}, "rigid"),
            ({"to_world": np.eye(3)}, "4x4"),
            ({"model": {"qwp_angle": 0.0}}, "CameraModel"),
        ],
    )
    def test_camera(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            CameraSpec(**kwargs)


def _custom_rig() -> Rig:
    m = np.eye(4)
    m[:3, :3] = _rot_y(0.1)
    m[:3, 3] = [0.01, -0.02, 0.0]
    model = CameraModel(qwp_retardance=(1.5, 1.55, 1.6), extinction_ratio=(80.0, float("inf"), 120.0))
    return Rig(
        display=DisplaySpec(curvature_radius=1.0, yaw=0.05, pattern="white", degree_of_polarization=0.97),
        camera=CameraSpec(focal_length=0.0123, to_world=m, model=model),
    )


class TestJson:
    def test_round_trip_exact(self):
        for rig in (Rig(), _custom_rig()):
            d = json.loads(json.dumps(rig.to_dict()))
            back = Rig.from_dict(d)
            assert back == rig
            assert back.to_dict() == rig.to_dict()

    def test_save_load(self, tmp_path):
        rig = _custom_rig()
        path = tmp_path / "sub" / "rig.json"
        rig.save(path)
        assert Rig.load(path) == rig
        assert [p.name for p in path.parent.iterdir()] == ["rig.json"]  # no temporary files left

    def test_partial_override_changes_only_that_number(self):
        rig = Rig.from_dict({"camera": {"focal_length": 0.012}})
        assert rig.camera.focal_length == 0.012
        a, b = Rig().to_dict(), rig.to_dict()
        b["camera"]["focal_length"] = a["camera"]["focal_length"]
        assert a == b
        deep = Rig.from_dict({"camera": {"model": {"sensor": {"gain": 0.4}}}})
        assert deep.camera.model.sensor.gain == 0.4
        assert deep.camera.model.sensor.read_noise == CameraModel().sensor.read_noise
        assert deep.display == DisplaySpec()

    def test_override_on_a_base_rig(self):
        base = _custom_rig()
        rig = Rig.from_dict({"display": {"radiance": 2.0}}, base=base)
        assert rig.display.radiance == 2.0
        assert rig.camera == base.camera and rig.display.curvature_radius == 1.0

    def test_unknown_keys(self):
        with pytest.raises(ValueError, match=r"unknown key 'rig.camera.focal'.*focal_length"):
            Rig.from_dict({"camera": {"focal": 0.01}})
        with pytest.raises(ValueError, match=r"unknown key 'rig.projector'"):
            Rig.from_dict({"projector": {}})
        with pytest.raises(ValueError, match=r"unknown key 'rig.camera.model.sensor.iso'"):
            Rig.from_dict({"camera": {"model": {"sensor": {"iso": 100}}}})

    def test_load_errors(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="rig file not found"):
            Rig.load(tmp_path / "missing.json")
        bad = tmp_path / "bad.json"
        bad.write_text("{ not json")
        with pytest.raises(ValueError, match="invalid JSON"):
            Rig.load(bad)
        wrong = tmp_path / "wrong.json"
        wrong.write_text(json.dumps({"display": {"width": "wide"}}))
        with pytest.raises(ValueError, match=r"wrong.json: display.width must be a number"):
            Rig.load(wrong)
        wrong.write_text(json.dumps({"display": 3}))
        with pytest.raises(ValueError, match=r"rig.display must be a JSON object"):
            Rig.load(wrong)
        wrong.write_text(json.dumps({"camera": {"model": {"exposures": "long"}}}))
        with pytest.raises(ValueError, match=r"camera.model"):
            Rig.load(wrong)


class TestProperties:
    """Hypothesis checks of the geometry over random rigs."""

    @settings(max_examples=60, deadline=None)
    @given(
        yaw=st.floats(-1.5, 1.5),
        pitch=st.floats(-1.0, 1.0),
        u=st.floats(0.0, 2448.0),
        v=st.floats(0.0, 2048.0),
        depth=st.floats(0.1, 5.0),
        focal=st.floats(4e-3, 25e-3),
    )
    def test_project_inverts_back_projection(self, yaw, pitch, u, v, depth, focal):
        # Camera posed like a display with the same yaw/pitch (any rigid pose will do).
        pose = np.eye(4)
        pose[:3, :3] = DisplaySpec(yaw=yaw, pitch=pitch).world_trans_display() @ np.diag([-1.0, 1.0, -1.0])
        pose[:3, 3] = [0.1, -0.05, 0.02]
        cam = CameraSpec(focal_length=focal, to_world=pose)
        f = cam.focal_length_px
        p_cam = np.array([(u - W / 2) / f * depth, (H / 2 - v) / f * depth, -depth, 1.0])
        uv, d = cam.project((pose @ p_cam)[:3])
        np.testing.assert_allclose(uv, [u, v], atol=1e-7)
        assert d == pytest.approx(depth, rel=1e-12)
        assert cam.out_of_view_px((pose @ p_cam)[:3]) <= 1e-7

    @settings(max_examples=40, deadline=None)
    @given(
        key=st.sampled_from(["width", "height", "yaw", "pitch", "radiance", "polarization_angle"]),
        value=st.floats(0.01, 3.0),
    )
    def test_single_display_override(self, key, value):
        rig = Rig.from_dict({"display": {key: value}})
        assert getattr(rig.display, key) == value
        a, b = Rig().to_dict(), rig.to_dict()
        b["display"][key] = a["display"][key]
        assert a == b
        assert Rig.from_dict(json.loads(json.dumps(rig.to_dict()))) == rig
