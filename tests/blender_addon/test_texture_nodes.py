"""Textured materials in the add-on: spec -> Image Texture nodes -> spec, and what Blender samples.

Blender's own evaluation of the node tree is the independent reference: a Cycles bake (EMIT,
one sample, at texel centres) of the socket feeding each Principled input on a unit quad whose
UVs span [0, 1]^2, compared with the texture's definition evaluated here (sRGB decoding by
IEC 61966-2-1, glTF's channel layout, ``KHR_texture_transform`` from the glTF spec's matrices,
bilinear lookup at texel centres with wrapping), never with the add-on's own conversion.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

pytestmark = pytest.mark.bpy
bpy = pytest.importorskip("bpy")
trimesh = pytest.importorskip("trimesh")
PIL = pytest.importorskip("PIL.Image")

from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from blender_addon.core.textures import MaterialTextures, TextureSpec, texture_array  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402
from tests.blender_addon.core.test_asset_materials import write_gltf  # noqa: E402
from tests.helpers import rigid_pose, rot_x  # noqa: E402


@pytest.fixture(autouse=True)
def cache_dir(tmp_path, monkeypatch):
    """Embedded and exported images go to a folder of the test, never to the user's cache."""
    monkeypatch.setenv("PBRDF_CACHE", str(tmp_path / "cache"))


