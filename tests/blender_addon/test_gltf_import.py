"""The reconstruction's .glb (pbrdf/data/gltf_asset.py) through Blender's own glTF importer (the bpy 5.0 wheel).

Blender ignores the file's TANGENT and builds MikkTSpace tangents from the UVs; the shading normal
it rebuilds from the normal map at the vertices must still be the predicted normal, both by our
formula on Blender's tangents and as Cycles evaluates the imported material (a normal bake).
"""

import numpy as np
import pytest

pytestmark = pytest.mark.bpy
bpy = pytest.importorskip("bpy")

from bpy_extras.object_utils import world_to_camera_view  # noqa: E402

from pbrdf.data.gltf_asset import write_gltf_asset  # noqa: E402
from pbrdf.sensor.projection import camera_to_pixel  # noqa: E402
from tests.gltf_helpers import attributes, image, read_glb, sphere_prediction  # noqa: E402

H, W = 40, 56
K = np.array([[60.0, 0.0, 30.0], [0.0, 60.0, 18.5], [0.0, 0.0, 1.0]])  # off-centre: a 60 x 43 viewport


def _to_blender(v):
    """glTF (y up) to Blender (z up), as the importer converts: (x, y, z) -> (x, -z, y)."""
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], -1)


def _get(collection, attr, n, width):
    out = np.zeros(n * width)
    collection.foreach_get(attr, out)
    return out.reshape(n, width) if width > 1 else out


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    import addon_utils

    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_utils.enable("io_scene_gltf2", default_set=True)
    pred = sphere_prediction(np.random.default_rng(5), K, H, W)
    path = write_gltf_asset(tmp_path_factory.mktemp("glb") / "sphere.glb", pred, K, name="sphere")
    assert bpy.ops.import_scene.gltf(filepath=str(path)) == {"FINISHED"}
    objects = {o.type: o for o in bpy.data.objects}
    return pred, read_glb(path.read_bytes()), objects["MESH"], objects["CAMERA"]


