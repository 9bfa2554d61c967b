"""Bake maps predicted from one view onto a captured asset's mesh, for use from any viewpoint.

:func:`bake_to_mesh`:

1. replaces the object's mesh by a triangulated copy unwrapped with xatlas
   (:func:`blender_addon.core.assets.ensure_uv`; UV layer ``UVMap``);
2. marks each vertex visible when the ray from the capture camera reaches it unoccluded (a BVH
   ray cast; attribute ``pdir_visible``);
3. builds a projection material: every shading point is projected through the capture camera
   (Texture Coordinate "Object" of the camera, so the projection is exact per point, not
   interpolated per vertex) to look up the maps; coverage = visible x facing the camera x mask;
4. bakes with Cycles into ``size x size`` float images: albedo, roughness, metallic, mask and
   coverage as Emission (exact values), the normal as a NORMAL bake in TANGENT or OBJECT space
   (Blender's own conversion, so the Normal Map node of the final material reads it back
   consistently); uncovered points keep the mesh's own normal;
5. gives the object a Principled material reading the baked images through ``UVMap``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from contextlib import contextmanager

import bpy
import numpy as np
from bpy.props import EnumProperty, IntProperty, PointerProperty, StringProperty
from mathutils import Vector
from mathutils.bvhtree import BVHTree

from .core import map_io, map_names
from .images import image_from_array, read_channels
from .pbr_import import (
    NORMAL_SPACES,
    UV_NAME,
    build_material,
    camera_frustum,
    ensure_camera,
)
from .ui import SidebarPanel

__all__ = ["CLASSES", "VISIBLE_ATTRIBUTE", "unwrap_object", "vertex_visibility", "bake_to_mesh"]

VISIBLE_ATTRIBUTE = "pdir_visible"
_EMIT_KINDS = ("albedo", "roughness", "metallic", "mask", "coverage")


# --------------------------------------------------------------------------- geometry


def unwrap_object(obj) -> None:
    """Replace ``obj``'s mesh by a triangulated copy with an xatlas UV layout in :data:`UV_NAME`.

    Vertices are split along chart seams (positions and normals copied), faces keep their
    smooth/flat shading as a whole (smooth if most faces were). Modifiers stay on the object.
    """
    import trimesh  # noqa: PLC0415 - optional in Blender's Python

    from .core.assets import ensure_uv  # noqa: PLC0415

    src = obj.data
    src.calc_loop_triangles()
    n_tri = len(src.loop_triangles)
    if n_tri == 0:
        raise ValueError(f"{obj.name!r} has no faces to bake onto")
    verts = np.empty((len(src.vertices), 3), np.float64)
    src.vertices.foreach_get("co", verts.ravel())
    tris = np.empty((n_tri, 3), np.int64)
    src.loop_triangles.foreach_get("vertices", tris.ravel())
    smooth = np.empty(len(src.polygons), bool)
    src.polygons.foreach_get("use_smooth", smooth)
    tm = ensure_uv(trimesh.Trimesh(vertices=verts, faces=tris, process=False), force=True)
    uv = np.asarray(tm.visual.uv, np.float32)
    faces = np.asarray(tm.faces, np.int64)
    mesh = bpy.data.meshes.new(src.name + "_baked")
    mesh.from_pydata(np.asarray(tm.vertices).tolist(), [], faces.tolist())
    layer = mesh.uv_layers.new(name=UV_NAME)
    corner = np.empty(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", corner)
    layer.data.foreach_set("uv", uv[corner].ravel())
    mesh.uv_layers.active = layer
    layer.active_render = True
    mesh.validate()
    if smooth.mean() >= 0.5:
        mesh.shade_smooth()
    mesh.update()
    obj.data = mesh
    if src.users == 0:
        bpy.data.meshes.remove(src)


def vertex_visibility(obj, camera, *, rel_eps: float = 1e-3) -> np.ndarray:
    """``(N,)`` float32: 1 where the segment from the camera to the vertex hits nothing before it."""
    mesh = obj.data
    m = obj.matrix_world
    verts = np.empty((len(mesh.vertices), 3), np.float64)
    mesh.vertices.foreach_get("co", verts.ravel())
    world = verts @ np.array(m.to_3x3()).T + np.array(m.translation)
    mesh.calc_loop_triangles()
    tris = np.empty((len(mesh.loop_triangles), 3), np.int64)
    mesh.loop_triangles.foreach_get("vertices", tris.ravel())
    bvh = BVHTree.FromPolygons(world.tolist(), tris.tolist())
    origin = camera.matrix_world.translation
    out = np.zeros(len(world), np.float32)
    for i, p in enumerate(world):
        d = Vector(p) - origin
        dist = d.length
        hit = bvh.ray_cast(origin, d / dist, dist)[0] if dist > 0 else None
        out[i] = hit is None or (hit - origin).length >= dist * (1.0 - rel_eps)
    return out


# --------------------------------------------------------------------------- projection material


def _math(nodes, links, op: str, a, b=None, c=None, loc=(0, 0)):
    """A Math node; each operand is a socket (linked) or a number (default value)."""
    node = nodes.new("ShaderNodeMath")
    node.operation = op
    node.location = loc
    for i, x in enumerate((a, b, c)):
        if x is None:
            continue
        if isinstance(x, (int, float)):
            node.inputs[i].default_value = float(x)
        else:
            links.new(x, node.inputs[i])
    return node.outputs[0]


def _projection_material(name, camera, frustum, images: Mapping[str, object]):
    """Material projecting ``images`` from ``camera``; returns (material, {kind: output socket}, normal socket)."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nodes, links = nt.nodes, nt.links
    nodes.clear()
    coords = nodes.new("ShaderNodeTexCoord")
    coords.object = camera  # "Object" output = position in the camera's frame (x right, y up, -z forward)
    coords.location = (-1400, 0)
    sep = nodes.new("ShaderNodeSeparateXYZ")
    sep.location = (-1200, 0)
    links.new(coords.outputs["Object"], sep.inputs["Vector"])
    x_over_z = _math(nodes, links, "DIVIDE", sep.outputs["X"], sep.outputs["Z"], loc=(-1000, 100))
    y_over_z = _math(nodes, links, "DIVIDE", sep.outputs["Y"], sep.outputs["Z"], loc=(-1000, -100))
    # u = (x / -z - cx) / (2 hw) + 1/2, v likewise (image top = v 1)
    su, sv = 1.0 / (2.0 * frustum.half_width), 1.0 / (2.0 * frustum.half_height)
    u = _math(nodes, links, "MULTIPLY_ADD", x_over_z, -su, 0.5 - frustum.center_x * su, loc=(-800, 100))
    v = _math(nodes, links, "MULTIPLY_ADD", y_over_z, -sv, 0.5 - frustum.center_y * sv, loc=(-800, -100))
    uvw = nodes.new("ShaderNodeCombineXYZ")
    uvw.location = (-600, 0)
    links.new(u, uvw.inputs["X"])
    links.new(v, uvw.inputs["Y"])
    outs = {}
    for i, (kind, image) in enumerate(images.items()):
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.interpolation = "Linear"
        tex.extension = "CLIP" if kind == "mask" else "EXTEND"  # the mask is 0 outside the frame
        tex.location = (-400, 400 - 300 * i)
        links.new(uvw.outputs["Vector"], tex.inputs["Vector"])
        outs[kind] = tex.outputs["Color"]

    # coverage = visible (per-vertex ray test) * facing the camera * mask
    geo = nodes.new("ShaderNodeNewGeometry")
    geo.location = (-1400, -600)
    to_cam = nodes.new("ShaderNodeVectorMath")
    to_cam.operation = "SUBTRACT"
    to_cam.inputs[0].default_value = camera.matrix_world.translation
    links.new(geo.outputs["Position"], to_cam.inputs[1])
    facing = nodes.new("ShaderNodeVectorMath")
    facing.operation = "DOT_PRODUCT"
    links.new(to_cam.outputs["Vector"], facing.inputs[0])
    links.new(geo.outputs["True Normal"], facing.inputs[1])
    front = _math(nodes, links, "GREATER_THAN", facing.outputs["Value"], 0.0, loc=(-1000, -600))
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = VISIBLE_ATTRIBUTE
    attr.location = (-1200, -800)
    vis = _math(nodes, links, "GREATER_THAN", attr.outputs["Fac"], 0.5, loc=(-1000, -800))
    cov = _math(nodes, links, "MULTIPLY", front, vis, loc=(-800, -700))
    cov = _math(nodes, links, "MULTIPLY", cov, outs["mask"], loc=(-600, -700))
    outs["coverage"] = cov

    normal = None
    if "normal" in outs:
        # camera-space n = 2 c - 1 -> world = R n (columns of the camera rotation), where covered;
        # elsewhere the mesh's own shading normal
        dec = nodes.new("ShaderNodeVectorMath")
        dec.operation = "MULTIPLY_ADD"
        dec.inputs[1].default_value = (2.0, 2.0, 2.0)
        dec.inputs[2].default_value = (-1.0, -1.0, -1.0)
        links.new(outs["normal"], dec.inputs[0])
        nsep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(dec.outputs["Vector"], nsep.inputs["Vector"])
        rot = camera.matrix_world.to_3x3()
        acc = None
        for k, comp in enumerate("XYZ"):
            scale = nodes.new("ShaderNodeVectorMath")
            scale.operation = "SCALE"
            scale.inputs[0].default_value = rot.col[k]
            links.new(nsep.outputs[comp], scale.inputs["Scale"])
            if acc is None:
                acc = scale.outputs["Vector"]
            else:
                add = nodes.new("ShaderNodeVectorMath")
                add.operation = "ADD"
                links.new(acc, add.inputs[0])
                links.new(scale.outputs["Vector"], add.inputs[1])
                acc = add.outputs["Vector"]
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "VECTOR"
        links.new(cov, mix.inputs["Factor"])
        links.new(geo.outputs["Normal"], mix.inputs[4])  # A (vector)
        links.new(acc, mix.inputs[5])  # B (vector)
        norm = nodes.new("ShaderNodeVectorMath")
        norm.operation = "NORMALIZE"
        links.new(mix.outputs[1], norm.inputs[0])
        normal = norm.outputs["Vector"]
    return mat, outs, normal


