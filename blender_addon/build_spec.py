"""Scene spec -> Blender: lay out the rig, objects, lights and world of a :class:`~.core.spec.SceneSpec`.

:func:`build_from_spec` is the inverse of :func:`.export_spec.export_scene`: every created
object, light and the world keep their exact spec in custom properties
(:data:`.export_spec.SPEC_KEY`, :data:`.export_spec.MESH_KEY`, ...), so exporting an unedited
layout gives the spec back. :func:`roundtrip_spec` does both in a fresh Blender session; it is
the Blender route of ``headless/render.py`` (``--via-blender`` or ``blender -b -P``).

Convention (frames):
    Objects and lights are children of the rig root with ``matrix_basis = to_world``: the
    spec's world frame is the rig frame of :mod:`.rig_bpy`. An environment map's rotation is
    taken through the root's ``matrix_world`` into a Mapping node (none when it is the
    identity).
"""

from __future__ import annotations

import json
import os

import bpy
import numpy as np
from mathutils import Matrix
from numpy.typing import NDArray

from . import rig_bpy, scene_builder
from .core.spec import EnvironmentSpec, LightSpec, SceneSpec
from .export_spec import (
    INDEX_KEY,
    MESH_CHECK_KEY,
    MESH_KEY,
    METADATA_KEY,
    ROLE_LIGHT,
    SPEC_KEY,
    export_scene,
    matrix_array,
    mesh_checksum,
    view_layer_of,
)

__all__ = ["build_from_spec", "roundtrip_spec"]


def _objects_collection(scene: bpy.types.Scene) -> bpy.types.Collection:
    """The scene builder's object collection (same role key), created if missing."""
    for coll in scene.collection.children:
        if coll.get(rig_bpy.ROLE_KEY) == scene_builder.ROLE_COLLECTION:
            return coll
    coll = bpy.data.collections.new("PDIR Objects")
    coll[rig_bpy.ROLE_KEY] = scene_builder.ROLE_COLLECTION
    scene.collection.children.link(coll)
    return coll


def _light_data(light: LightSpec) -> bpy.types.Light:
    types = {"point": "POINT", "spot": "SPOT", "area": "AREA", "sun": "SUN"}
    data = bpy.data.lights.new(light.name, types[light.kind])
    data.color = light.color
    data.energy = light.power
    if light.kind == "point" or light.kind == "spot":
        data.shadow_soft_size = 0.0  # the spec's lights are points
    if light.kind == "spot":
        data.spot_size, data.spot_blend = light.spot_angle, light.spot_blend
    if light.kind == "area":
        data.shape = "RECTANGLE" if light.shape == "rectangle" else "ELLIPSE"
        data.size, data.size_y = light.size
        data.normalize = light.normalize
    return data


def _set_world(scene: bpy.types.Scene, env: EnvironmentSpec, spec_to_world: NDArray) -> None:
    world = scene.world or bpy.data.worlds.new("PDIR World")
    scene.world = world
    if world.node_tree is None:
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputWorld")
    bg = nodes.new("ShaderNodeBackground")
    links.new(bg.outputs["Background"], out.inputs["Surface"])
    bg.inputs["Strength"].default_value = env.strength
    world.color = env.color
    if env.image is None:
        bg.inputs["Color"].default_value = (*env.color, 1.0)
    else:
        tex = nodes.new("ShaderNodeTexEnvironment")
        tex.image = bpy.data.images.load(env.image, check_existing=True)
        links.new(tex.outputs["Color"], bg.inputs["Color"])
        rot = (spec_to_world @ np.asarray(env.to_world))[:3, :3]  # map frame -> Blender world
        if not np.allclose(rot, np.eye(3), atol=1e-9):
            mapping = nodes.new("ShaderNodeMapping")
            coords = nodes.new("ShaderNodeTexCoord")
            mapping.inputs["Rotation"].default_value = Matrix(rot.T.tolist()).to_euler("XYZ")
            links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
            links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    world[SPEC_KEY] = json.dumps(env.to_dict())