def test_mesh_and_camera_keep_the_capture_geometry(imported):
    pred, (doc, blob), obj, cam = imported
    attrs, faces = attributes(doc, blob)
    me = obj.data
    assert (len(me.vertices), len(me.polygons)) == (len(attrs["POSITION"]), len(faces))
    co = _get(me.vertices, "co", len(me.vertices), 3)
    world = co @ np.array(obj.matrix_world)[:3, :3].T + np.array(obj.matrix_world)[:3, 3]
    # in the imported camera's frame the vertices are the file's (camera-frame) positions
    cam_inv = np.array(cam.matrix_world.inverted())
    np.testing.assert_allclose(world @ cam_inv[:3, :3].T + cam_inv[:3, 3], attrs["POSITION"], atol=1e-5)
    # Blender's camera at the viewport size puts every vertex on its capture pixel (+ the offset)
    extras = doc["cameras"][0]["extras"]
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = (int(v) for v in extras["viewport_px"])
    scene.render.resolution_percentage = 100
    assert cam.data.angle_y == pytest.approx(doc["cameras"][0]["perspective"]["yfov"], rel=1e-6)
    from mathutils import Vector

    ndc = np.array([world_to_camera_view(scene, cam, Vector(p))[:2] for p in world[:: max(len(world) // 200, 1)]])
    px = np.stack([ndc[:, 0] * scene.render.resolution_x, (1 - ndc[:, 1]) * scene.render.resolution_y], 1)
    want = camera_to_pixel(attrs["POSITION"][:: max(len(world) // 200, 1)], K)[0] + extras["capture_offset_px"]
    np.testing.assert_allclose(px, want, atol=1e-3)
    assert extras["capture_offset_px"] == [0.0, 3.0]


def test_material_node_tree(imported):
    _, (doc, blob), obj, _ = imported
    mat = obj.data.materials[0]
    nodes = mat.node_tree.nodes
    bsdf = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    links = {(lk.to_node.name, lk.to_socket.name): lk for lk in mat.node_tree.links}

    def source(node, socket):
        return links[(node.name, socket)].from_node

    base = source(bsdf, "Base Color")
    assert base.bl_idname == "ShaderNodeTexImage" and base.image.colorspace_settings.name == "sRGB"
    assert source(bsdf, "Alpha").bl_idname == "ShaderNodeMath"  # the importer's alpha cut (MASK at 0.5)
    sep = source(bsdf, "Roughness")
    assert sep.name == source(bsdf, "Metallic").name and sep.bl_idname == "ShaderNodeSeparateColor"
    assert links[(bsdf.name, "Roughness")].from_socket.name == "Green"
    assert links[(bsdf.name, "Metallic")].from_socket.name == "Blue"
    assert source(sep, "Color").image.colorspace_settings.name == "Non-Color"
    nmap = source(bsdf, "Normal")
    assert nmap.bl_idname == "ShaderNodeNormalMap" and nmap.space == "TANGENT"
    tex = source(nmap, "Color")
    assert tex.image.colorspace_settings.name == "Non-Color"
    # the image Blender holds is the file's (rows bottom-up, float)
    h, w = tex.image.size[1], tex.image.size[0]
    pixels = np.array(tex.image.pixels[:]).reshape(h, w, 4)[::-1, :, :3]
    np.testing.assert_allclose(pixels, image(doc, blob, 2) / 255.0, atol=1e-6)
    assert mat.use_backface_culling  # doubleSided false


def test_blender_tangent_frame_rebuilds_the_predicted_normals(imported):
    pred, (doc, blob), obj, _ = imported
    me = obj.data
    attrs, _ = attributes(doc, blob)
    me.calc_tangents(uvmap=me.uv_layers[0].name)
    n = len(me.loops)
    tangent, sign = _get(me.loops, "tangent", n, 3), _get(me.loops, "bitangent_sign", n, 1)
    normal = _get(me.corner_normals, "vector", n, 3)
    vi = _get(me.loops, "vertex_index", n, 1).astype(int)
    # MikkTSpace agrees with the exported frame: same handedness, tangents within a few degrees
    ours = _to_blender(attrs["TANGENT"][:, :3])[vi]
    assert (sign == attrs["TANGENT"][vi, 3]).all()
    ang = np.degrees(np.arccos(np.clip((tangent * ours).sum(1), -1, 1)))
    assert np.median(ang) < 0.5 and np.percentile(ang, 95) < 5, np.percentile(ang, [50, 95, 99])
    # the shading normal Blender rebuilds at each vertex (texel centre) is the predicted normal
    y0, x0, y1, x1 = doc["asset"]["extras"]["texture_box_rows_cols"]
    ts = image(doc, blob, 2) / 255.0 * 2 - 1
    uv = attrs["TEXCOORD_0"][vi]
    row, col = np.rint(uv[:, 1] * (y1 - y0) - 0.5).astype(int), np.rint(uv[:, 0] * (x1 - x0) - 0.5).astype(int)
    x = ts[row, col]
    shading = tangent * x[:, :1] + sign[:, None] * np.cross(normal, tangent) * x[:, 1:2] + normal * x[:, 2:]
    shading /= np.linalg.norm(shading, axis=1, keepdims=True)
    inside = pred["mask"][row + y0, col + x0, 0] > 0
    want = _to_blender(pred["normal"][row + y0, col + x0])
    err = np.degrees(np.arccos(np.clip((shading * want).sum(1), -1, 1)))[inside]
    assert np.percentile(err, 99) < 2.0, np.percentile(err, [50, 99, 100])


def test_cycles_bakes_the_predicted_normals_from_the_imported_material(imported):
    """Blender evaluates the imported material itself: Cycles bakes its shading normal (object space) per texel.

    Independent of our decoding: Blender's importer builds the Normal Map node, Cycles computes its
    MikkTSpace tangents and evaluates the node at each texel centre of a bake image of the normal
    map's size; the baked normals, in the capture camera's frame, must be the predicted ones.
    """
    pred, (doc, blob), obj, _ = imported
    th, tw = image(doc, blob, 2).shape[:2]
    target = bpy.data.images.new("baked normals", tw, th, float_buffer=True, alpha=False)
    tree = obj.data.materials[0].node_tree
    node = tree.nodes.new("ShaderNodeTexImage")  # the bake writes into the material's active image node
    node.image = target
    tree.nodes.active = node
    scene = bpy.context.scene
    scene.render.engine, scene.cycles.device, scene.cycles.samples = "CYCLES", "CPU", 1
    for o in scene.objects:
        o.select_set(o == obj)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.object.bake(type="NORMAL", normal_space="OBJECT", margin=0, use_clear=True) == {"FINISHED"}
    baked = np.array(target.pixels[:]).reshape(th, tw, 4)[::-1, :, :3] * 2 - 1  # rows top-down, as the texture
    world = baked @ np.array(obj.matrix_world)[:3, :3].T
    gltf = np.stack([world[..., 0], world[..., 2], -world[..., 1]], -1)  # Blender (z up) back to glTF (y up)
    y0, x0, y1, x1 = doc["asset"]["extras"]["texture_box_rows_cols"]
    inside = pred["mask"][y0:y1, x0:x1, 0] > 0
    # a texel centre is a vertex: Blender's rasteriser leaves some at the mesh's outline (where the relief drops
    # triangles across the rim's depth steps) unbaked, at the cleared value (-1, -1, -1)
    done = np.abs(np.linalg.norm(gltf, axis=-1) - 1) < 0.01
    assert done[inside].mean() > 0.9, done[inside].mean()
    err = np.degrees(np.arccos(np.clip((gltf * pred["normal"][y0:y1, x0:x1]).sum(-1), -1, 1)))[inside & done]
    assert np.percentile(err, 99) < 2.0, np.percentile(err, [50, 99, 100])
    # not the mesh's own normals: those are off by the ripples
    flat = np.degrees(np.arccos(np.clip((gltf * _mesh_normal_grid(doc, blob, th, tw)).sum(-1), -1, 1)))
    assert np.percentile(flat[inside & done], 90) > 5


def _mesh_normal_grid(doc, blob, th, tw):
    """The file's vertex NORMAL at each vertex's texel (``(th, tw, 3)``, zero where no vertex lies)."""
    attrs, _ = attributes(doc, blob)
    uv = attrs["TEXCOORD_0"]
    grid = np.zeros((th, tw, 3))
    grid[np.rint(uv[:, 1] * th - 0.5).astype(int), np.rint(uv[:, 0] * tw - 0.5).astype(int)] = attrs["NORMAL"]
    return grid
