"""PBR import (blender_addon/pbr_import.py) with the real bpy 5.0 wheel and Cycles (tiny renders)."""

import json
import re
import warnings

import numpy as np
import pytest

# clean_file (tests/conftest.py): the registered add-on and a fresh scene set up for Cycles.
pytestmark = [pytest.mark.bpy, pytest.mark.usefixtures("clean_file")]
bpy = pytest.importorskip("bpy")

from bpy_extras.object_utils import world_to_camera_view  # noqa: E402

from blender_addon import images, pbr_import  # noqa: E402
from blender_addon.core import map_io  # noqa: E402
from blender_addon.core.frustum import blender_frustum, camera_from_intrinsics  # noqa: E402
from pbrdf.io.exr import read_exr  # noqa: E402
from pbrdf.sensor import projection  # noqa: E402
from tests.helpers import add_camera, write_pbr_maps  # noqa: E402

H, W = 24, 32


def _sphere_field(h, w, centre=(0.03, -0.02, -2.0), radius=0.35):
    """Normals, mask and depth of a real sphere seen by the default camera (lens 50, sensor 36)."""
    fr = blender_frustum(w, h, lens=50.0, sensor_width=36.0, sensor_height=24.0)
    d = np.concatenate([fr.pixel_xy(), -np.ones((h, w, 1))], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.asarray(centre)
    b = d @ c
    disc = b * b - (c @ c - radius**2)
    mask = disc > 0
    t = b - np.sqrt(np.maximum(disc, 0))
    p = d * t[..., None]
    n = np.where(mask[..., None], (p - c) / radius, 0.0).astype(np.float32)
    depth = np.where(mask, -p[..., 2], np.inf)
    return n, mask, depth


def _render_passes(scene, path):
    fmt = scene.render.image_settings
    fmt.media_type = "MULTI_LAYER_IMAGE"
    fmt.file_format = "OPEN_EXR_MULTILAYER"
    fmt.color_depth = "32"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return read_exr(path)


def _angles(a, b):
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0)))


# --------------------------------------------------------------------------- import


def test_import_operator_builds_camera_plane(clean_file, tmp_path):
    scene = clean_file
    cam = add_camera(scene, (0.5, -3.0, 1.0), (1.2, 0.0, 0.3))
    n, mask, _ = _sphere_field(H, W)
    alb = np.random.default_rng(0).uniform(0.1, 0.9, (H, W, 3)).astype(np.float32)
    folder = write_pbr_maps(tmp_path / "maps", n, albedo=alb, mask=mask, roughness=np.full((H, W), 0.25))
    assert bpy.ops.pdir.import_pbr(directory=str(folder), distance=2.0) == {"FINISHED"}
    obj = next(o for o in scene.objects if o.type == "MESH")
    assert obj.parent == cam and tuple(obj.scale) == (1.0, 1.0, 1.0)
    assert obj["pdir_maps"] == "normal,albedo,roughness,mask" and obj["pdir_missing"] == "metallic,depth"
    # plane size from the camera: width = sensor_width / lens * distance, height = width * H / W
    xs = [v.co.x for v in obj.data.vertices]
    ys = [v.co.y for v in obj.data.vertices]
    assert max(xs) - min(xs) == pytest.approx(36.0 / 50.0 * 2.0, rel=1e-6)
    assert max(ys) - min(ys) == pytest.approx(36.0 / 50.0 * 2.0 * H / W, rel=1e-6)
    np.testing.assert_allclose(obj.matrix_local.translation, (0, 0, -2.0), atol=1e-7)
    assert (scene.render.resolution_x, scene.render.resolution_y) == (W, H)
    # images: data as Non-Color, albedo linear, values exact (Blender's row 0 is the bottom)
    nodes = obj.active_material.node_tree.nodes
    tex = {n.label: n.image for n in nodes if n.bl_idname == "ShaderNodeTexImage"}
    assert set(tex) == {"normal", "albedo", "roughness", "mask"}
    assert {k: im.colorspace_settings.name for k, im in tex.items()} == {
        "normal": "Non-Color",
        "albedo": "Linear Rec.709",
        "roughness": "Non-Color",
        "mask": "Non-Color",
    }
    px = np.empty(W * H * 4, np.float32)
    tex["albedo"].pixels.foreach_get(px)
    np.testing.assert_array_equal(px.reshape(H, W, 4)[::-1][mask, :3], alb[mask])  # outside: extended (map_io)
    tex["normal"].pixels.foreach_get(px)
    np.testing.assert_allclose(px.reshape(H, W, 4)[::-1][mask, :3], 0.5 + 0.5 * n[mask], atol=1e-6)
    assert all(im.packed_file is not None for im in tex.values())
    nmap = next(n for n in nodes if n.bl_idname == "ShaderNodeNormalMap")
    assert (nmap.space, nmap.uv_map) == ("TANGENT", "UVMap")