# --------------------------------------------------------------------------- bake


def _load(maps) -> map_io.PBRMaps:
    if isinstance(maps, map_io.PBRMaps):
        return maps
    return map_io.load_maps(map_names.match_map_files(maps, required=()), reader=read_channels)


def bake_to_mesh(
    obj,
    maps: map_io.PBRMaps | str | os.PathLike | Iterable | Mapping,
    camera,
    *,
    size: int = 512,
    normal_space: str = "TANGENT",
    margin: int = 8,
    samples: int = 4,
) -> dict:
    """Project maps seen by ``camera`` onto ``obj``, unwrap it with xatlas and bake the maps into textures.

    The object's mesh is replaced by the unwrapped, triangulated copy and its materials by one
    Principled material reading the baked images (alpha is not used: uncovered parts keep the
    margin-extended values; see the ``coverage`` image).

    Args:
        obj: mesh object in the current scene, placed as it was captured.
        maps: :class:`~blender_addon.core.map_io.PBRMaps`, or a folder / files / ``{kind: file}``.
        camera: the capture camera object (its view frames the maps: same aspect ratio).
        size: texture size in pixels (square).
        normal_space: ``"TANGENT"`` or ``"OBJECT"`` for the baked normal map.
        margin: bake margin in pixels (extends charts so filtering never reads empty texels).
        samples: Cycles samples per texel (anti-aliasing of the projection).

    Returns:
        kind -> baked ``bpy.types.Image`` for albedo, roughness, metallic, mask, normal (those
        present) and ``coverage`` (1 where the capture saw the surface), float, packed.

    Raises:
        ValueError: not a mesh, bad camera or arguments, no maps.
    """
    scene = bpy.context.scene
    _check_bake_args(obj, scene, normal_space, size)
    camera = ensure_camera(scene, camera)
    maps = _load(maps)
    kinds = [k for k in ("albedo", "roughness", "metallic", "normal") if getattr(maps, k) is not None]
    if not kinds:
        raise ValueError("no albedo, roughness, metallic or normal map to bake")
    h, w = maps.shape
    frustum = camera_frustum(camera, w, h, scene=scene)

    unwrap_object(obj)
    attr = obj.data.attributes.new(VISIBLE_ATTRIBUTE, "FLOAT", "POINT")
    attr.data.foreach_set("value", vertex_visibility(obj, camera))

    sources = {}
    for kind in kinds:
        data = 0.5 + 0.5 * maps.normal if kind == "normal" else getattr(maps, kind)
        sources[kind] = image_from_array(f"{obj.name}_proj_{kind}", data, pack=False)
    sources["mask"] = image_from_array(f"{obj.name}_proj_mask", maps.mask, pack=False)
    proj, outs, normal = _projection_material(f"{obj.name}_projection", camera, frustum, sources)
    baked: dict = {}
    try:
        with _baking(bpy.context, obj, proj, samples, margin):
            bake_kind = _baker(proj, outs, normal, normal_space=normal_space, margin=margin)
            emit_kinds = [k for k in _EMIT_KINDS if k in outs and k != "normal"]
            for kind in [*emit_kinds, *(["normal"] if normal is not None else [])]:
                img = bpy.data.images.new(f"{obj.name}_{kind}", width=size, height=size, alpha=True, float_buffer=True)
                img.colorspace_settings.name = "Linear Rec.709" if kind == "albedo" else "Non-Color"
                bake_kind(kind, img)
                img.file_format = "OPEN_EXR"
                img.pack()
                baked[kind] = img
    finally:
        for img in sources.values():
            bpy.data.images.remove(img)
        bpy.data.materials.remove(proj)
    final = {k: v for k, v in baked.items() if k in ("albedo", "roughness", "metallic", "normal")}
    obj.data.materials.append(build_material(f"{obj.name}_baked", final, normal_space=normal_space, use_alpha=False))
    obj["pdir_baked"] = ",".join(baked)
    obj["pdir_normal_space"] = normal_space
    return baked


