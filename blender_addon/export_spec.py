"""Blender scene -> scene spec: camera or rig, meshes as PLY, materials, lights and world.

:func:`export_scene` (operator ``pdir.export_scene`` in :mod:`.render_operator`) writes a
Blender scene as a :class:`~.core.spec.SceneSpec`:

- Frame: the spec's world is the rig frame of :mod:`.rig_bpy` when the scene has a rig root
  (its camera is the rig camera, :func:`.rig_bpy.rig_from_blender`), else the frame of the
  scene camera (x right, y up, looking along -z, as :mod:`pbrdf.sensor.rig`), with the default
  display 5 cm behind it.
- Meshes: every visible mesh-like object except the rig's own parts, evaluated (modifiers
  applied), split per material slot, written as binary PLY in rig-frame coordinates (the
  object's ``to_world`` is then the identity) from ``loop_triangles`` and corner normals read
  with ``foreach_get`` (flat and smooth shading survive; mirrored objects are re-wound).
  Objects laid out from a spec by :func:`.build_spec.build_from_spec` keep their mesh reference
  (``builtin:...`` or a file) while their mesh data is unchanged (:func:`mesh_checksum`).
- Materials: the :class:`~.core.spec.MaterialSpec` stored by the scene builder
  (:func:`.scene_builder.material_spec_of`) while the Principled BSDF still shows its Disney
  parameters and texture nodes; otherwise one derived from the node tree
  (:func:`material_spec_from_blender`, textures by :mod:`.texture_nodes`; packed and generated
  images written to ``textures/``).
- Lights (point, spot, area, sun) and the world (background colour or an Environment
  Texture) in Blender's units: see :class:`~.core.spec.LightSpec` for the conversions to
  Mitsuba (area radiance ``energy / (pi A)``, point intensity ``energy / (4 pi)`` W/sr, sun
  irradiance ``strength`` W/m^2).
- Output folder: ``scene.json`` (the spec), ``meshes/*.ply``, ``textures/`` and, when mitsuba is importable,
  ``scene.xml``, the RGB preview scene of :func:`.core.mitsuba_preview.preview_scene_dict`.

Convention (exactness):
    Values a spec put into Blender (float32 there) come back exactly while the live values
    agree with the stored spec (custom property :data:`SPEC_KEY`, compared to 1e-5), so spec ->
    Blender -> spec is the identity (:func:`.build_spec.roundtrip_spec`). Example: a light built
    with ``power = 12.5`` and moved by 0.1 m exports its live position; left alone it exports the
    stored transform bit for bit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from pathlib import Path
from typing import Any

import bpy
import numpy as np
from mathutils import Matrix
from numpy.typing import NDArray

from pbrdf.sensor.rig import CameraSpec, Rig

from . import prefs, rig_bpy, scene_builder, texture_nodes
from .core.spec import EnvironmentSpec, LightSpec, MaterialSpec, ObjectSpec, SceneSpec

__all__ = [
    "INDEX_KEY",
    "MESH_CHECK_KEY",
    "MESH_KEY",
    "METADATA_KEY",
    "ROLE_LIGHT",
    "SPEC_KEY",
    "camera_spec_from_blender",
    "environment_from_blender",
    "export_scene",
    "light_spec_from_blender",
    "material_spec_from_blender",
    "matrix_array",
    "mesh_checksum",
    "view_layer_of",
    "write_preview_xml",
]

log = logging.getLogger(__name__)

#: Custom property holding the JSON of the spec an object, light or world was built from.
SPEC_KEY = "pdir_spec"
#: Object: mesh reference (``builtin:...`` or a file) and the checksum of the mesh built from it.
MESH_KEY, MESH_CHECK_KEY = "pdir_mesh", "pdir_mesh_check"
#: Object/light: position in the spec's list (export order).
INDEX_KEY = "pdir_index"
#: Scene: JSON of the spec's metadata.
METADATA_KEY = "pdir_metadata"
#: Role (custom property :data:`.rig_bpy.ROLE_KEY`) of a light laid out from a spec.
ROLE_LIGHT = "scene_light"
#: Roles of the rig's own objects (never exported as scene objects).
_RIG_ROLES = (rig_bpy.ROLE_ROOT, rig_bpy.ROLE_CAMERA, rig_bpy.ROLE_DISPLAY)
_MESH_TYPES = ("MESH", "CURVE", "SURFACE", "META", "FONT")
# Live float32 values within this of a stored spec are the stored values.
_MATCH_TOL = 1e-5


# --------------------------------------------------------------------------- small helpers


def matrix_array(m: Matrix) -> NDArray[np.float64]:
    """A mathutils matrix as a float64 array (rows as in Blender: ``(4, 4)`` for an object matrix)."""
    return np.array([list(row) for row in m], dtype=np.float64)


def _rigid(m: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(rigid (4, 4), scale (3,))`` of an affine matrix: columns normalised, translation kept."""
    scale = np.linalg.norm(m[:3, :3], axis=0)
    if not np.all(scale > 1e-12):
        raise ValueError("a transform with zero scale")
    out = np.array(m, dtype=np.float64)
    out[:3, :3] = m[:3, :3] / scale
    u, _, vt = np.linalg.svd(out[:3, :3])  # nearest rotation (float32 shear noise)
    out[:3, :3] = u @ vt
    return out, scale