def test_import_operator_reports_errors(clean_file, tmp_path):
    n, _, _ = _sphere_field(H, W)
    folder = write_pbr_maps(tmp_path / "amb", n, albedo=np.zeros((H, W, 3), np.float32))
    (folder / "other_diffuse.png").write_bytes(b"")
    with pytest.raises(RuntimeError, match=r"ambiguous map files: 2 files match albedo"):
        bpy.ops.pdir.import_pbr(directory=str(folder))
    (tmp_path / "none").mkdir()
    (tmp_path / "none" / "x_albedo.png").write_bytes(b"")
    with pytest.raises(RuntimeError, match=r"no normal map in"):
        bpy.ops.pdir.import_pbr(directory=str(tmp_path / "none"))
    assert not any(o.type == "MESH" for o in clean_file.objects)


@pytest.mark.parametrize("space", ["TANGENT", "OBJECT"])
def test_rendered_normals_match_input(clean_file, tmp_path, space):
    scene = clean_file
    cam = add_camera(scene, (0.3, -2.0, 0.5), (1.3, 0.1, 0.2))
    n, mask, _ = _sphere_field(H * 2, W * 2)
    obj = pbr_import.import_pbr_maps(
        bpy.context, write_pbr_maps(tmp_path / "s", n, mask=mask), pbr_import.ImportOptions(1.5, normal_space=space)
    )
    # AOV of the Normal Map node's output (the shading normal the BSDF receives)
    nt = obj.active_material.node_tree
    aov = nt.nodes.new("ShaderNodeOutputAOV")
    aov.aov_name = "nmap"
    nt.links.new(
        next(x for x in nt.nodes if x.bl_idname == "ShaderNodeNormalMap").outputs["Normal"], aov.inputs["Color"]
    )
    layer = scene.view_layers[0]
    layer.aovs.add().name = "nmap"
    layer.use_pass_normal = True
    scene.cycles.samples = 2
    ch = _render_passes(scene, tmp_path / "passes.exr")
    world_to_cam = np.array(cam.matrix_world.to_3x3())  # row vectors: n_cam = n_world @ R
    normal_pass = np.stack([ch[f"ViewLayer.Normal.{c}"] for c in "XYZ"], -1) @ world_to_cam
    aov_pass = np.stack([ch[f"ViewLayer.nmap.{c}"] for c in "RGB"], -1) @ world_to_cam
    # Cycles bends the specular closure's normal where the mirror reflection would dip below the
    # surface (normals tilted more than ~45 deg from the view on a camera-facing plane), and the
    # Normal pass averages the closures' normals: compare it where the sphere's normals are
    # within 45 deg of the view; the Normal Map node's output (AOV) everywhere.
    view = np.concatenate(
        [
            -blender_frustum(W * 2, H * 2, lens=50, sensor_width=36, sensor_height=24).pixel_xy(),
            np.ones((H * 2, W * 2, 1)),
        ],
        -1,
    )
    cap = mask & (_angles(view, n) < 45.0)
    err_pass, err_aov = _angles(normal_pass, n)[cap], _angles(aov_pass, n)[mask]
    # measured (64 x 48, 2 spp): Normal pass within 45 deg median 0.000, max 0.02 deg (beyond 50 deg
    # p99 0.6, beyond 60 deg 5.6); Normal Map output median 0.000, p99 0.14, max 0.27 deg
    assert cap.sum() > 0.4 * mask.sum()
    assert np.median(err_pass) < 0.1 and err_pass.max() < 0.1
    assert np.median(err_aov) < 0.01 and np.percentile(err_aov, 99) < 0.5