def _check_bake_args(obj, scene, normal_space: str, size: int) -> None:
    """Refuse what :func:`bake_to_mesh` cannot bake (one line naming the argument)."""
    if obj is None or obj.type != "MESH":
        raise ValueError(f"bake needs a mesh object, got {getattr(obj, 'type', None)!r}")
    if normal_space not in NORMAL_SPACES:
        raise ValueError(f"normal_space must be one of {NORMAL_SPACES}, got {normal_space!r}")
    if isinstance(size, bool) or not isinstance(size, int) or not 8 <= size <= 16384:
        raise ValueError(f"size must be an integer in [8, 16384], got {size!r}")
    if scene.objects.get(obj.name) is None:
        raise ValueError(f"{obj.name!r} is not in the scene {scene.name!r}")


@contextmanager
def _baking(context, obj, material, samples: int, margin: int):
    """Cycles with ``samples``, ``obj`` alone selected and active, wearing ``material``; all restored after."""
    scene = context.scene
    saved = {
        "engine": scene.render.engine,
        "samples": scene.cycles.samples,
        "selected": [o for o in context.view_layer.objects if o.select_get()],
        "active": context.view_layer.objects.active,
    }
    obj.data.materials.clear()
    obj.data.materials.append(material)
    try:
        scene.render.engine = "CYCLES"
        scene.cycles.samples = samples
        for o in saved["selected"]:
            o.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj
        bake = scene.render.bake
        bake.margin, bake.margin_type, bake.use_clear, bake.target = margin, "EXTEND", True, "IMAGE_TEXTURES"
        yield
    finally:
        scene.render.engine = saved["engine"]
        scene.cycles.samples = saved["samples"]
        obj.select_set(False)
        for o in saved["selected"]:
            if o.name in context.view_layer.objects:
                o.select_set(True)
        context.view_layer.objects.active = saved["active"] if saved["active"] is not None else obj
        obj.data.materials.clear()