def _srgb_to_linear(c):  # IEC 61966-2-1
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _smooth_png(path, size, seed):
    """A tileable smooth 8-bit RGB image (low-frequency waves), so bilinear lookups are nearly exact."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    chans = [
        0.5 + 0.4 * np.sin(2 * np.pi * (x + rng.uniform()) + rng.uniform(0, 6)) * np.cos(2 * np.pi * y) for _ in "rgb"
    ]
    arr = np.round(np.stack(chans, -1) * 255).astype(np.uint8)
    PIL.fromarray(arr).save(path)
    return arr


def _bilinear(img, uv):
    """``img`` (H, W, C), row 0 at the top, sampled at OpenGL UVs ``(..., 2)`` with texel centres and wrap."""
    h, w = img.shape[:2]
    x, y = uv[..., 0] * w - 0.5, (1.0 - uv[..., 1]) * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    at = lambda yy, xx: img[yy % h, xx % w]  # noqa: E731
    return (at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx) * (1 - fy) + (
        at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    ) * fy


def _khr(uv, offset, rotation, scale):
    """KHR_texture_transform from its definition: glTF UVs (v down) ``T R S``; OpenGL UVs in and out."""
    g = np.stack([uv[..., 0], 1.0 - uv[..., 1]], -1)
    c, s = math.cos(rotation), math.sin(rotation)
    g = g * scale
    g = np.stack([c * g[..., 0] + s * g[..., 1], -s * g[..., 0] + c * g[..., 1]], -1) + offset  # as implementations
    return np.stack([g[..., 0], 1.0 - g[..., 1]], -1)


def _quad(name="quad", material=None):
    from blender_addon import scene_builder

    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    mesh = scene_builder.blender_mesh(name, v, np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0, 0, 1.0], (4, 1)), v[:, :2])
    if material is not None:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _bake(obj, input_name, res):
    """Cycles' value of what feeds a Principled input, baked over the UV square: ``(res, res, 3)``, row 0 top."""
    mat = obj.material_slots[0].material
    nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL")
    emit = nt.nodes.new("ShaderNodeEmission")
    nt.links.new(bsdf.inputs[input_name].links[0].from_socket, emit.inputs["Color"])
    nt.links.new(emit.outputs[0], out.inputs["Surface"])
    img = bpy.data.images.new("bake", res, res, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    target = nt.nodes.new("ShaderNodeTexImage")
    target.image, nt.nodes.active = img, target
    scene = bpy.context.scene
    scene.render.engine, scene.cycles.device, scene.cycles.samples = "CYCLES", "CPU", 1
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    for o in scene.objects:
        o.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    try:
        bpy.ops.object.bake(type="EMIT", margin=0)
        px = np.empty(res * res * 4, np.float32)
        img.pixels.foreach_get(px)
    finally:
        nt.links.new(bsdf.outputs[0], out.inputs["Surface"])
        for n in (emit, target):
            nt.nodes.remove(n)
        bpy.data.images.remove(img)
    return px.reshape(res, res, 4)[::-1, :, :3]


def _texel_uvs(res):
    c = (np.arange(res) + 0.5) / res
    u, v = np.meshgrid(c, c[::-1])  # row 0 at the top: v near 1
    return np.stack([u, v], -1)


# --------------------------------------------------------------------------- spec -> Blender, sampled by Cycles


def test_cycles_samples_the_textures_as_defined(bpy, tmp_path):
    """Base colour (sRGB, factor, KHR transform), roughness in G and metallic in B of a packed image, procedural."""
    from blender_addon import scene_builder

    alb = _smooth_png(tmp_path / "albedo.png", 16, 1)
    mr = _smooth_png(tmp_path / "mr.png", 16, 2)
    offset, rotation, scale = (0.2, -0.1), 0.4, (1.5, 0.75)
    noise = TextureSpec("procedural:noise", (0,), (1.0,), params={"seed": 3, "size": 16, "base": 2, "low": 0.2})
    textures = MaterialTextures(
        albedo=TextureSpec(
            str(tmp_path / "albedo.png"),
            factor=(0.9, 0.8, 0.7),
            colorspace="srgb",
            offset=offset,
            rotation=rotation,
            scale=scale,
        ),  # fmt: skip
        roughness=TextureSpec(str(tmp_path / "mr.png"), (1,), (0.5,)),
        metallic=TextureSpec(str(tmp_path / "mr.png"), (2,)),
    )
    spec = MaterialSpec("tex", "pplastic", (0.5, 0.4, 0.3), 0.3, 0.5, textures=textures)
    obj = _quad(material=scene_builder.material_from_spec(spec))
    uv = _texel_uvs(16)
    expected = _bilinear(_srgb_to_linear(alb / 255.0), _khr(uv, offset, rotation, scale)) * [0.9, 0.8, 0.7]
    np.testing.assert_allclose(_bake(obj, "Base Color", 16), expected, atol=0.01)
    np.testing.assert_allclose(_bake(obj, "Roughness", 16)[..., 0], 0.5 * mr[..., 1] / 255.0, atol=0.005)
    np.testing.assert_allclose(_bake(obj, "Metallic", 16)[..., 0], mr[..., 2] / 255.0, atol=0.005)
    # A procedural texture is the packed image of its values.
    spec2 = MaterialSpec("proc", "pplastic", (0.5, 0.4, 0.3), 0.3, 0.0, textures=MaterialTextures(roughness=noise))
    obj2 = _quad("quad2", scene_builder.material_from_spec(spec2))
    np.testing.assert_allclose(_bake(obj2, "Roughness", 16)[..., 0], texture_array(noise)[..., 0], atol=2e-3)
    img = next(n.image for n in obj2.material_slots[0].material.node_tree.nodes if n.type == "TEX_IMAGE")
    assert img.packed_file is not None and img.is_float
    px = np.empty(16 * 16 * 4, np.float32)
    img.pixels.foreach_get(px)
    np.testing.assert_array_equal(px.reshape(16, 16, 4)[::-1, :, 0], texture_array(noise)[..., 0])


# --------------------------------------------------------------------------- spec -> Blender -> spec


def _textured_spec(tmp_path) -> SceneSpec:
    _smooth_png(tmp_path / "albedo.png", 16, 4)
    _smooth_png(tmp_path / "mr.png", 16, 5)
    textures = MaterialTextures(
        albedo=TextureSpec(
            str(tmp_path / "albedo.png"), colorspace="srgb", offset=(0.25, 0.5), rotation=0.3, scale=(2.0, 1.0)
        ),  # fmt: skip
        roughness=TextureSpec("procedural:noise", (0,), (1.0,), params={"seed": 7, "size": 32, "low": 0.3}),
        metallic=TextureSpec(str(tmp_path / "mr.png"), (2,)),
        normal=TextureSpec("procedural:normal", params={"seed": 8, "size": 32, "depth": 0.01}),
        normal_scale=0.8,
    )
    mat = MaterialSpec("painted", "pplastic", (0.4, 0.5, 0.6), 0.45, 0.3, ior=1.6, textures=textures)
    obj = ObjectSpec("ball", "builtin:sphere?seed=1", rigid_pose((0.0, 0.0, -0.7), rot_x(0.3) * 0.2), "painted")
    return SceneSpec(rig=Rig(), objects=(obj,), materials=(mat,), seed=3)


def test_textured_round_trip(bpy, build_spec, export_spec, tmp_path):
    """Unedited: the stored spec comes back exactly. Read from the nodes: the same textures."""
    spec = _textured_spec(tmp_path)
    build_spec.build_from_spec(bpy.context.scene, spec)
    assert export_spec.export_scene(bpy.context.scene, tmp_path / "rt", xml=False) == spec
    mesh = bpy.data.objects["ball"].data
    assert mesh.uv_layers.active is not None and mesh.uv_layers.active.name == "UVMap"  # unwrapped, as headless

    warnings: list[str] = []
    mat = bpy.data.objects["ball"].material_slots[0].material
    got = export_spec.material_spec_from_blender(mat, warnings, tmp_path / "tex")
    want = spec.materials[0].textures
    assert not warnings and got.kind == "pplastic" and got.ior == pytest.approx(1.6)
    t = got.textures
    assert t.albedo.source == want.albedo.source and t.albedo.colorspace == "srgb"
    assert t.albedo.offset == pytest.approx(want.albedo.offset, abs=1e-6)
    assert t.albedo.rotation == pytest.approx(0.3, abs=1e-6) and t.albedo.scale == pytest.approx((2.0, 1.0))
    assert t.metallic.source == want.metallic.source and t.metallic.channels == (2,)
    assert t.normal_scale == pytest.approx(0.8)
    for slot in ("roughness", "normal"):  # procedural -> packed image -> a file written once under its hash
        mine = getattr(t, slot)
        assert mine.source.startswith(str(tmp_path / "tex")) and mine.source.endswith(".exr")
        np.testing.assert_allclose(texture_array(mine), texture_array(getattr(want, slot)), atol=2e-3)
    assert got.roughness == pytest.approx(texture_array(want.roughness).mean(), abs=2e-3)  # constants: the means
    again = export_spec.material_spec_from_blender(mat, [], tmp_path / "tex")
    assert again == got and len(list((tmp_path / "tex").iterdir())) == 2


def test_edited_texture_nodes_export_live_values(bpy, build_spec, export_spec, tmp_path):
    spec = _textured_spec(tmp_path)
    build_spec.build_from_spec(bpy.context.scene, spec)
    mat = bpy.data.objects["ball"].material_slots[0].material
    mapping = next(n for n in mat.node_tree.nodes if n.type == "MAPPING")
    mapping.inputs["Scale"].default_value[0] = 3.0
    tex_node = next(n for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.outputs["Color"].links
                    and n.outputs["Color"].links[0].to_node.type == "SEPARATE_COLOR")  # fmt: skip
    musgrave = mat.node_tree.nodes.new("ShaderNodeTexNoise")  # a Blender procedural: not exported
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    mat.node_tree.links.new(musgrave.outputs["Fac"], bsdf.inputs["Metallic"])
    assert tex_node is not None
    warnings: list[str] = []
    out = export_spec.export_scene(bpy.context.scene, tmp_path / "ed", xml=False, warnings=warnings)
    got = out.materials[0]
    assert got.textures.albedo.scale == pytest.approx((3.0, 1.0)) and got.textures.metallic is None
    assert any("edited" in w for w in warnings) and any("TEX_NOISE" in w for w in warnings)
    assert got.metallic == pytest.approx(0.3)  # the constant left on the input
    tex_node.extension = "EXTEND"  # exported, with a warning: the spec's UVs wrap
    warnings.clear()
    again = export_spec.material_spec_from_blender(mat, warnings, tmp_path / "tex")
    assert again.textures.metallic is None and again.textures.roughness is not None
    assert any("EXTEND" in w for w in warnings)


def test_missing_texture_file_is_one_line(bpy, build_spec, tmp_path):
    spec = _textured_spec(tmp_path)
    (tmp_path / "albedo.png").unlink()
    with pytest.raises(ValueError, match=r"albedo\.png: texture file not found"):
        build_spec.build_from_spec(bpy.context.scene, spec)


def test_clearing_a_build_removes_its_images(bpy, tmp_path):
    from blender_addon import scene_builder

    folder = tmp_path / "assets"
    folder.mkdir()
    trimesh.creation.icosphere(subdivisions=1).export(folder / "ball.ply")
    scene_builder.build_scene(bpy.context.scene, folder, 2, seed=1, texture_fraction=1.0)
    assert any("pdir_texture" in i for i in bpy.data.images)
    scene_builder.clear_scene_objects(bpy.context.scene)
    assert not any("pdir_texture" in i for i in bpy.data.images)


def test_mapping_conversion_inverts():
    from blender_addon.texture_nodes import mapping_of, transform_of

    t = TextureSpec("a.png", offset=(0.3, -0.7), rotation=1.1, scale=(0.5, 2.5))
    back = transform_of(*mapping_of(t))
    assert back["offset"] == pytest.approx(t.offset) and back["rotation"] == pytest.approx(1.1)
    assert back["scale"] == pytest.approx(t.scale)


# --------------------------------------------------------------------------- assets keep their materials


def _gltf_quad(folder):
    """A unit quad (UVs over [0, 1]^2) with base colour, metallic-roughness and normal textures, and a plain box."""
    alb = _smooth_png(folder / "base.png", 8, 11)
    mr = _smooth_png(folder / "mr.png", 8, 12)
    _smooth_png(folder / "nrm.png", 8, 13)
    corners = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    uv = np.stack([corners[:, 0], 1.0 - corners[:, 1]], -1)  # glTF's v points down
    material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 1},
                                         "roughnessFactor": 0.6, "metallicFactor": 1.0},
                "normalTexture": {"index": 2, "scale": 0.7}}  # fmt: skip
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.2))
    box = np.asarray(box.vertices)[np.asarray(box.faces)].reshape(-1, 3) + (0.5, 0.5, -0.3)  # below the quad
    plain = {"pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.3, 0.4, 1.0], "metallicFactor": 0.0}}
    prims = [{"v": corners, "uv": uv, "material": 0}, {"v": box, "uv": np.zeros((len(box), 2)), "material": 1}]
    write_gltf(folder, "quad", prims, materials=[material, plain],
               textures=[{"source": 0}, {"source": 1}, {"source": 2}],
               images=[("uri", "base.png"), ("uri", "mr.png"), ("uri", "nrm.png")])  # fmt: skip
    return alb, mr


def test_gltf_asset_keeps_its_material_in_the_scene_builder(bpy, tmp_path):
    from blender_addon import rig_bpy, scene_builder

    folder = tmp_path / "assets"
    folder.mkdir()
    alb, mr = _gltf_quad(folder)
    assert bpy.ops.pdir.build_scene(folder=str(folder), count=1, seed=2, asset_materials=True) == {"FINISHED"}
    objs = [o for o in bpy.context.scene.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]
    assert sorted(o.name for o in objs) == ["quad_00_part0", "quad_00_part1"]  # one object per material
    obj = bpy.data.objects["quad_00_part0"]
    box = scene_builder.material_spec_of(bpy.data.objects["quad_00_part1"].material_slots[0].material)
    assert box.textures is None and box.albedo == pytest.approx((0.2, 0.3, 0.4))
    assert np.allclose(bpy.data.objects["quad_00_part1"].matrix_basis, obj.matrix_basis)  # one pose
    assert "asset_notes" not in json.loads(bpy.context.scene["pdir_metadata"])  # nothing lost reading it
    np.testing.assert_allclose(_bake(obj, "Base Color", 8), _srgb_to_linear(alb / 255.0), atol=0.01)
    np.testing.assert_allclose(_bake(obj, "Roughness", 8)[..., 0], 0.6 * mr[..., 1] / 255.0, atol=0.005)
    np.testing.assert_allclose(_bake(obj, "Metallic", 8)[..., 0], mr[..., 2] / 255.0, atol=0.005)
    bsdf = next(n for n in obj.material_slots[0].material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    nmap = bsdf.inputs["Normal"].links[0].from_node
    assert nmap.type == "NORMAL_MAP" and nmap.inputs["Strength"].default_value == pytest.approx(0.7)
    assert nmap.inputs["Color"].links[0].from_node.image.colorspace_settings.name == "Non-Color"


def test_texture_fraction_textures_drawn_materials(bpy, tmp_path):
    from blender_addon import rig_bpy, scene_builder

    folder = tmp_path / "assets"
    folder.mkdir()
    trimesh.creation.icosphere(subdivisions=1).export(folder / "ball.ply")
    scene = bpy.context.scene
    plain = scene_builder.build_scene(scene, folder, 2, seed=4)
    poses = [np.array(o.matrix_basis) for o in plain]
    names = [json.loads(o.material_slots[0].material[scene_builder.MATERIAL_KEY])["name"] for o in plain]
    same = scene_builder.build_scene(scene, folder, 2, seed=4, texture_fraction=0.0)
    assert [np.array(o.matrix_basis).tolist() for o in same] == [p.tolist() for p in poses]  # 0: the old stream
    assert bpy.ops.pdir.build_scene(folder=str(folder), count=2, seed=4, texture_fraction=1.0) == {"FINISHED"}
    objs = [o for o in scene.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]
    for o in objs:
        spec = scene_builder.material_spec_of(o.material_slots[0].material)
        assert spec.textures is not None and spec.textures.albedo is not None
        assert o.data.uv_layers.active is not None  # unwrapped for its textures
        assert any(n.type == "TEX_IMAGE" for n in o.material_slots[0].material.node_tree.nodes)
    assert names and all(o.name.startswith("ball_") for o in objs)
    with pytest.raises(ValueError, match="texture_fraction"):
        scene_builder.build_scene(scene, folder, 1, seed=0, texture_fraction=1.5)
    # The panel's settings mirror headless/render.py's flags (off by default: the scenes of earlier builds).
    rna = scene.pdir_builder.bl_rna.properties
    assert "--texture-fraction" in rna["texture_fraction"].description and scene.pdir_builder.texture_fraction == 0
    assert "--asset-materials" in rna["asset_materials"].description and not scene.pdir_builder.asset_materials


# --------------------------------------------------------------------------- Blender's own glTF importer


def _import_with_blender(tmp_path, rotation):
    """The quad asset with a KHR_texture_transform, read by Blender's glTF importer and by the headless reader."""
    from blender_addon.core import asset_materials as am

    folder = tmp_path / "assets"
    folder.mkdir()
    _gltf_quad(folder)
    path = folder / "quad.gltf"
    doc = json.loads(path.read_text())
    base = doc["materials"][0]["pbrMetallicRoughness"]
    base["baseColorFactor"] = [0.9, 0.8, 0.7, 1.0]
    xf = {"offset": [0.2, 0.1], "rotation": rotation, "scale": [2.0, 1.5]}
    base["baseColorTexture"]["extensions"] = {"KHR_texture_transform": xf}
    doc["extensionsUsed"] = ["KHR_texture_transform"]
    path.write_text(json.dumps(doc))
    bpy.ops.import_scene.gltf(filepath=str(path))
    mat = next(m for m in bpy.data.materials if m.node_tree and any(n.type == "TEX_IMAGE" for n in m.node_tree.nodes))
    return mat, am.read_materials(path).materials[0].textures


def test_blender_gltf_importer_materials_export_as_the_headless_reader_reads_them(bpy, export_spec, tmp_path):
    """Mix (base colour factor), Math (roughness factor), Separate Color (G, B), Normal Map, Mapping: all read."""
    mat, want = _import_with_blender(tmp_path, 0.0)
    warnings: list[str] = []
    got = export_spec.material_spec_from_blender(mat, warnings, tmp_path / "tex").textures
    assert not warnings
    for slot in ("albedo", "roughness", "metallic", "normal"):
        a, b = getattr(got, slot), getattr(want, slot)
        assert (a.source, a.channels, a.colorspace) == (b.source, b.channels, b.colorspace), slot
        for key in ("factor", "offset", "scale"):
            assert getattr(a, key) == pytest.approx(getattr(b, key), abs=1e-6), (slot, key)
    assert got.normal_scale == pytest.approx(want.normal_scale)


def test_blender_gltf_importer_rotation_agrees_with_uv_matrix(bpy, export_spec, tmp_path):
    mat, want = _import_with_blender(tmp_path, 0.3)
    got = export_spec.material_spec_from_blender(mat, [], tmp_path / "tex").textures
    assert got.albedo.rotation == pytest.approx(want.albedo.rotation, abs=1e-6)