def test_depth_mesh_lies_on_the_surface_and_keeps_normals(clean_file, tmp_path):
    scene = clean_file
    cam = add_camera(scene, (1.0, 0.5, 0.2), (0.2, -0.3, 0.4))
    centre, radius = (0.03, -0.02, -2.0), 0.35
    n, mask, depth = _sphere_field(H, W, centre, radius)
    folder = write_pbr_maps(tmp_path / "d", n, mask=mask, depth=depth)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obj = pbr_import.import_pbr_maps(bpy.context, folder)  # TANGENT requested, OBJECT used
    assert any("OBJECT space" in str(w.message) for w in caught)
    support = map_io.dilate(mask)  # the mesh goes one pixel past the outline (map_io.extend_past_mask)
    assert obj["pdir_normal_space"] == "OBJECT" and len(obj.data.vertices) == support.sum()
    # every vertex of a mask pixel lies on the sphere (camera frame): | p - c | = r
    m = np.array(cam.matrix_world.inverted() @ obj.matrix_world)
    v = np.array([tuple(x.co) for x in obj.data.vertices]) @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(np.linalg.norm(v[mask[support]] - centre, axis=1), radius, rtol=1e-5)
    nt = obj.active_material.node_tree
    aov = nt.nodes.new("ShaderNodeOutputAOV")
    aov.aov_name = "nmap"
    nt.links.new(
        next(x for x in nt.nodes if x.bl_idname == "ShaderNodeNormalMap").outputs["Normal"], aov.inputs["Color"]
    )
    scene.view_layers[0].aovs.add().name = "nmap"
    scene.cycles.samples = 1
    ch = _render_passes(scene, tmp_path / "d.exr")
    covered = ch["ViewLayer.Combined.A"] > 0.999
    got = np.stack([ch[f"ViewLayer.nmap.{c}"] for c in "RGB"], -1) @ np.array(cam.matrix_world.to_3x3())
    err = _angles(got, n)[covered & mask]
    assert covered.sum() > 0.5 * mask.sum() and np.median(err) < 0.1


def test_flat_relief_shades_with_the_normals_it_carries(clean_file, tmp_path):
    """A flat relief (constant depth) carrying tilted normals: Cycles shades with the maps' normals, not the plane's.

    The relief's vertices lie on the pixel centres (a 0.01 px filter samples them) and its
    Normal Map node is unlinked, so the rendered Normal pass is the carried vertex normal: the
    tilts (up to 25 deg, far from the geometry's +z) come back, and the mesh is valid as built.
    """
    scene = clean_file
    cam = add_camera(scene)
    yy, xx = np.mgrid[0:H, 0:W]
    tilt = np.radians(25.0) * np.stack([np.sin(xx / 5.0), np.cos(yy / 4.0)], -1)  # a smooth field of tilts
    n = np.concatenate([np.sin(tilt), np.ones((H, W, 1))], -1)
    n = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    mask = np.zeros((H, W), bool)
    mask[4:-4, 5:-5] = True
    obj = pbr_import.import_pbr_maps(
        bpy.context, write_pbr_maps(tmp_path / "f", n * mask[..., None], mask=mask, depth=np.where(mask, 1.5, 0.0))
    )
    assert obj.data.validate(verbose=False) is False  # nothing to fix: the bulk-written mesh is valid
    corner = np.empty(len(obj.data.loops) * 3, np.float32)
    obj.data.corner_normals.foreach_get("vector", corner)
    support = map_io.dilate(mask)
    vertex = np.empty(len(obj.data.loops), np.int32)
    obj.data.loops.foreach_get("vertex_index", vertex)
    inside = mask[support][vertex]  # corners of mask pixels' vertices (the extension's are extrapolated)
    assert _angles(corner.reshape(-1, 3)[inside], n[support][vertex[inside]]).max() < 0.05
    scene.view_layers[0].use_pass_normal = True
    scene.cycles.samples = 1
    ch = _render_passes(scene, tmp_path / "f.exr")
    rendered = np.stack([ch[f"ViewLayer.Normal.{c}"] for c in "XYZ"], -1) @ np.array(cam.matrix_world.to_3x3())
    inner = ~map_io.dilate(~mask)  # away from the outline
    err = _angles(rendered, n)[inner]
    assert inner.sum() > 200 and np.percentile(err, 99) < 0.1, np.percentile(err, [50, 99, 100])