def _close(a: Any, b: Any) -> bool:
    """Nested JSON values equal, numbers to :data:`_MATCH_TOL` (relative above 1)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None or isinstance(a, str):
        return a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return abs(a - b) <= _MATCH_TOL * max(1.0, abs(b))
    return a == b


def _snap(live: Any, holder: Any, cls: type) -> Any:
    """The spec stored on ``holder`` when it agrees with ``live`` to float32 precision, else ``live``."""
    payload = holder.get(SPEC_KEY) if holder is not None else None
    if payload is None:
        return live
    try:
        stored = cls.from_dict(json.loads(payload))
    except (TypeError, ValueError):
        return live
    return stored if _close(live.to_dict(), stored.to_dict()) else live


def _safe_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def view_layer_of(scene: bpy.types.Scene) -> bpy.types.ViewLayer:
    """The context's view layer when ``scene`` is the context scene, else the scene's first one."""
    ctx = bpy.context
    if getattr(ctx, "scene", None) == scene and getattr(ctx, "view_layer", None) is not None:
        return ctx.view_layer
    return scene.view_layers[0]


def mesh_checksum(mesh: bpy.types.Mesh) -> str:
    """Checksum of a mesh's vertex positions and polygon vertex indices (detects edits)."""
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    idx = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", idx)
    start = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_start", start)
    h = hashlib.sha1(co.tobytes())
    h.update(idx.tobytes())
    h.update(start.tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------- Blender -> specs


def camera_spec_from_blender(cam_obj: bpy.types.Object, scene: bpy.types.Scene) -> CameraSpec:
    """A pinhole :class:`CameraSpec` of a Blender camera, posed at the origin (identity ``to_world``).

    Sensor fit: the sensor size that Blender fits to the resolution (AUTO: ``sensor_width``
    along the larger image side; HORIZONTAL: ``sensor_width``; VERTICAL: ``sensor_height``)
    sets the pixel pitch; the resolution is the render resolution times its percentage.

    Raises:
        ValueError: not a perspective camera, or non-square pixels.
    """
    data = cam_obj.data
    if data.type != "PERSP":
        raise ValueError(f"camera {cam_obj.name!r} is {data.type}; only perspective cameras are exported")
    r = scene.render
    if abs(r.pixel_aspect_x - r.pixel_aspect_y) > 1e-6:
        raise ValueError("non-square pixels (render pixel aspect) are not supported")
    w = max(1, round(r.resolution_x * r.resolution_percentage / 100))
    h = max(1, round(r.resolution_y * r.resolution_percentage / 100))
    fit = data.sensor_fit
    if fit == "AUTO":
        pitch = data.sensor_width / max(w, h)
    elif fit == "HORIZONTAL":
        pitch = data.sensor_width / w
    else:
        pitch = data.sensor_height / h
    return CameraSpec(sensor_width_px=w, sensor_height_px=h, pixel_pitch=pitch * 1e-3, focal_length=data.lens * 1e-3)


def _principled_inputs(
    node: bpy.types.Node, warnings: list[str], where: str, textured: set[str] = frozenset()
) -> dict[str, Any]:
    out = {}
    for name in ("Base Color", "Roughness", "Metallic", "IOR", "Specular IOR Level", "Color"):
        sock = node.inputs.get(name)
        if sock is None:
            continue
        if sock.is_linked and name not in textured:
            warnings.append(f"{where}: input {name!r} is linked (texture); its default value is exported")
        out[name] = sock.default_value
    return out


def _surface_node(mat: bpy.types.Material) -> bpy.types.Node | None:
    tree = mat.node_tree
    if tree is None:
        return None
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    out = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    if out is None or not out.inputs["Surface"].is_linked:
        return None
    return out.inputs["Surface"].links[0].from_node


def material_spec_from_blender(
    mat: bpy.types.Material | None,
    warnings: list[str] | None = None,
    texture_dir: str | os.PathLike | None = None,
) -> MaterialSpec:
    """A :class:`MaterialSpec` derived from a material's surface shader (Disney parameters and textures).

    Principled BSDF: base colour -> albedo, roughness, metallic; metallic >= 0.5 gives a
    ``conductor`` reflecting the albedo at normal incidence (complex IOR ``1 - ik`` with
    ``k = 2 sqrt(R / (1 - R))``, since ``R0 = k^2 / (4 + k^2)`` at n = 1), ``Specular IOR Level``
    0 a Lambertian ``diffuse``, otherwise ``pplastic`` with the node's IOR. Image Texture nodes
    on Base Color, Roughness, Metallic and Normal become the spec's textures
    (:func:`.texture_nodes.textures_from_nodes`; packed and generated images are written to
    ``texture_dir``, default a ``blender-images`` folder beside :func:`.core.asset_materials.image_cache_dir`),
    and the textured constants their means; a textured metallic keeps the ``pplastic`` (metal
    mixed in per texel). Diffuse BSDF -> ``diffuse``; Glossy BSDF -> ``conductor`` with its
    colour; anything else (or no material) a ``diffuse`` with the viewport colour. Other linked
    inputs export their default value with a warning.
    """
    warnings = warnings if warnings is not None else []
    if mat is None:
        return MaterialSpec.diffuse("default", (0.8, 0.8, 0.8), 0.5)
    where = f"material {mat.name!r}"
    node = _surface_node(mat)
    kind = node.type if node is not None else None
    if kind in ("BSDF_PRINCIPLED", "BSDF_DIFFUSE", "BSDF_GLOSSY", "BSDF_ANISOTROPIC"):
        textures, textured = None, set()
        if kind == "BSDF_PRINCIPLED":
            textures, textured = texture_nodes.textures_from_nodes(node, _texture_dir(texture_dir), warnings, where)
        vals = _principled_inputs(node, warnings, where, textured)
        color = vals.get("Base Color", vals.get("Color"))
        albedo = tuple(float(np.clip(c, 0.0, 1.0)) for c in color[:3])
        rough = float(np.clip(vals.get("Roughness", 0.5), 0.0, 1.0))
        metal = float(np.clip(vals.get("Metallic", 1.0 if kind != "BSDF_DIFFUSE" else 0.0), 0.0, 1.0))
        if textures is not None:
            albedo, rough, metal = _texture_means(textures, (albedo, rough, metal), warnings, where)
        if kind == "BSDF_DIFFUSE":
            return MaterialSpec.diffuse(mat.name, albedo, rough)
        if kind != "BSDF_PRINCIPLED" or (metal >= 0.5 and (textures is None or textures.metallic is None)):
            r = np.clip(np.asarray(albedo), 0.0, 0.999)
            k = tuple(float(v) for v in 2.0 * np.sqrt(r / (1.0 - r)))
            return MaterialSpec(mat.name, "conductor", albedo, rough, metal, eta=(1.0, 1.0, 1.0), k=k,
                                textures=textures)  # fmt: skip
        if vals.get("Specular IOR Level", 0.5) <= 1e-6:
            return MaterialSpec(mat.name, "diffuse", albedo, rough, metal, textures=textures)
        ior = float(max(vals.get("IOR", 1.5), 1.0001))
        return MaterialSpec(mat.name, "pplastic", albedo, rough, metal, ior=ior, textures=textures)
    warnings.append(f"{where}: surface shader {kind or 'none'} is exported as a diffuse viewport colour")
    return MaterialSpec.diffuse(mat.name, tuple(float(np.clip(c, 0, 1)) for c in mat.diffuse_color[:3]), 0.5)


def _texture_dir(texture_dir: str | os.PathLike | None) -> Path:
    if texture_dir is not None:
        return Path(texture_dir)
    from .core.asset_materials import image_cache_dir  # noqa: PLC0415 - needs trimesh

    return image_cache_dir().parent / "blender-images"


def _texture_means(textures, constants: tuple, warnings: list[str], where: str) -> tuple:
    """``(albedo, roughness, metallic)``: the textured ones replaced by their textures' means."""
    from .core.textures import texture_mean  # noqa: PLC0415

    albedo, rough, metal = constants
    try:
        if textures.albedo is not None:
            albedo = tuple(float(np.clip(c, 0.0, 1.0)) for c in texture_mean(textures.albedo))
        if textures.roughness is not None:
            rough = float(np.clip(texture_mean(textures.roughness)[0], 0.0, 1.0))
        if textures.metallic is not None:
            metal = float(np.clip(texture_mean(textures.metallic)[0], 0.0, 1.0))
    except (ImportError, ValueError) as e:  # Blender's own Python lacks Pillow/OpenEXR
        warnings.append(f"{where}: texture means not computed ({e}); the node's constants are exported")
    return albedo, rough, metal


def _material_spec(mat: bpy.types.Material | None, warnings: list[str], texture_dir: Path) -> MaterialSpec:
    """The scene builder's stored spec while the node tree still shows it, else a derived one.

    "Still shows it": the Principled constants and the texture nodes (:func:`.texture_nodes.node_signature`:
    images, channels, factors, transforms) are those :func:`.scene_builder.material_from_spec` built.
    """
    if mat is None or mat.get(scene_builder.MATERIAL_KEY) is None:
        return material_spec_from_blender(mat, warnings, texture_dir)
    stored = scene_builder.material_spec_of(mat)
    node = _surface_node(mat)
    if node is not None and node.type == "BSDF_PRINCIPLED":
        live = (*node.inputs["Base Color"].default_value[:3], node.inputs["Roughness"].default_value,
                node.inputs["Metallic"].default_value)  # fmt: skip
        built = json.loads(mat.get(texture_nodes.SIGNATURE_KEY, "{}"))
        if not _close(list(live), [*stored.albedo, stored.roughness, stored.metallic]) or not _close(
            texture_nodes.node_signature(node), built
        ):
            warnings.append(f"material {mat.name!r} was edited: exported from its nodes, not its stored pBRDF")
            return material_spec_from_blender(mat, warnings, texture_dir)
    return stored


def light_spec_from_blender(obj: bpy.types.Object, matrix: NDArray, name: str | None = None) -> LightSpec:
    """A :class:`LightSpec` of a light object whose transform to the spec's world is ``matrix`` (4, 4).

    The object's scale multiplies an area light's size (as in Cycles) and is dropped otherwise;
    ``power = energy * 2**exposure``.

    Raises:
        ValueError: a mirrored light transform.
    """
    data = obj.data
    if np.linalg.det(matrix[:3, :3]) <= 0:
        raise ValueError(f"light {obj.name!r} has a mirrored or collapsed transform")
    rigid, scale = _rigid(matrix)
    power = float(data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0))
    common = {"name": name or obj.name, "to_world": rigid, "color": tuple(float(c) for c in data.color),
              "power": power}  # fmt: skip
    if data.type == "POINT":
        return LightSpec(kind="point", **common)
    if data.type == "SUN":
        return LightSpec(kind="sun", **common)
    if data.type == "SPOT":
        return LightSpec(kind="spot", spot_angle=float(data.spot_size), spot_blend=float(data.spot_blend), **common)
    if data.type == "AREA":
        square = data.shape in ("SQUARE", "DISK")
        size = (data.size * scale[0], (data.size if square else data.size_y) * scale[1])
        shape = "rectangle" if data.shape in ("SQUARE", "RECTANGLE") else "ellipse"
        return LightSpec(
            kind="area", size=size, shape=shape, normalize=bool(getattr(data, "normalize", True)), **common
        )
    raise ValueError(f"light {obj.name!r}: unsupported light type {data.type}")