def _baker(material, outs: Mapping, normal, *, normal_space: str, margin: int):
    """A function ``bake(kind, image)`` that bakes one kind of the projection material into ``image``.

    Values bake as Emission (exact); the normal as a NORMAL bake of a diffuse BSDF reading the
    projected normal, in ``normal_space`` (Blender's own conversion).
    """
    nt = material.node_tree
    emit = nt.nodes.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = 1.0
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    target = nt.nodes.new("ShaderNodeTexImage")
    common = {"uv_layer": UV_NAME, "margin": margin, "margin_type": "EXTEND", "use_clear": True,
              "target": "IMAGE_TEXTURES"}  # fmt: skip

    def bake(kind: str, image) -> None:
        target.image = image
        nt.nodes.active = target
        if kind == "normal":
            nt.links.new(normal, diffuse.inputs["Normal"])
            nt.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
            bpy.ops.object.bake(type="NORMAL", normal_space=normal_space, normal_r="POS_X", normal_g="POS_Y",
                                normal_b="POS_Z", **common)  # fmt: skip
        else:
            nt.links.new(outs[kind], emit.inputs["Color"])
            nt.links.new(emit.outputs["Emission"], out.inputs["Surface"])
            bpy.ops.object.bake(type="EMIT", **common)

    return bake