def test_blender_png_reader_equals_pillow(clean_file, tmp_path):
    # Blender's bundled Python has no Pillow: the add-on then reads PNG maps with Blender's loader
    from PIL import Image

    rgb = np.random.default_rng(3).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "a.png")
    got, is_float = images.read_channels_blender(tmp_path / "a.png")
    ref, _ = map_io.read_channels(tmp_path / "a.png")
    assert not is_float and set(ref) <= set(got)
    for c in "RGB":
        np.testing.assert_allclose(got[c], ref[c], atol=1e-6)
    np.testing.assert_allclose(got["A"], 1.0)
    assert not bpy.data.images  # the temporary image is removed


# --------------------------------------------------------------------------- capture camera and sequences

# a capture camera unlike Blender's default (lens 50 mm, centred): wider view, principal point off centre
K = np.array([[60.0, 0.0, 19.3], [0.0, 60.0, 9.8], [0.0, 0.0, 1.0]])


def _plane_field(k, h, w, normal=(0.2, 0.1, 1.0), point=(0.05, 0.0, -2.0), radius=0.4):
    """Normals, mask and depth of a tilted disc seen through the pinhole ``k`` (no depth jumps)."""
    n = np.asarray(normal) / np.linalg.norm(normal)
    rays = projection.pixel_rays(k, h, w)
    depth = (n @ np.asarray(point)) / (rays @ n)
    mask = np.linalg.norm(rays * depth[..., None] - point, axis=-1) < radius
    normals = np.where(mask[..., None], n, 0.0).astype(np.float32)
    return normals, mask, np.where(mask, depth, np.inf)


def _write_camera(path, k, w, h, distance=2.0):
    """``<prefix>_camera.json`` as ``pbrdf.data.predictions.CameraRecord`` writes it."""
    path.write_text(json.dumps({"intrinsics": k.tolist(), "width": w, "height": h, "distance_m": distance}))


def _k_project(k, p):
    depth = -p[..., 2]
    return np.stack([k[0, 0] * p[..., 0] / depth + k[0, 2], k[1, 2] - k[1, 1] * p[..., 1] / depth], -1)