def _node_from(sock: bpy.types.NodeSocket) -> bpy.types.Node | None:
    return sock.links[0].from_node if sock.is_linked else None


def environment_from_blender(
    world: bpy.types.World | None, world_to_spec: NDArray, warnings: list[str] | None = None
) -> EnvironmentSpec | None:
    """The world background as an :class:`EnvironmentSpec` (None without a world).

    Supported: a Background shader with a constant colour, or fed by an Environment Texture
    (optionally through a Mapping node of rotation only, fed by generated/object coordinates or
    nothing). ``world_to_spec`` (4, 4) takes Blender's world frame to the spec's world.
    """
    warnings = warnings if warnings is not None else []
    if world is None:
        return None
    rot = _rigid(world_to_spec)[0]
    rot[:3, 3] = 0.0
    # A constant background looks the same in every orientation: keep the stored one, if any.
    stored = world.get(SPEC_KEY)
    flat = np.asarray(json.loads(stored)["to_world"]) if stored else np.eye(4)
    tree = world.node_tree
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"] if tree is not None else []
    out = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    bg = _node_from(out.inputs["Surface"]) if out is not None else None
    if bg is None or bg.type != "BACKGROUND":
        if bg is not None:
            warnings.append(f"world {world.name!r}: shader {bg.type} is exported as the world colour")
        live = EnvironmentSpec(color=tuple(float(c) for c in world.color), to_world=flat)
        return _snap(live, world, EnvironmentSpec)
    strength = float(bg.inputs["Strength"].default_value)
    tex = _node_from(bg.inputs["Color"])
    if tex is None:
        color = tuple(float(c) for c in bg.inputs["Color"].default_value[:3])
        live = EnvironmentSpec(color=color, strength=strength, to_world=flat)
        return _snap(live, world, EnvironmentSpec)
    if tex.type != "TEX_ENVIRONMENT" or tex.image is None:
        warnings.append(f"world {world.name!r}: background colour node {tex.type} is not exported (black)")
        return _snap(EnvironmentSpec(strength=strength, to_world=flat), world, EnvironmentSpec)
    path = Path(bpy.path.abspath(tex.image.filepath)) if tex.image.filepath else None
    if path is None or not path.is_file():
        raise ValueError(f"world {world.name!r}: environment image {tex.image.name!r} has no file on disk; save it")
    mapping = _node_from(tex.inputs["Vector"])
    map_rot = np.eye(4)
    if mapping is not None and mapping.type == "MAPPING":
        euler = mapping.inputs["Rotation"].default_value
        map_rot[:3, :3] = matrix_array(euler.to_matrix())
        # The Mapping node rotates the lookup direction: the map's frame -> world is its inverse.
        map_rot = map_rot.T
    elif mapping is not None:
        warnings.append(f"world {world.name!r}: vector input {mapping.type} of the environment texture is ignored")
    live = EnvironmentSpec(strength=strength, image=str(path), to_world=rot @ map_rot)
    return _snap(live, world, EnvironmentSpec)