def _attach(obj, item, index: int, role: str, coll, root) -> None:
    """Link ``obj`` under the rig root at ``item.to_world``, keeping ``item``'s exact spec in custom properties."""
    obj[rig_bpy.ROLE_KEY] = role
    obj[SPEC_KEY] = json.dumps(item.to_dict())
    obj[INDEX_KEY] = index
    obj["pdir_name"] = item.name
    coll.objects.link(obj)
    obj.parent = root
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.matrix_basis = Matrix(np.asarray(item.to_world).tolist())


def build_from_spec(scene: bpy.types.Scene, spec: SceneSpec) -> bpy.types.Object:
    """Lay a scene spec out in ``scene``: the rig, its objects, lights and world.

    Objects are meshes built from their mesh reference (:func:`.core.assets.load_mesh`), children
    of the rig root with ``matrix_basis = to_world``, carrying the scene builder's material
    (:func:`.scene_builder.material_from_spec`, textured through :mod:`.texture_nodes`) and
    the mesh's UVs (a textured material's mesh without UVs is unwrapped as the headless renderer
    unwraps it, :func:`.core.assets.ensure_uv`). Everything keeps its exact spec in custom
    properties, so :func:`.export_spec.export_scene` gives the spec back while nothing is edited.

    Args:
        scene: the Blender scene to add to (normally empty).
        spec: the scene spec; its meshes need trimesh to load.

    Returns:
        The rig root (:func:`.rig_bpy.add_rig`), parent of every created object and light.

    Raises:
        ValueError, FileNotFoundError: an invalid spec or a missing mesh file.
    """
    from .core import assets  # noqa: PLC0415 - needs trimesh

    root = rig_bpy.add_rig(scene, spec.rig)
    coll = _objects_collection(scene)
    materials = {m.name: m for m in spec.materials}
    for i, o in enumerate(spec.objects):
        if o.material not in materials:
            raise ValueError(f"object {o.name!r} references unknown material {o.material!r}")
        material = materials[o.material]
        # UVs as the headless renderer uses them: the file's, or an unwrap for a textured material.
        tm, uv = scene_builder.mesh_uvs(assets.load_mesh(o.mesh), material.textures is not None)
        mesh = scene_builder.blender_mesh(o.name, tm.vertices, tm.faces, tm.vertex_normals, uv)
        mesh.materials.append(scene_builder.material_from_spec(material))
        obj = bpy.data.objects.new(o.name, mesh)
        obj[scene_builder.MATERIAL_KEY] = o.material
        obj[MESH_KEY] = o.mesh
        obj[MESH_CHECK_KEY] = mesh_checksum(mesh)
        _attach(obj, o, i, scene_builder.ROLE_OBJECT, coll, root)
    for i, light in enumerate(spec.lights):
        _attach(bpy.data.objects.new(light.name, _light_data(light)), light, i, ROLE_LIGHT, coll, root)
    if spec.environment is not None:
        view_layer_of(scene).update()  # the root's matrix_world
        _set_world(scene, spec.environment, matrix_array(root.matrix_world))
    scene[scene_builder.SEED_KEY] = int(spec.seed)
    scene[METADATA_KEY] = json.dumps(spec.metadata)
    view_layer_of(scene).update()
    return root


def roundtrip_spec(spec: SceneSpec, work_dir: str | os.PathLike | None = None) -> SceneSpec:
    """Spec -> Blender -> spec in a fresh empty Blender session (the Blender route of ``headless/render.py``).

    Resets Blender to factory settings (an empty scene), lays the spec out with
    :func:`build_from_spec` and exports it with :func:`.export_spec.export_scene`.

    Args:
        spec: the scene spec.
        work_dir: export folder (meshes edited in Blender become PLYs there); None uses a
            temporary folder, removed afterwards.

    Returns:
        The exported spec, equal to ``spec`` for a spec Blender can represent.
    """
    import tempfile  # noqa: PLC0415

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    build_from_spec(scene, spec)
    if work_dir is not None:
        return export_scene(scene, work_dir, xml=False)
    with tempfile.TemporaryDirectory(prefix="pdir_roundtrip_") as tmp:
        return export_scene(scene, tmp, xml=False)
