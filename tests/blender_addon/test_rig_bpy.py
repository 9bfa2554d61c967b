"""The display-camera rig in real Blender (bpy 5.0 wheel) against the bpy-free rig spec.

Blender's side is read through Blender's own machinery (world matrices after a depsgraph update,
``calc_matrix_camera``, ``world_to_camera_view``, a Cycles render), never through the add-on's
conversion helpers, so the checks are independent of the code under test.
"""

import dataclasses
import json
import math

import numpy as np
import pytest

# The add-on registered once per module (tests/conftest.py), an empty Blender file for each test.
pytestmark = [pytest.mark.bpy, pytest.mark.usefixtures("addon_registered", "empty_blend_file")]
bpy = pytest.importorskip("bpy")

from blender_addon import rig_bpy  # noqa: E402
from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig  # noqa: E402
from tests.helpers import world_matrix  # noqa: E402


def _rot(axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(4)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def _custom_rig():
    to_world = _rot("y", 0.3) @ _rot("x", -0.2)
    to_world[:3, 3] = (0.02, -0.03, 0.01)
    display = DisplaySpec(curvature_radius=1.0, center=(0.05, 0.1, 0.08), yaw=0.2, pitch=-0.1, radiance=3.5)
    camera = CameraSpec(
        sensor_width_px=1224, sensor_height_px=1024, pixel_pitch=6.9e-6, focal_length=0.012, to_world=to_world
    )
    return Rig(display=display, camera=camera)


def _in_root(root, obj):
    """Blender's world matrix of ``obj`` expressed in the root's frame."""
    return np.linalg.inv(world_matrix(root)) @ world_matrix(obj)


def _vertices_in_root(root, obj):
    v = np.array([tuple(x.co) for x in obj.data.vertices], dtype=np.float64)
    m = _in_root(root, obj)
    return v @ m[:3, :3].T + m[:3, 3]


def test_add_rig_operator_creates_the_rig():
    assert bpy.ops.pdir.add_rig() == {"FINISHED"}
    scene = bpy.context.scene
    root = rig_bpy.find_rig_root(scene)
    cam, disp = rig_bpy.rig_parts(root)
    assert root.type == "EMPTY" and cam.type == "CAMERA" and disp.type == "MESH"
    assert cam.parent == root and disp.parent == root
    assert scene.camera == cam
    # The default settings are the default rig, bit for bit.
    assert rig_bpy.rig_from_blender(root) == Rig()
    # A second call updates the same rig instead of adding another one.
    assert bpy.ops.pdir.add_rig() == {"FINISHED"}
    assert sum(o.get(rig_bpy.ROLE_KEY) == rig_bpy.ROLE_ROOT for o in bpy.data.objects) == 1
    assert len(bpy.data.objects) == 3


def test_root_looks_along_blender_y():
    root = rig_bpy.add_rig(bpy.context.scene, Rig())
    cam, _ = rig_bpy.rig_parts(root)
    view = world_matrix(cam)[:3, :3] @ np.array([0.0, 0.0, -1.0])
    up = world_matrix(cam)[:3, :3] @ np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(view, [0.0, 1.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(up, [0.0, 0.0, 1.0], atol=1e-7)


@pytest.mark.parametrize("rig", [Rig(), _custom_rig()], ids=["default", "curved_rotated"])
def test_rig_matches_spec(rig):
    scene = bpy.context.scene
    root = rig_bpy.add_rig(scene, rig)
    cam, disp = rig_bpy.rig_parts(root)
    spec_cam, spec_disp = rig.camera, rig.display

    # Camera pose: Blender's camera looks down its local -z with y up, like the OpenGL camera frame.
    np.testing.assert_allclose(_in_root(root, cam), spec_cam.camera_to_world(), atol=1e-6)
    # Intrinsics through Blender's own projection matrix and FOV.
    w, h = spec_cam.sensor_width_px, spec_cam.sensor_height_px
    assert (scene.render.resolution_x, scene.render.resolution_y) == (w, h)
    proj = np.array(cam.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(), x=w, y=h))
    assert 2 * math.atan(1 / proj[0, 0]) == pytest.approx(spec_cam.fov_x, abs=1e-6)
    assert 2 * math.atan(1 / proj[1, 1]) == pytest.approx(spec_cam.fov_y, abs=1e-6)
    assert cam.data.angle_x == pytest.approx(spec_cam.fov_x, abs=1e-6)
    assert proj[0, 2] == pytest.approx(0.0, abs=1e-9) and proj[1, 2] == pytest.approx(0.0, abs=1e-9)

    # Pixel projection of random points in view: Blender's world_to_camera_view vs CameraSpec.project.
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    rng = np.random.default_rng(0)
    uv_true = rng.uniform([0, 0], [w, h], (20, 2))
    depth = rng.uniform(0.3, 2.0, 20)
    f = spec_cam.focal_length_px
    pc = np.stack([(uv_true[:, 0] - w / 2) / f * depth, (h / 2 - uv_true[:, 1]) / f * depth, -depth], axis=-1)
    m = spec_cam.camera_to_world()
    points = pc @ m[:3, :3].T + m[:3, 3]  # rig frame
    uv_spec, depth_spec = spec_cam.project(points)
    np.testing.assert_allclose(uv_spec, uv_true, atol=1e-6)
    root_w = world_matrix(root)
    blender_pts = points @ root_w[:3, :3].T + root_w[:3, 3]
    ndc = np.array([tuple(world_to_camera_view(scene, cam, Vector(p))) for p in blender_pts])
    uv_blender = np.stack([ndc[:, 0] * w, (1.0 - ndc[:, 1]) * h], axis=-1)
    np.testing.assert_allclose(uv_blender, uv_spec, atol=2e-3)  # float32 matrices: about 1e-4 px measured
    np.testing.assert_allclose(ndc[:, 2], depth_spec, rtol=1e-5)

    # Display: corners from the mesh's world-space vertices, all vertices on the spec's surface.
    verts = _vertices_in_root(root, disp)
    for corner in spec_disp.corners_world():
        assert np.min(np.linalg.norm(verts - corner, axis=1)) < 1e-6
    local = (verts - np.asarray(spec_disp.center)) @ spec_disp.world_trans_display()  # display-local
    np.testing.assert_allclose(np.abs(local[:, 1]), spec_disp.height / 2, atol=1e-6)
    if spec_disp.curvature_radius is None:
        np.testing.assert_allclose(local[:, 2], 0.0, atol=1e-6)
        assert len(verts) == 4
    else:
        r = spec_disp.curvature_radius
        np.testing.assert_allclose(np.hypot(local[:, 0], local[:, 2] - r), r, atol=1e-6)
        arc = r * np.arctan2(local[:, 0], r - local[:, 2])
        assert arc.min() == pytest.approx(-spec_disp.width / 2, abs=1e-6)
        assert arc.max() == pytest.approx(spec_disp.width / 2, abs=1e-6)
        assert len(verts) >= 2 * 60  # facets of at most 1 degree over 69 degrees of arc
    # Front faces face the objects: their normals along the spec's normal at the centre (+-70 deg).
    bpy.context.view_layer.update()
    normals = np.array([tuple(p.normal) for p in disp.data.polygons])
    normals = normals @ _in_root(root, disp)[:3, :3].T
    assert np.all(normals @ spec_disp.normal_world() > math.cos(math.radians(70)))

    # The spec read back from Blender is the rig, exactly.
    assert rig_bpy.rig_from_blender(root) == rig


def test_pattern_texture_and_brightness():
    rig = Rig(display=DisplaySpec(radiance=2.5))
    root = rig_bpy.add_rig(bpy.context.scene, rig)
    _, disp = rig_bpy.rig_parts(root)
    tex, emission = rig_bpy.display_nodes(disp)
    img = tex.image
    assert tex.interpolation == "Closest"
    assert img.colorspace_settings.name == "Non-Color"
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    expected = rig.display.pattern_image()
    np.testing.assert_array_equal(px.reshape(h, w, 4)[::-1, :, :3], expected)
    assert emission.inputs["Strength"].default_value == pytest.approx(2.5, rel=1e-7)
    # UVs: u runs along the display's X (left to right seen from the front), v along Y (up).
    mesh = disp.data
    uv = np.array([tuple(d.uv) for d in mesh.uv_layers.active.data])
    loops = np.array([lp.vertex_index for lp in mesh.loops])
    xy = np.array([tuple(v.co)[:2] for v in mesh.vertices])[loops]
    np.testing.assert_allclose(uv[:, 0], xy[:, 0] / rig.display.width + 0.5, atol=1e-6)
    np.testing.assert_allclose(uv[:, 1], xy[:, 1] / rig.display.height + 0.5, atol=1e-6)


def test_render_shows_the_pattern_seen_from_the_front(tmp_path):
    """Cycles render of the display through a camera turned to face it, against pattern_rgb_at."""
    to_world = _rot("y", math.pi)
    to_world[:3, 3] = (0.0, 0.0, -0.6)  # 0.65 m in front of the display, looking along +z at it
    w, h = 48, 40
    camera = CameraSpec(sensor_width_px=w, sensor_height_px=h, pixel_pitch=3.45e-6 * 2448 / w, to_world=to_world)
    rig = Rig(display=DisplaySpec(radiance=0.8), camera=camera)
    scene = bpy.context.scene
    rig_bpy.add_rig(scene, rig)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 0.01
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "display.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(tmp_path / "display.exr"))
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    rendered = px.reshape(h, w, 4)[::-1, :, :3]  # row 0 = top
    # Independent expectation: the ray through each pixel centre hits the flat display plane.
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    f = camera.focal_length_px
    d_cam = np.stack([(u - w / 2) / f, (h / 2 - v) / f, -np.ones_like(u)], axis=-1)
    m = camera.camera_to_world()
    d = d_cam @ m[:3, :3].T
    t = (rig.display.center[2] - m[2, 3]) / d[..., 2]
    hit = m[:3, 3] + t[..., None] * d
    local = (hit - np.asarray(rig.display.center)) @ rig.display.world_trans_display()
    expected = rig.display.radiance * rig.display.pattern_rgb_at(local[..., :2])
    # Skip the pixels the centre lines of the pattern cross (box filter straddles them).
    keep = (np.abs(u - w / 2) > 1) & (np.abs(v - h / 2) > 1)
    np.testing.assert_allclose(rendered[keep], expected[keep], atol=1e-3)
    # Seen from the front: red on the right, blue on top (the spec's convention, in the image).
    assert rendered[5, -5, 0] > 0.5 and rendered[5, 5, 0] < 1e-3
    assert rendered[5, 5, 2] > 0.5 and rendered[-5, 5, 2] < 1e-3


def test_settings_edit_only_their_field():
    scene = bpy.context.scene
    root = rig_bpy.add_rig(scene, Rig())
    rig_bpy.settings_from_rig(scene.pdir_rig, Rig())
    _, disp = rig_bpy.rig_parts(root)
    disp.location = (0.1, -0.05, 0.2)  # moved in the viewport (rig frame = parent frame)
    scene.pdir_rig.display_width = 1.0
    assert scene.pdir_rig.error == ""
    rig = rig_bpy.rig_from_blender(root)
    assert rig.display.width == 1.0  # the typed decimal, not its float32 neighbour
    np.testing.assert_allclose(rig.display.center, (0.1, -0.05, 0.2), atol=1e-6)  # the move survives
    verts = _vertices_in_root(root, disp)
    for corner in rig.display.corners_world():
        assert np.min(np.linalg.norm(verts - corner, axis=1)) < 1e-6
    np.testing.assert_allclose(scene.pdir_rig.display_center, (0.1, -0.05, 0.2), atol=1e-6)  # panel synced

    scene.pdir_rig.camera_focal_length = 12.0
    cam, _ = rig_bpy.rig_parts(root)
    assert cam.data.lens == pytest.approx(12.0) and rig_bpy.rig_from_blender(root).camera.focal_length == 0.012
    scene.pdir_rig.camera_pixel_pitch = 6.9
    assert rig_bpy.rig_from_blender(root).camera.pixel_pitch == 6.9e-6
    scene.pdir_rig.display_polarization_angle = math.radians(45.0)
    assert rig_bpy.rig_from_blender(root).display.polarization_angle == math.radians(45.0)

    # An invalid combination is reported in the panel and leaves the rig as it was.
    before = rig_bpy.rig_from_blender(root)
    scene.pdir_rig.display_curved = True
    scene.pdir_rig.display_curvature_radius = 0.2
    assert "curvature_radius" in scene.pdir_rig.error
    assert rig_bpy.rig_from_blender(root).display.curvature_radius == 1.0
    scene.pdir_rig.display_curvature_radius = 0.5
    assert scene.pdir_rig.error == ""
    assert rig_bpy.rig_from_blender(root) == dataclasses.replace(
        before, display=dataclasses.replace(before.display, curvature_radius=0.5)
    )


def test_live_edits_and_unrepresentable_poses():
    root = rig_bpy.add_rig(bpy.context.scene, Rig())
    cam, disp = rig_bpy.rig_parts(root)
    disp.rotation_euler = (0.1, math.pi + 0.25, 0.0)  # XYZ Euler: pitch-like then yaw-like
    rig = rig_bpy.rig_from_blender(root)
    np.testing.assert_allclose(rig.display.display_to_world(), _in_root(root, disp), atol=1e-6)
    cam.data.lens = 16.0
    cam.location = (0.0, 0.0, 0.1)
    rig = rig_bpy.rig_from_blender(root)
    assert rig.camera.focal_length == pytest.approx(0.016, rel=1e-6)
    np.testing.assert_allclose(rig.camera.camera_to_world(), _in_root(root, cam), atol=1e-6)
    disp.rotation_euler = (0.0, math.pi, 0.3)  # a roll about the display normal
    with pytest.raises(ValueError, match="rolled"):
        rig_bpy.rig_from_blender(root)
    disp.rotation_euler = (0.0, math.pi, 0.0)
    disp.scale = (2.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="scaled"):
        rig_bpy.rig_from_blender(root)


def test_rig_json_operators(tmp_path):
    with pytest.raises(RuntimeError, match="No display-camera rig"):
        bpy.ops.pdir.rig_to_json(filepath=str(tmp_path / "none.json"))
    partial = tmp_path / "partial.json"
    partial.write_text(json.dumps({"camera": {"focal_length": 0.012}, "display": {"curvature_radius": 1.0}}))
    assert bpy.ops.pdir.rig_from_json(filepath=str(partial)) == {"FINISHED"}
    scene = bpy.context.scene
    root = rig_bpy.find_rig_root(scene)
    cam, _ = rig_bpy.rig_parts(root)
    assert cam.data.lens == pytest.approx(12.0)
    assert scene.pdir_rig.camera_focal_length == pytest.approx(12.0)
    assert scene.pdir_rig.display_curved
    out = tmp_path / "rig.json"
    assert bpy.ops.pdir.rig_to_json(filepath=str(out)) == {"FINISHED"}
    expected = Rig.from_dict({"camera": {"focal_length": 0.012}, "display": {"curvature_radius": 1.0}})
    assert Rig.load(out) == expected
    bad = tmp_path / "bad.json"
    bad.write_text('{"camera": {"focal_length": -1}}')
    with pytest.raises(RuntimeError, match="focal_length"):
        bpy.ops.pdir.rig_from_json(filepath=str(bad))
    assert Rig.load(out) == rig_bpy.rig_from_blender(root)  # unchanged by the failed load


def test_pattern_file_from_the_panel(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(1)
    pixels = rng.integers(0, 256, (6, 10, 3), dtype=np.uint8)
    path = tmp_path / "pattern.png"
    Image.fromarray(pixels).save(path)
    scene = bpy.context.scene
    s = scene.pdir_rig
    s.display_pattern = "FILE"
    assert "pattern image file" in s.error  # no file chosen yet
    s.display_pattern_file = str(path)
    s.display_curved = True
    assert s.error == ""
    assert bpy.ops.pdir.add_rig() == {"FINISHED"}  # a new rig takes the panel settings
    root = rig_bpy.find_rig_root(scene)
    rig = rig_bpy.rig_from_blender(root)
    assert rig.display.pattern == str(path) and rig.display.curvature_radius == 1.0
    tex, _ = rig_bpy.display_nodes(rig_bpy.rig_parts(root)[1])
    img = tex.image
    assert tuple(img.size) == (10, 6) and img.colorspace_settings.name == "Non-Color"
    px = np.empty(10 * 6 * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    # Blender's reading of the file (raw values, row 0 at the bottom) equals the spec's (Pillow).
    np.testing.assert_allclose(px.reshape(6, 10, 4)[::-1, :, :3], rig.display.pattern_image(), atol=1e-6)
    s.display_pattern_file = str(tmp_path / "missing.png")
    assert "not found" in s.error
    assert rig_bpy.rig_from_blender(root).display.pattern == str(path)  # unchanged