def _mesh_arrays(obj: bpy.types.Object, depsgraph: bpy.types.Depsgraph, matrix: NDArray) -> dict[int, dict]:
    """Triangles of an evaluated object per material index, in the frame of ``matrix`` (4, 4).

    Returns:
        ``{material_index: {"v": (N, 3), "f": (F, 3), "n": (N, 3), "uv": (N, 2) or None}}``;
        vertices are split where corner normals or UVs differ.
    """
    ev = obj.evaluated_get(depsgraph)
    try:
        c = scene_builder.triangle_corners(ev.to_mesh(), uv=True)
    finally:
        ev.to_mesh_clear()
    if c is None:
        return {}
    co, tri, normals, uv = c["co"], c["tri"], c["normals"], c["uv"]
    mat_index, loop_vert = c["material_index"], c["loop_vert"]
    lin = matrix[:3, :3]
    normal_matrix = np.linalg.inv(lin).T
    mirrored = np.linalg.det(lin) < 0
    out = {}
    for m in np.unique(mat_index):
        corners = tri[mat_index == m]  # (F, 3) loop indices
        flat = corners.ravel()
        key = np.column_stack([loop_vert[flat].astype(np.float64), normals[flat], *(() if uv is None else (uv[flat],))])
        unique, inverse = np.unique(key, axis=0, return_inverse=True)
        faces = inverse.reshape(-1, 3)
        if mirrored:
            faces = faces[:, ::-1]
        v = co[unique[:, 0].astype(np.int64)].astype(np.float64) @ lin.T + matrix[:3, 3]
        n = unique[:, 1:4] @ normal_matrix.T
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        out[int(m)] = {"v": v, "f": faces, "n": n, "uv": None if uv is None else unique[:, 4:6]}
    return out