# --------------------------------------------------------------------------- settings, operator, panel


class PDIR_BakeSettings(bpy.types.PropertyGroup):
    """Bake settings of a scene (``scene.pdir_bake``)."""

    maps_dir: StringProperty(
        name="Maps", description="Folder with the predicted maps of the capture view", subtype="DIR_PATH"
    )
    size: IntProperty(name="Size", description="Baked texture size in pixels", default=512, min=8, max=16384)
    normal_space: EnumProperty(
        name="Normal Space",
        description="Space of the baked normal map",
        items=(
            ("TANGENT", "Tangent", "Tangent space of the xatlas UV layout"),
            ("OBJECT", "Object", "Object space"),
        ),
        default="TANGENT",
    )
    camera: PointerProperty(
        name="Capture Camera",
        description="Camera the maps were captured from (empty: the scene camera)",
        type=bpy.types.Object,
        poll=lambda _self, o: o.type == "CAMERA",
    )


class PDIR_OT_bake_to_mesh(bpy.types.Operator):
    """Project the captured maps onto the active mesh, unwrap it with xatlas and bake textures."""

    bl_idname = "pdir.bake_to_mesh"
    bl_label = "Bake to Mesh"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        """Bake onto the active object with the scene's bake settings."""
        s = context.scene.pdir_bake
        if not s.maps_dir:
            self.report({"ERROR"}, "choose the folder with the maps first")
            return {"CANCELLED"}
        obj = context.active_object
        try:
            images = bake_to_mesh(
                obj,
                bpy.path.abspath(s.maps_dir),
                s.camera or context.scene.camera,
                size=s.size,
                normal_space=s.normal_space,
            )
        except (ValueError, OSError, ImportError, RuntimeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        cover = np.empty(images["coverage"].size[0] * images["coverage"].size[1] * 4, np.float32)
        images["coverage"].pixels.foreach_get(cover)
        self.report(
            {"INFO"},
            f"baked {', '.join(images)} onto {obj.name!r} ({s.size} px); "
            f"{100 * float((cover[0::4] > 0.5).mean()):.0f}% of the texture seen by the camera",
        )
        return {"FINISHED"}


class PDIR_PT_bake(SidebarPanel, bpy.types.Panel):
    """Bake the captured maps onto the asset's mesh."""

    bl_label = "Bake to Mesh"
    bl_idname = "PDIR_PT_bake"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 4

    def draw(self, context):
        """Bake settings and the bake button."""
        s = context.scene.pdir_bake
        col = self.layout.column()
        for prop in ("maps_dir", "camera", "size", "normal_space"):
            col.prop(s, prop)
        col.operator("pdir.bake_to_mesh", icon="RENDER_STILL")


CLASSES = (PDIR_BakeSettings, PDIR_OT_bake_to_mesh, PDIR_PT_bake)


def register_extra() -> None:
    """Attach the settings to every scene."""
    bpy.types.Scene.pdir_bake = PointerProperty(type=PDIR_BakeSettings)


def unregister_extra() -> None:
    """Remove the scene settings."""
    del bpy.types.Scene.pdir_bake