def _interior(mask):
    """Mask pixels whose 8 neighbours are in the mask too (inside the mesh, off its boundary)."""
    m = np.pad(mask, 1)
    return np.all([m[1 + dy : 1 + dy + mask.shape[0], 1 + dx : 1 + dx + mask.shape[1]]
                   for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)  # fmt: skip


def _camera_frame_vertices(obj, cam):
    m = np.array(cam.matrix_world.inverted() @ obj.matrix_world)
    return np.array([tuple(x.co) for x in obj.data.vertices]) @ m[:3, :3].T + m[:3, 3]


def test_camera_file_gives_the_capture_camera(clean_file, tmp_path):
    scene = clean_file
    cam = add_camera(scene, (0.5, -3.0, 1.0), (1.2, 0.0, 0.3))  # lens 50 mm: not the capture's
    n, mask, depth = _plane_field(K, H, W)
    folder = write_pbr_maps(tmp_path / "c", n, mask=mask, depth=depth)
    _write_camera(folder / "cap_camera.json", K, W, H)
    _write_camera(folder / "other_camera.json", K * [[2], [2], [1]], W, H)  # another capture's: ignored
    # the explicit {kind: file} of blender_addon/reconstruct_operator.py: the camera file is found beside the normal map
    files = {kind: folder / f"cap_{kind}.exr" for kind in ("normal", "mask", "depth")}
    obj = pbr_import.import_pbr_maps(bpy.context, files, pbr_import.ImportOptions(normal_space="OBJECT"))
    assert obj["pdir_camera"] == str(folder / "cap_camera.json")
    want = camera_from_intrinsics(K, W, H)
    data, render = cam.data, scene.render
    assert (data.sensor_fit, data.sensor_width, data.lens_unit) == ("HORIZONTAL", 36.0, "MILLIMETERS")
    assert data.lens == pytest.approx(want.lens, rel=1e-6) and want.lens == pytest.approx(36.0 * 60.0 / W)
    assert (data.shift_x, data.shift_y) == pytest.approx((want.shift_x, want.shift_y), abs=1e-7)
    assert (data.shift_x, data.shift_y) == pytest.approx(((W / 2 - 19.3) / W, (9.8 - H / 2) / W))
    assert (render.pixel_aspect_x, render.pixel_aspect_y) == (1.0, 1.0)
    assert (render.resolution_x, render.resolution_y, render.resolution_percentage) == (W, H, 100)
    # every vertex projects onto its pixel centre: through K, and through Blender's own camera model
    support = map_io.dilate(mask)  # the mesh goes one pixel past the outline (map_io.extend_past_mask)
    rows, cols = np.nonzero(support)
    centres = np.stack([cols + 0.5, rows + 0.5], -1)
    v = _camera_frame_vertices(obj, cam)
    np.testing.assert_allclose(_k_project(K, v), centres, atol=1e-4)  # float32 vertices
    np.testing.assert_allclose(-v[mask[support], 2], depth[mask], rtol=1e-6)
    seen = [world_to_camera_view(scene, cam, obj.matrix_world @ x.co) for x in obj.data.vertices]
    np.testing.assert_allclose([(q.x * W, (1 - q.y) * H) for q in seen], centres, atol=1e-3)
    # and Cycles renders the mesh over the mask's pixel centres, nowhere else
    render.film_transparent = True
    scene.cycles.samples = 1
    covered = _render_passes(scene, tmp_path / "c.exr")["ViewLayer.Combined.A"] > 0.5
    assert covered[_interior(mask)].all() and not covered[~mask].any()


def test_malformed_camera_file_is_refused(clean_file, tmp_path):
    n, mask, _ = _plane_field(K, H, W)
    folder = write_pbr_maps(tmp_path / "m", n, mask=mask)
    path = folder / "cap_camera.json"
    path.write_text(json.dumps({"intrinsics": [[60, 0, 16], [0, 60, 12]], "width": W, "height": H}))
    with pytest.raises(RuntimeError, match=rf"{re.escape(str(path))}: intrinsics: must be a finite 3x3 matrix"):
        bpy.ops.pdir.import_pbr(directory=str(folder))
    _write_camera(path, K, W // 2, H // 2)
    with pytest.raises(RuntimeError, match=r"cap_camera.json: width, height: 16 x 12, but the maps are 32 x 24"):
        bpy.ops.pdir.import_pbr(directory=str(folder))
    assert not clean_file.objects  # nothing imported, no camera made
    assert bpy.ops.pdir.import_pbr(directory=str(folder), use_camera_file=False) == {"FINISHED"}
    obj = next(o for o in clean_file.objects if o.type == "MESH")
    assert obj["pdir_camera"] == "" and clean_file.camera.data.lens == 50.0
    # fx != fy: square pixels with fx, and a warning
    _write_camera(path, K * [[1.0], [1.1], [1.0]], W, H)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obj = pbr_import.import_pbr_maps(bpy.context, folder)
    assert obj["pdir_camera"] == str(path) and clean_file.camera.data.lens == pytest.approx(36 * 60 / W)
    assert any("fx != fy" in str(w.message) and "1.1 of the capture's" in str(w.message) for w in caught)


def test_sequence_plays_its_frames(clean_file, tmp_path):
    scene = clean_file
    cam = add_camera(scene, (0.2, 0.4, -0.1), (0.3, 0.2, -0.5))
    n1, mask, depth = _plane_field(K, H, W)
    n2 = np.where(mask[..., None], np.float32([-0.3, 0.2, 0.9]) / np.linalg.norm([-0.3, 0.2, 0.9]), 0.0)
    folder = tmp_path / "seq"
    frames = {1: (n1, 0.2, 0.3), 2: (n2.astype(np.float32), 0.6, 0.7)}  # normals, albedo, roughness
    for i, (n, albedo, rough) in frames.items():
        write_pbr_maps(folder, n, albedo=np.full((H, W, 3), albedo, np.float32), mask=mask, depth=depth,
                       roughness=np.full((H, W), rough), prefix=f"face_{i:04d}")  # fmt: skip
        _write_camera(folder / f"face_{i:04d}_camera.json", K, W, H)
    doc = {"name": "face", "frames": [{"frame": i, "prefix": f"face_{i:04d}"} for i in frames], "frames_per_second": 1}
    (folder / "face_sequence.json").write_text(json.dumps(doc))
    assert bpy.ops.pdir.import_pbr(directory=str(folder)) == {"FINISHED"}
    obj = next(o for o in scene.objects if o.type == "MESH")
    assert (obj.name, obj["pdir_frames"], len(obj.data.vertices)) == ("face", 2, map_io.dilate(mask).sum())
    assert obj["pdir_camera"] == str(folder / "face_0001_camera.json") and cam.data.shift_x != 0
    assert (scene.frame_start, scene.frame_end, scene.frame_current) == (1, 2, 1)
    nt = obj.active_material.node_tree
    tex = {x.label: x for x in nt.nodes if x.bl_idname == "ShaderNodeTexImage"}
    assert set(tex) == {"normal", "albedo", "roughness", "mask"}
    for node in tex.values():
        u = node.image_user
        assert node.image.source == "SEQUENCE" and node.image.packed_file is None
        assert (u.frame_duration, u.frame_start, u.frame_offset, u.use_auto_refresh) == (2, 1, 0, True)
    assert tex["albedo"].image.colorspace_settings.name == "Linear Rec.709"
    assert tex["normal"].image.colorspace_settings.name == "Non-Color"
    aovs = {"alb": tex["albedo"].outputs["Color"], "rough": tex["roughness"].outputs["Color"]}
    aovs["nmap"] = next(x for x in nt.nodes if x.bl_idname == "ShaderNodeNormalMap").outputs["Normal"]
    for aov_name, socket in aovs.items():
        aov = nt.nodes.new("ShaderNodeOutputAOV")
        aov.aov_name = aov_name
        nt.links.new(socket, aov.inputs["Color"])
        scene.view_layers[0].aovs.add().name = aov_name
    scene.cycles.samples = 1
    inside = _interior(mask)
    world_to_cam = np.array(cam.matrix_world.to_3x3())
    for i, (n, albedo, rough) in frames.items():
        scene.frame_set(i)
        # the evaluated image user follows the frame: Blender numbers "face_0002_albedo.exr" by its 0002
        user = (
            obj.active_material.evaluated_get(bpy.context.evaluated_depsgraph_get())
            .node_tree.nodes[tex["albedo"].name]
            .image_user
        )
        assert user.frame_current == i
        assert tex["albedo"].image.filepath_from_user(image_user=user).endswith(f"face_{i:04d}_albedo.exr")
        ch = _render_passes(scene, tmp_path / f"frame{i}.exr")
        np.testing.assert_allclose(np.stack([ch[f"ViewLayer.alb.{c}"] for c in "RGB"], -1)[inside], albedo, atol=1e-6)
        np.testing.assert_allclose(ch["ViewLayer.rough.R"][inside], rough, atol=1e-6)
        got = np.stack([ch[f"ViewLayer.nmap.{c}"] for c in "RGB"], -1) @ world_to_cam
        assert _angles(got, n)[inside].max() < 0.05  # raw EXR normals encoded for the Normal Map node