def _frame(scene: bpy.types.Scene) -> tuple[bpy.types.Object | None, Rig, NDArray]:
    """``(rig root or None, rig, Blender world -> spec world (4, 4))``."""
    root = rig_bpy.find_rig_root(scene)
    if root is not None:
        return root, rig_bpy.rig_from_blender(root), np.linalg.inv(matrix_array(root.matrix_world))
    cam = scene.camera
    if cam is None:
        raise ValueError("the scene has neither a display-camera rig nor a camera: add one first")
    camera = camera_spec_from_blender(cam, scene)
    frame, _ = _rigid(matrix_array(cam.matrix_world))
    return None, Rig(camera=camera), np.linalg.inv(frame)


def _to_spec_frame(root: bpy.types.Object | None, world_to_spec: NDArray, obj: bpy.types.Object) -> NDArray:
    if root is not None:
        return rig_bpy.to_rig_frame(root, obj)
    return world_to_spec @ matrix_array(obj.matrix_world)


def _exported_objects(scene: bpy.types.Scene, types: tuple[str, ...]) -> list[bpy.types.Object]:
    objs = [
        o for o in scene.objects
        if o.type in types and not o.hide_render and o.get(rig_bpy.ROLE_KEY) not in _RIG_ROLES
    ]  # fmt: skip
    return sorted(objs, key=lambda o: (o.get(INDEX_KEY, 1 << 30), o.name))


