"""Export a Blender scene to a scene spec + PLY meshes + Mitsuba XML, and render it polarized.

Export (:func:`export_scene`, operator ``pdir.export_scene``):
    - Frame: the spec's world is the rig frame of :mod:`.rig_bpy` when the scene has a rig root
      (its camera is the rig camera, :func:`.rig_bpy.rig_from_blender`), else the frame of the
      scene camera (x right, y up, looking along -z, as :mod:`.core.rig`), with the default
      display 5 cm behind it.
    - Meshes: every visible mesh-like object except the rig's own parts, evaluated (modifiers
      applied), split per material slot, written as binary PLY in rig-frame coordinates (the
      object's ``to_world`` is then the identity) from ``loop_triangles`` and corner normals read
      with ``foreach_get`` (flat and smooth shading survive; mirrored objects are re-wound).
      Objects laid out from a spec by :func:`build_from_spec` keep their mesh reference
      (``builtin:...`` or a file) while their mesh data is unchanged (checksum).
    - Materials: the :class:`~.core.spec.MaterialSpec` stored by the scene builder
      (:func:`.scene_builder.material_spec_of`) while the Principled BSDF still shows its Disney
      parameters; otherwise one derived from the node tree (:func:`material_spec_from_blender`).
    - Lights (point, spot, area, sun) and the world (background colour or an Environment
      Texture) in Blender's units: see :class:`~.core.spec.LightSpec` for the conversions to
      Mitsuba (area radiance ``energy / (pi A)``, point intensity ``energy / (4 pi)`` W/sr, sun
      irradiance ``strength`` W/m^2).
    - Exactness: values a spec put into Blender (float32 there) come back exactly while the live
      values agree with the stored spec (custom properties ``pdir_spec``), so spec -> Blender ->
      spec is the identity (:func:`roundtrip_spec`).
    - Output folder: ``scene.json`` (the spec), ``meshes/*.ply`` and, when mitsuba is importable,
      ``scene.xml``, the RGB preview scene of :func:`.core.mitsuba_scene.preview_scene_dict`.

Polarized render (:func:`render_polarized`, operator ``pdir.render_polarized``), two routes:
    - In Blender's Python, when mitsuba, drjit, scipy and trimesh import there (install them
      with ``<blender python> -m pip install mitsuba scipy trimesh``): the exported spec goes
      through :func:`.core.generate.render_sample` in-process.
    - Otherwise through an external Python that has them (the add-on preference "Python with
      Mitsuba", or the environment variable ``PDIR_PYTHON``, e.g. the project's
      ``.venv/bin/python``): ``python -m headless.render --scene scene.json --npz ...`` in a
      subprocess (run from the repository when the add-on sits in a checkout; otherwise that
      Python needs the project installed, ``pip install -e .``), then the sample's ``.npz`` is
      read back (numpy only).
    - Neither: the operator fails with a one-line how-to.
    Both routes give the same sample for the same seeds. The nine maps and the Stokes images
    become float images ``PDIR <map>`` (``PDIR R_unpol`` ... ``PDIR B_CP``), ``PDIR S0`` ...
    ``PDIR S3`` (RGB = the three colour channels) and ``PDIR mask`` (:data:`IMAGE_NAMES`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import bpy
import numpy as np
from bpy.props import BoolProperty, IntProperty, PointerProperty, StringProperty
from mathutils import Matrix
from numpy.typing import NDArray

from pbrdf.sensor.rig import CameraSpec, Rig

from . import rig_bpy, scene_builder
from .core.spec import EnvironmentSpec, LightSpec, MaterialSpec, ObjectSpec, SceneSpec
from .ui import SidebarPanel

__all__ = [
    "CLASSES",
    "IMAGE_NAMES",
    "build_from_spec",
    "camera_spec_from_blender",
    "environment_from_blender",
    "export_scene",
    "external_python",
    "load_images",
    "light_spec_from_blender",
    "material_spec_from_blender",
    "render_polarized",
    "roundtrip_spec",
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
ROLE_LIGHT = "scene_light"
#: Roles of the rig's own objects (never exported as scene objects).
_RIG_ROLES = (rig_bpy.ROLE_ROOT, rig_bpy.ROLE_CAMERA, rig_bpy.ROLE_DISPLAY)
_MESH_TYPES = ("MESH", "CURVE", "SURFACE", "META", "FONT")
# Live float32 values within this of a stored spec are the stored values.
_MATCH_TOL = 1e-5
_MAP_NAMES = ("R_unpol", "G_unpol", "B_unpol", "R_LP", "G_LP", "B_LP", "R_CP", "G_CP", "B_CP")
#: Names of the images :func:`load_images` creates.
IMAGE_NAMES = (*(f"PDIR {n}" for n in _MAP_NAMES), *(f"PDIR S{k}" for k in range(4)), "PDIR mask")
#: Python packages the in-process render needs in Blender's Python.
INPROCESS_PACKAGES = ("mitsuba", "drjit", "scipy", "trimesh")
#: Environment variable naming an external Python with mitsuba (after the add-on preference).
PYTHON_ENV = "PDIR_PYTHON"
_REPO_ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- small helpers


def _np(m: Matrix) -> NDArray[np.float64]:
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


def _view_layer(scene: bpy.types.Scene) -> bpy.types.ViewLayer:
    ctx = bpy.context
    if getattr(ctx, "scene", None) == scene and getattr(ctx, "view_layer", None) is not None:
        return ctx.view_layer
    return scene.view_layers[0]


def _mesh_checksum(mesh: bpy.types.Mesh) -> str:
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


def _principled_inputs(node: bpy.types.Node, warnings: list[str], where: str) -> dict[str, Any]:
    out = {}
    for name in ("Base Color", "Roughness", "Metallic", "IOR", "Specular IOR Level", "Color"):
        sock = node.inputs.get(name)
        if sock is None:
            continue
        if sock.is_linked:
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


def material_spec_from_blender(mat: bpy.types.Material | None, warnings: list[str] | None = None) -> MaterialSpec:
    """A :class:`MaterialSpec` derived from a material's surface shader (Disney parameters).

    Principled BSDF: base colour -> albedo, roughness, metallic; metallic >= 0.5 gives a
    ``conductor`` reflecting the albedo at normal incidence (complex IOR ``1 - ik`` with
    ``k = 2 sqrt(R / (1 - R))``, since ``R0 = k^2 / (4 + k^2)`` at n = 1), ``Specular IOR Level``
    0 a Lambertian ``diffuse``, otherwise ``pplastic`` with the node's IOR. Diffuse BSDF ->
    ``diffuse``; Glossy BSDF -> ``conductor`` with its colour; anything else (or no material) a
    ``diffuse`` with the viewport colour. Linked (textured) inputs export their default value
    with a warning.
    """
    warnings = warnings if warnings is not None else []
    if mat is None:
        return MaterialSpec.diffuse("default", (0.8, 0.8, 0.8), 0.5)
    where = f"material {mat.name!r}"
    node = _surface_node(mat)
    kind = node.type if node is not None else None
    if kind in ("BSDF_PRINCIPLED", "BSDF_DIFFUSE", "BSDF_GLOSSY", "BSDF_ANISOTROPIC"):
        vals = _principled_inputs(node, warnings, where)
        color = vals.get("Base Color", vals.get("Color"))
        albedo = tuple(float(np.clip(c, 0.0, 1.0)) for c in color[:3])
        rough = float(np.clip(vals.get("Roughness", 0.5), 0.0, 1.0))
        metal = float(np.clip(vals.get("Metallic", 1.0 if kind != "BSDF_DIFFUSE" else 0.0), 0.0, 1.0))
        if kind == "BSDF_DIFFUSE":
            return MaterialSpec.diffuse(mat.name, albedo, rough)
        if kind != "BSDF_PRINCIPLED" or metal >= 0.5:
            r = np.clip(np.asarray(albedo), 0.0, 0.999)
            k = tuple(float(v) for v in 2.0 * np.sqrt(r / (1.0 - r)))
            return MaterialSpec(mat.name, "conductor", albedo, rough, metal, eta=(1.0, 1.0, 1.0), k=k)
        if vals.get("Specular IOR Level", 0.5) <= 1e-6:
            return MaterialSpec(mat.name, "diffuse", albedo, rough, metal)
        return MaterialSpec(mat.name, "pplastic", albedo, rough, metal, ior=float(max(vals.get("IOR", 1.5), 1.0001)))
    warnings.append(f"{where}: surface shader {kind or 'none'} is exported as a diffuse viewport colour")
    return MaterialSpec.diffuse(mat.name, tuple(float(np.clip(c, 0, 1)) for c in mat.diffuse_color[:3]), 0.5)


def _material_spec(mat: bpy.types.Material | None, warnings: list[str]) -> MaterialSpec:
    """The scene builder's stored spec while the node tree still shows it, else a derived one."""
    if mat is None or mat.get(scene_builder.MATERIAL_KEY) is None:
        return material_spec_from_blender(mat, warnings)
    stored = scene_builder.material_spec_of(mat)
    node = _surface_node(mat)
    if node is not None and node.type == "BSDF_PRINCIPLED":
        live = (*node.inputs["Base Color"].default_value[:3], node.inputs["Roughness"].default_value,
                node.inputs["Metallic"].default_value)  # fmt: skip
        if not _close(list(live), [*stored.albedo, stored.roughness, stored.metallic]):
            warnings.append(f"material {mat.name!r} was edited: exported from its nodes, not its stored pBRDF")
            return material_spec_from_blender(mat, warnings)
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
        map_rot[:3, :3] = _np(euler.to_matrix())
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
    mesh = ev.to_mesh()
    try:
        mesh.calc_loop_triangles()
        nv, nt, nl = len(mesh.vertices), len(mesh.loop_triangles), len(mesh.loops)
        if nt == 0:
            return {}
        co = np.empty(3 * nv, dtype=np.float32)
        mesh.vertices.foreach_get("co", co)
        tri = np.empty(3 * nt, dtype=np.int32)
        mesh.loop_triangles.foreach_get("loops", tri)
        mat_index = np.empty(nt, dtype=np.int32)
        mesh.loop_triangles.foreach_get("material_index", mat_index)
        loop_vert = np.empty(nl, dtype=np.int32)
        mesh.loops.foreach_get("vertex_index", loop_vert)
        normals = np.empty(3 * nl, dtype=np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        uv = None
        if mesh.uv_layers.active is not None:
            uv = np.empty(2 * nl, dtype=np.float32)
            mesh.uv_layers.active.data.foreach_get("uv", uv)
            uv = uv.reshape(-1, 2)
    finally:
        ev.to_mesh_clear()
    co, tri, normals = co.reshape(-1, 3), tri.reshape(-1, 3), normals.reshape(-1, 3)
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
        return root, rig_bpy.rig_from_blender(root), np.linalg.inv(_np(root.matrix_world))
    cam = scene.camera
    if cam is None:
        raise ValueError("the scene has neither a display-camera rig nor a camera: add one first")
    camera = camera_spec_from_blender(cam, scene)
    frame, _ = _rigid(_np(cam.matrix_world))
    return None, Rig(camera=camera), np.linalg.inv(frame)


def _to_spec_frame(root: bpy.types.Object | None, world_to_spec: NDArray, obj: bpy.types.Object) -> NDArray:
    if root is not None:
        return rig_bpy.to_rig_frame(root, obj)
    return world_to_spec @ _np(obj.matrix_world)


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
    view_layer = _view_layer(scene)
    view_layer.update()
    depsgraph = view_layer.depsgraph
    root, rig, world_to_spec = _frame(scene)

    materials: dict[str, MaterialSpec] = {}

    def material_name(mat: bpy.types.Material | None) -> str:
        spec = _material_spec(mat, warnings)
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
            and obj.get(MESH_CHECK_KEY) == _mesh_checksum(obj.data) and np.linalg.det(matrix[:3, :3]) > 0
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
            from .core.assets import write_ply_arrays  # noqa: PLC0415 - bpy-free core, numpy only

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
    if xml or (xml is None and _importable("mitsuba", "drjit")):
        write_preview_xml(spec, out, display=root is not None)
    for w in warnings:
        log.warning("export: %s", w)
    return spec


def write_preview_xml(spec: SceneSpec, out_dir: str | os.PathLike, *, display: bool = True) -> Path:
    """Write the RGB preview scene of ``spec`` as ``out_dir/scene.xml`` (files in ``out_dir/preview``).

    ``display``: include the rig's display as a light (scenes exported without a rig have none).
    """
    import mitsuba as mi  # noqa: PLC0415

    from .core import mitsuba_scene as ms  # noqa: PLC0415
    from .core.render import choose_rgb_variant  # noqa: PLC0415

    variant = choose_rgb_variant()
    if mi.variant() != variant:
        mi.set_variant(variant)
    out = Path(out_dir)
    scene = ms.preview_scene_dict(spec, out / "preview", resolution=None, display=display)
    return ms.write_xml(scene, out / "scene.xml")


# --------------------------------------------------------------------------- spec -> Blender


def _objects_collection(scene: bpy.types.Scene) -> bpy.types.Collection:
    """The scene builder's object collection (same role key), created if missing."""
    for coll in scene.collection.children:
        if coll.get(rig_bpy.ROLE_KEY) == scene_builder.ROLE_COLLECTION:
            return coll
    coll = bpy.data.collections.new("PDIR Objects")
    coll[rig_bpy.ROLE_KEY] = scene_builder.ROLE_COLLECTION
    scene.collection.children.link(coll)
    return coll


def _mesh_from_arrays(name: str, vertices: NDArray, faces: NDArray) -> bpy.types.Mesh:
    mesh = bpy.data.meshes.new(name)
    f = np.asarray(faces, dtype=np.int32)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    mesh.loops.add(f.size)
    mesh.loops.foreach_set("vertex_index", f.ravel())
    mesh.polygons.add(len(f))
    mesh.polygons.foreach_set("loop_start", np.arange(0, f.size, 3, dtype=np.int32))
    mesh.update()
    mesh.shade_smooth()  # the polarized renderer interpolates vertex normals too
    return mesh


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
    """Lay a scene spec out in ``scene``: the rig, its objects, lights and world; returns the rig root.

    Objects are meshes built from their mesh reference (:func:`.core.assets.load_mesh`), children
    of the rig root with ``matrix_basis = to_world``, carrying the scene builder's material
    (:func:`.scene_builder.material_from_spec`). Everything keeps its exact spec in custom
    properties, so :func:`export_scene` gives the spec back while nothing is edited.

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
        tm = assets.load_mesh(o.mesh)
        mesh = _mesh_from_arrays(o.name, np.asarray(tm.vertices), np.asarray(tm.faces))
        mesh.materials.append(scene_builder.material_from_spec(materials[o.material]))
        obj = bpy.data.objects.new(o.name, mesh)
        obj[scene_builder.MATERIAL_KEY] = o.material
        obj[MESH_KEY] = o.mesh
        obj[MESH_CHECK_KEY] = _mesh_checksum(mesh)
        _attach(obj, o, i, scene_builder.ROLE_OBJECT, coll, root)
    for i, light in enumerate(spec.lights):
        _attach(bpy.data.objects.new(light.name, _light_data(light)), light, i, ROLE_LIGHT, coll, root)
    if spec.environment is not None:
        _view_layer(scene).update()  # the root's matrix_world
        _set_world(scene, spec.environment, _np(root.matrix_world))
    scene[scene_builder.SEED_KEY] = int(spec.seed)
    scene[METADATA_KEY] = json.dumps(spec.metadata)
    _view_layer(scene).update()
    return root


def roundtrip_spec(spec: SceneSpec, work_dir: str | os.PathLike | None = None) -> SceneSpec:
    """Spec -> Blender -> spec in a fresh empty Blender session (the Blender route of ``headless/render.py``).

    Resets Blender to factory settings (an empty scene), lays the spec out with
    :func:`build_from_spec` and exports it with :func:`export_scene` into ``work_dir`` (a
    temporary folder by default, removed afterwards; meshes edited in Blender become PLYs there).
    """
    import tempfile  # noqa: PLC0415

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    build_from_spec(scene, spec)
    if work_dir is not None:
        return export_scene(scene, work_dir, xml=False)
    with tempfile.TemporaryDirectory(prefix="pdir_roundtrip_") as tmp:
        return export_scene(scene, tmp, xml=False)


# --------------------------------------------------------------------------- polarized render


def _importable(*names: str) -> bool:
    return all(importlib.util.find_spec(n) is not None for n in names)


def external_python(context: bpy.types.Context | None = None) -> Path | None:
    """The external Python with mitsuba: the add-on preference, else ``$PDIR_PYTHON``; None if unset."""
    try:
        from . import prefs  # noqa: PLC0415 - helper A's preferences module

        path = prefs.external_python(context)
    except (ImportError, AttributeError):
        path = None
    if path is None and os.environ.get(PYTHON_ENV, "").strip():
        env = Path(os.environ[PYTHON_ENV].strip())
        if not env.is_file():
            raise ValueError(f"{PYTHON_ENV}={env}: no such file")
        path = env
    return path


def how_to_get_mitsuba() -> str:
    """One line saying how to make the polarized render available."""
    missing = [n for n in INPROCESS_PACKAGES if importlib.util.find_spec(n) is None]
    return (
        f"Mitsuba rendering needs {', '.join(missing)}: run '{sys.executable} -m pip install {' '.join(missing)}', "
        f"or set a Python that has them (the project's .venv/bin/python) in the add-on preferences or ${PYTHON_ENV}"
    )


def _render_subprocess(python: Path, spec_path: Path, out: Path, resolution: int, spp: int, noise: bool) -> dict:
    if out.exists():
        if not ((out / "manifest.json").exists() or (out / "samples").exists() or not any(out.iterdir())):
            raise ValueError(f"{out}: exists and is not a render folder of the add-on; choose another output folder")
        shutil.rmtree(out)
    spec = SceneSpec.load(spec_path)
    cmd = [str(python), "-m", "headless.render", "--scene", str(spec_path), "--out", str(out), "--count", "1",
           "--seed", str(spec.seed), "--resolution", str(resolution), "--spp", str(spp), "--keep-stokes", "--npz",
           "--quiet"]  # fmt: skip
    if not noise:
        cmd.append("--no-noise")
    cwd = _REPO_ROOT if (_REPO_ROOT / "headless" / "render.py").is_file() else None
    env = dict(os.environ)
    if cwd is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(cwd), env.get("PYTHONPATH", "")]))
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        lines = [ln.strip() for ln in (proc.stderr + "\n" + proc.stdout).splitlines() if ln.strip()]
        why = [ln for ln in lines if ln.startswith(("error:", "sample 0:"))] or lines[-1:] or ["no output"]
        raise RuntimeError(f"external render failed ({python}): {why[0]}")
    with np.load(out / "arrays" / "000000.npz") as data:
        return {k: data[k] for k in data.files if k not in ("map_names", "metadata")}


def render_polarized(
    scene: bpy.types.Scene,
    out_dir: str | os.PathLike,
    *,
    resolution: int = 128,
    spp: int = 16,
    noise: bool = True,
    route: str = "auto",
    context: bpy.types.Context | None = None,
) -> tuple[dict[str, NDArray], str]:
    """Export ``scene`` and render its polarized capture; returns ``(sample, route used)``.

    Args:
        scene: the scene (a rig and objects fully in the camera view).
        out_dir: output folder: ``scene/`` (the export) and, for the subprocess route,
            ``polarized/`` (the dataset sample and its ``.npz``).
        resolution: sample size R (maps R x R).
        spp: samples per pixel per colour pass.
        noise: simulate sensor noise.
        route: ``"auto"``, ``"inprocess"`` or ``"subprocess"`` (see the module docstring).
        context: for the add-on preferences.

    Raises:
        RuntimeError: no way to run Mitsuba (the message says how to get one) or a failed
            external render.
        ValueError: an invalid scene (objects out of view, ...).
    """
    out = Path(out_dir)
    spec = export_scene(scene, out / "scene", xml=False)
    if _importable("trimesh"):  # else the external Python checks it (meshes need trimesh)
        spec.validate()
    if route == "auto":
        if _importable(*INPROCESS_PACKAGES):
            route = "inprocess"
        elif external_python(context) is not None:
            route = "subprocess"
        else:
            raise RuntimeError(how_to_get_mitsuba())
    if route == "inprocess":
        from .core import generate, render, scenegen  # noqa: PLC0415

        settings = render.RenderSettings(resolution=resolution, spp=spp, noise=noise)
        sample, _, _ = generate.render_sample(
            spec, settings, sample_seed=scenegen.sample_seed(spec.seed, 0), noise=noise, keep_stokes=True
        )
        return sample, route
    if route == "subprocess":
        python = external_python(context)
        if python is None:
            raise RuntimeError(how_to_get_mitsuba())
        return _render_subprocess(
            python, out / "scene" / "scene.json", out / "polarized", resolution, spp, noise
        ), route
    raise ValueError(f"route must be 'auto', 'inprocess' or 'subprocess', got {route!r}")


def _image(name: str, rgb: NDArray) -> bpy.types.Image:
    """A float image ``name`` (Non-Color) holding ``rgb (H, W, 3)``, row 0 at the top."""
    h, w = rgb.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and (tuple(img.size) != (w, h) or not img.is_float):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = rgb[::-1]  # Blender's pixel row 0 is the bottom
    img.pixels.foreach_set(rgba.ravel())
    img.update()
    img.pack()  # generated pixels would be lost on save otherwise
    return img


def load_images(sample: dict[str, NDArray]) -> list[bpy.types.Image]:
    """Create (or update) the images of :data:`IMAGE_NAMES` from a rendered sample.

    ``maps (H, W, 9)`` -> one grey image per map; ``stokes (H, W, 3, 4)`` -> ``PDIR S0`` ...
    ``PDIR S3`` with the colour channels as RGB; ``mask (H, W)`` -> ``PDIR mask``.
    """
    maps = np.asarray(sample["maps"], dtype=np.float32)
    out = [_image(f"PDIR {n}", np.repeat(maps[..., i : i + 1], 3, axis=-1)) for i, n in enumerate(_MAP_NAMES)]
    if "stokes" in sample:
        stokes = np.asarray(sample["stokes"], dtype=np.float32)
        out += [_image(f"PDIR S{k}", stokes[..., :, k]) for k in range(4)]
    mask = np.asarray(sample["mask"], dtype=np.float32)
    out.append(_image("PDIR mask", np.repeat(mask[..., None], 3, axis=-1)))
    return out


# --------------------------------------------------------------------------- UI


def _default_dir() -> str:
    return "//pdir_export" if bpy.data.filepath else str(Path(bpy.app.tempdir or "/tmp") / "pdir_export")


class PDIR_ExportSettings(bpy.types.PropertyGroup):
    """Settings of the export and polarized-render operators."""

    output_dir: StringProperty(
        name="Output", description="Folder for the exported scene and renders ('//' = next to the .blend file)",
        subtype="DIR_PATH", default="//pdir_export",
    )  # fmt: skip
    resolution: IntProperty(
        name="Resolution", description="Size of the rendered maps in pixels (even)", default=128, min=8, max=4096,
        step=2,
    )  # fmt: skip
    spp: IntProperty(name="Samples", description="Samples per pixel per colour pass", default=16, min=1, max=4096)
    noise: BoolProperty(name="Sensor Noise", description="Simulate the camera's sensor noise", default=True)


def _out_dir(context: bpy.types.Context) -> Path:
    settings = getattr(context.scene, "pdir_export", None)
    raw = settings.output_dir.strip() if settings is not None else ""
    if not raw or (raw.startswith("//") and not bpy.data.filepath):
        raw = _default_dir()
    return Path(bpy.path.abspath(raw))


class PDIR_OT_export_scene(bpy.types.Operator):
    """Export the scene to a scene spec (JSON), PLY meshes and a Mitsuba XML preview scene."""

    bl_idname = "pdir.export_scene"
    bl_label = "Export Scene"
    bl_options = {"REGISTER"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Export into the output folder of the panel."""
        out = _out_dir(context)
        warnings: list[str] = []
        try:
            spec = export_scene(context.scene, out, warnings=warnings)
        except (ValueError, OSError, RuntimeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for w in warnings[:5]:
            self.report({"WARNING"}, w)
        xml = " + scene.xml" if (out / "scene.xml").exists() else ""
        self.report({"INFO"}, f"Exported {len(spec.objects)} objects, {len(spec.lights)} lights to {out}{xml}")
        return {"FINISHED"}


class PDIR_OT_render_polarized(bpy.types.Operator):
    """Render the polarized capture of the scene with Mitsuba and load the nine maps and Stokes images."""

    bl_idname = "pdir.render_polarized"
    bl_label = "Render Polarized Capture"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Export, render (in-process or through the external Python) and create the images."""
        settings = getattr(context.scene, "pdir_export", None)
        resolution = settings.resolution if settings is not None else 128
        if resolution % 2:
            resolution += 1
        try:
            sample, route = render_polarized(
                context.scene, _out_dir(context), resolution=resolution,
                spp=settings.spp if settings is not None else 16,
                noise=settings.noise if settings is not None else True, context=context,
            )  # fmt: skip
            images = load_images(sample)
        except (ValueError, OSError, RuntimeError, NotImplementedError) as e:
            self.report({"ERROR"}, str(e).splitlines()[0] if str(e) else type(e).__name__)
            return {"CANCELLED"}
        where = "in Blender" if route == "inprocess" else "with the external Python"
        self.report({"INFO"}, f"Rendered {resolution}x{resolution} {where}: {len(images)} images 'PDIR ...'")
        return {"FINISHED"}


class PDIR_PT_export(SidebarPanel, bpy.types.Panel):
    """Export to Mitsuba and render the polarized capture."""

    bl_label = "Export and Render"
    bl_idname = "PDIR_PT_export"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 2

    def draw(self, context: bpy.types.Context) -> None:
        """Settings and the two buttons."""
        layout = self.layout
        settings = getattr(context.scene, "pdir_export", None)
        if settings is not None:
            layout.prop(settings, "output_dir")
        layout.operator(PDIR_OT_export_scene.bl_idname, icon="EXPORT")
        if settings is not None:
            col = layout.column(align=True)
            col.prop(settings, "resolution")
            col.prop(settings, "spp")
            col.prop(settings, "noise")
        layout.operator(PDIR_OT_render_polarized.bl_idname, icon="RENDER_STILL")
        if not _importable(*INPROCESS_PACKAGES):
            try:
                python = external_python(context)
            except ValueError as e:
                layout.label(text=str(e), icon="ERROR")
                return
            if python is None:
                layout.label(text="Mitsuba missing: see the add-on preferences", icon="ERROR")


CLASSES = (PDIR_ExportSettings, PDIR_OT_export_scene, PDIR_OT_render_polarized, PDIR_PT_export)


def register_extra() -> None:
    """Attach the settings to every scene as ``scene.pdir_export``."""
    bpy.types.Scene.pdir_export = PointerProperty(type=PDIR_ExportSettings)


def unregister_extra() -> None:
    """Remove ``scene.pdir_export``."""
    del bpy.types.Scene.pdir_export