def _unique(name: str, taken: set[str]) -> str:
    out, i = name, 1
    while out in taken:
        out, i = f"{name}.{i}", i + 1
    taken.add(out)
    return out


def export_scene(
    scene: bpy.types.Scene,
    out_dir: str | os.PathLike,
    *,
    xml: bool | None = None,
    warnings: list[str] | None = None,
) -> SceneSpec:
    """Export ``scene`` to ``out_dir``: ``scene.json``, ``meshes/*.ply`` and optionally ``scene.xml``.

    See the module docstring for what is exported and how.

    Args:
        scene: the Blender scene.
        out_dir: output folder (created).
        xml: write the Mitsuba preview XML; None writes it when mitsuba is importable.
        warnings: list that collects one-line warnings (textured inputs, unsupported nodes).

    Returns:
        The scene spec (also written as ``out_dir/scene.json``).

    Raises:
        ValueError: no rig and no camera, or objects the spec cannot describe.
    """
    warnings = warnings if warnings is not None else []
    out = Path(out_dir)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    view_layer = view_layer_of(scene)
    view_layer.update()
    depsgraph = view_layer.depsgraph
    root, rig, world_to_spec = _frame(scene)

    materials: dict[str, MaterialSpec] = {}

    def material_name(mat: bpy.types.Material | None) -> str:
        spec = _material_spec(mat, warnings, out / "textures")
        name = spec.name
        i = 1
        while name in materials and materials[name] != spec:
            name, i = f"{spec.name}.{i}", i + 1
        materials[name] = dataclasses.replace(spec, name=name)
        return name

    objects: list[ObjectSpec] = []
    taken: set[str] = set()
    for obj in _exported_objects(scene, _MESH_TYPES):
        matrix = _to_spec_frame(root, world_to_spec, obj)
        slots = [s.material for s in obj.material_slots]
        base = obj.get("pdir_name", obj.name)
        ref = obj.get(MESH_KEY)
        if (
            ref is not None and obj.type == "MESH" and not any(m.show_render for m in obj.modifiers)
            and obj.get(MESH_CHECK_KEY) == mesh_checksum(obj.data) and np.linalg.det(matrix[:3, :3]) > 0
        ):  # fmt: skip
            live = ObjectSpec(_unique(base, taken), ref, matrix, material_name(slots[0] if slots else None))
            objects.append(_snap(live, obj, ObjectSpec))
            continue
        parts = _mesh_arrays(obj, depsgraph, matrix)
        if not parts:
            warnings.append(f"object {obj.name!r} has no faces; skipped")
            continue
        for index, arrays in parts.items():
            mat = slots[index] if index < len(slots) else None
            name = _unique(base if len(parts) == 1 else f"{base}.{mat.name if mat else index}", taken)
            path = out / "meshes" / f"{_safe_name(name)}.ply"
            from .core.ply_io import write_ply_arrays  # noqa: PLC0415 - bpy-free core, numpy only

            write_ply_arrays(path, arrays["v"], arrays["f"], normals=arrays["n"], uvs=arrays["uv"])
            objects.append(ObjectSpec(name, str(path.resolve()), material=material_name(mat)))

    lights = []
    taken_lights: set[str] = set()
    for obj in _exported_objects(scene, ("LIGHT",)):
        try:
            live = light_spec_from_blender(obj, _to_spec_frame(root, world_to_spec, obj))
        except ValueError as e:
            warnings.append(str(e))
            continue
        live = dataclasses.replace(live, name=_unique(obj.get("pdir_name", obj.name), taken_lights))
        lights.append(_snap(live, obj, LightSpec))
    environment = environment_from_blender(scene.world, world_to_spec, warnings)
    try:
        metadata = json.loads(scene.get(METADATA_KEY, "{}"))
    except (TypeError, ValueError):
        metadata = {}
    spec = SceneSpec(
        rig=rig,
        objects=tuple(objects),
        materials=tuple(materials.values()),
        seed=int(scene.get(scene_builder.SEED_KEY, 0)),
        metadata=metadata,
        lights=tuple(lights),
        environment=environment,
    )
    spec.save(out / "scene.json")
    if xml or (xml is None and prefs.importable("mitsuba", "drjit")):
        write_preview_xml(spec, out, display=root is not None)
    for w in warnings:
        log.warning("export: %s", w)
    return spec


def write_preview_xml(spec: SceneSpec, out_dir: str | os.PathLike, *, display: bool = True) -> Path:
    """Write the RGB preview scene of ``spec`` as ``out_dir/scene.xml`` (files in ``out_dir/preview``).

    Args:
        spec: the exported scene.
        out_dir: the export folder.
        display: include the rig's display as a light (scenes exported without a rig have none).

    Returns:
        The path of ``scene.xml``.
    """
    import mitsuba as mi  # noqa: PLC0415

    from .core import mitsuba_preview  # noqa: PLC0415
    from .core.render import choose_rgb_variant  # noqa: PLC0415

    variant = choose_rgb_variant()
    if mi.variant() != variant:
        mi.set_variant(variant)
    out = Path(out_dir)
    scene = mitsuba_preview.preview_scene_dict(spec, out / "preview", resolution=None, display=display)
    return mitsuba_preview.write_xml(scene, out / "scene.xml")
