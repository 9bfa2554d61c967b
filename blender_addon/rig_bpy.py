"""The display-camera rig in Blender, kept equal to the bpy-free :class:`~pbrdf.sensor.rig.Rig`.

Objects (in the collection "PDIR Rig"):
    - the rig root, an empty: the rig frame of :mod:`pbrdf.sensor.rig` (metres, x right, y up, the
      camera looking along -z). Moving it moves the whole rig and the objects parented to it.
    - the camera, a child of the root with ``matrix_basis = CameraSpec.camera_to_world()``:
      Blender cameras also look down their local -z with y up, so no axis change is needed.
      Horizontal sensor fit, ``sensor_width = W * pixel_pitch``, ``lens = focal_length``, no
      shift (principal point at the sensor centre), render resolution ``W x H``.
    - the display, a child of the root with ``matrix_basis = DisplaySpec.display_to_world()``:
      an emissive mesh in display-local coordinates (flat quad, or a strip of facets of at most
      1 degree on the 1000R-style cylinder, vertices exactly on
      :meth:`~pbrdf.sensor.rig.DisplaySpec.surface_points_local`) showing the pattern through an Image
      Texture with Closest interpolation (Non-Color, rows flipped: Blender's pixel row 0 is the
      bottom), Emission strength = ``radiance``; the back side is black.

Convention (Blender frame):
    The root is rotated by +90 degrees about Blender's X axis, so the camera looks along Blender
    +Y and the rig's up (+y) is Blender's up (+Z). :func:`rig_from_blender` and
    :func:`to_rig_frame` express everything relative to the root, so the root's own pose never
    enters the spec. Example: rig point ``(0, 0, -0.5)`` (0.5 m in front of the camera) is
    Blender point ``(0, 0.5, 0)`` when the root sits at the origin.

Exactness: Blender stores object transforms, lens and sensor size as float32. The root keeps the
last applied rig as JSON (custom property ``pdir_rig``); :func:`rig_from_blender` returns those
exact numbers for every part whose live Blender value agrees with them to float32 precision and
the live values for parts the user has changed (moved camera or display, edited lens).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import bpy
import numpy as np
from bpy.props import StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper
from mathutils import Matrix
from numpy.typing import NDArray

from pbrdf.sensor.rig import BUILTIN_PATTERNS, CameraSpec, DisplaySpec, Rig

__all__ = [
    "CLASSES",
    "ROLE_KEY",
    "RIG_KEY",
    "ROOT_MATRIX",
    "add_rig",
    "apply_rig",
    "find_rig_root",
    "rig_from_blender",
    "rig_from_settings",
    "rig_parts",
    "save_rig_json",
    "settings_from_rig",
    "to_rig_frame",
    "update_from_setting",
]

#: Custom property naming an object's part in the add-on's scene ("rig_root", "rig_camera", ...).
ROLE_KEY = "pdir_role"
ROLE_ROOT, ROLE_CAMERA, ROLE_DISPLAY = "rig_root", "rig_camera", "rig_display"
#: Custom property on the root holding the JSON of the last applied rig (exact values).
RIG_KEY = "pdir_rig"
#: Pose of a new root in Blender: +90 degrees about X (camera looks along Blender +Y, rig y up = +Z).
ROOT_MATRIX = Matrix.Rotation(math.pi / 2, 4, "X")

COLLECTION_NAME = "PDIR Rig"
_PATTERN_NODE, _EMISSION_NODE = "PDIR Pattern", "PDIR Emission"
# Live float32 values within this of the stored rig are the stored values (float32 carries about
# 7 significant digits: 1e-7 relative on metre-sized numbers, far below any deliberate edit).
_MATCH_TOL = 1e-5
_CURVED_FACET = math.radians(1.0)  # chord sag R (1 - cos 0.5 deg) = 0.04 mm at 1000R

_syncing = False  # True while settings_from_rig writes the panel settings (their updates skip)


# --------------------------------------------------------------------------- matrices and lookup


def _np(m: Matrix) -> NDArray[np.float64]:
    return np.array([list(row) for row in m], dtype=np.float64)


def _matrix(a: NDArray) -> Matrix:
    return Matrix(np.asarray(a, dtype=np.float64).tolist())


def find_rig_root(scene: bpy.types.Scene) -> bpy.types.Object | None:
    """The rig root of ``scene`` (the first by name if there are several), or None."""
    roots = sorted((o for o in scene.objects if o.get(ROLE_KEY) == ROLE_ROOT), key=lambda o: o.name)
    return roots[0] if roots else None


def rig_parts(root: bpy.types.Object) -> tuple[bpy.types.Object, bpy.types.Object]:
    """``(camera, display)`` objects of a rig root.

    Raises:
        ValueError: the root is not a rig root or lacks one of its parts.
    """
    if root.get(ROLE_KEY) != ROLE_ROOT or RIG_KEY not in root:
        raise ValueError(f"object {root.name!r} is not a rig root (add one with 'Add display-camera rig')")
    parts = {}
    for child in root.children:
        role = child.get(ROLE_KEY)
        if role in (ROLE_CAMERA, ROLE_DISPLAY) and role not in parts:
            parts[role] = child
    for role, what in ((ROLE_CAMERA, "camera"), (ROLE_DISPLAY, "display")):
        if role not in parts:
            raise ValueError(f"rig {root.name!r} has no {what} child (was it deleted or unparented?)")
    return parts[ROLE_CAMERA], parts[ROLE_DISPLAY]


def to_rig_frame(root: bpy.types.Object, obj: bpy.types.Object) -> NDArray[np.float64]:
    """Transform ``(4, 4)`` from ``obj``'s local coordinates to the rig frame of ``root``.

    For descendants of the root it is composed from parent inverses and local matrices (exact
    without a depsgraph update); other objects use the world matrices (call
    ``view_layer.update()`` first if they were just moved).
    """
    m = Matrix.Identity(4)
    o = obj
    while o is not None and o != root:
        m = o.matrix_parent_inverse @ o.matrix_basis @ m
        o = o.parent
    if o is None:
        m = root.matrix_world.inverted() @ obj.matrix_world
    return _np(m)


# --------------------------------------------------------------------------- Blender -> spec


def _stored_rig(root: bpy.types.Object) -> Rig:
    try:
        return Rig.from_dict(json.loads(root[RIG_KEY]))
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"rig {root.name!r}: invalid stored rig ({RIG_KEY}): {e}") from None


def _close(live: float, stored: float) -> bool:
    return abs(live - stored) <= _MATCH_TOL * max(1.0, abs(stored))


def _live_camera(root: bpy.types.Object, cam_obj: bpy.types.Object, base: CameraSpec) -> CameraSpec:
    data = cam_obj.data
    m = to_rig_frame(root, cam_obj)
    changes: dict[str, Any] = {}
    if np.max(np.abs(m - base.camera_to_world())) > _MATCH_TOL:
        changes["to_world"] = tuple(map(tuple, m))
    if not _close(data.lens, base.focal_length * 1e3):
        changes["focal_length"] = data.lens * 1e-3
    if not _close(data.sensor_width, base.sensor_width_m * 1e3):
        changes["pixel_pitch"] = data.sensor_width * 1e-3 / base.sensor_width_px
    try:
        return dataclasses.replace(base, **changes)
    except ValueError as e:
        raise ValueError(f"rig camera {cam_obj.name!r}: {e} (remove scale from the camera object)") from None


def _live_display(root: bpy.types.Object, disp_obj: bpy.types.Object, base: DisplaySpec) -> DisplaySpec:
    m = to_rig_frame(root, disp_obj)
    if np.max(np.abs(m - base.display_to_world())) <= _MATCH_TOL:
        return base
    rot = m[:3, :3]
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
        raise ValueError(f"rig display {disp_obj.name!r} is scaled; set its size in the panel instead")
    a = rot @ np.diag([-1.0, 1.0, -1.0])  # = Ry(yaw) Rx(pitch), see DisplaySpec.world_trans_display
    if abs(a[1, 0]) > 1e-5:
        raise ValueError(
            f"rig display {disp_obj.name!r} is rolled about its normal; the rig spec has only yaw and pitch"
        )
    return dataclasses.replace(
        base,
        center=tuple(float(v) for v in m[:3, 3]),
        yaw=math.atan2(-a[2, 0], a[0, 0]),
        pitch=math.atan2(-a[1, 2], a[1, 1]),
    )


def rig_from_blender(root: bpy.types.Object) -> Rig:
    """The rig spec of the rig under ``root``, in the root's frame.

    Camera pose, focal length, sensor width and display pose come from the Blender objects
    (exact stored values where they are unchanged, see the module docstring); display size,
    curvature, pattern, brightness, polarization and the camera model come from the stored rig,
    which the panel settings edit.

    Raises:
        ValueError: not a rig root, missing parts, or objects the spec cannot describe (scaled
            camera or display, display rolled about its normal).
    """
    base = _stored_rig(root)
    cam_obj, disp_obj = rig_parts(root)
    return Rig(display=_live_display(root, disp_obj, base.display), camera=_live_camera(root, cam_obj, base.camera))


def save_rig_json(root: bpy.types.Object, path: str | os.PathLike) -> Rig:
    """Write :func:`rig_from_blender` as rig JSON (atomically) and return it."""
    rig = rig_from_blender(root)
    rig.save(path)
    return rig


# --------------------------------------------------------------------------- spec -> Blender


def _display_mesh(mesh: bpy.types.Mesh, display: DisplaySpec) -> None:
    """Fill ``mesh`` with the display surface in display-local coordinates, UVs over the active area."""
    w, h = display.width, display.height
    n = 1 if display.curvature_radius is None else max(2, math.ceil(w / display.curvature_radius / _CURVED_FACET))
    xs = np.linspace(-w / 2, w / 2, n + 1)  # exact corners at +-w/2
    xy = np.stack([np.concatenate([xs, xs]), np.repeat([-h / 2, h / 2], n + 1)], axis=-1)
    verts = display.surface_points_local(xy)
    # Counter-clockwise seen from the front (+Z_d): front normals point toward the objects.
    faces = [(i, i + 1, n + 2 + i, n + 1 + i) for i in range(n)]
    mesh.clear_geometry()
    mesh.from_pydata(verts.tolist(), [], faces)
    uv_layer = mesh.uv_layers.new(name="UVMap")
    loop_vert = np.empty(len(mesh.loops), dtype=np.int64)
    mesh.loops.foreach_get("vertex_index", loop_vert)
    uv = np.stack([xy[:, 0] / w + 0.5, xy[:, 1] / h + 0.5], axis=-1)[loop_vert]
    uv_layer.data.foreach_set("uv", uv.astype(np.float32).ravel())
    mesh.update()


def _pattern_image(display: DisplaySpec) -> bpy.types.Image:
    """The display pattern as a Blender image (Non-Color; built-ins generated and packed).

    Raises:
        FileNotFoundError: a pattern file that does not exist.
    """
    if display.pattern in BUILTIN_PATTERNS:
        pixels = display.pattern_image()  # (H, W, 3), row 0 = top
        h, w = pixels.shape[:2]
        name = f"PDIR Pattern {display.pattern}"
        img = bpy.data.images.get(name)
        if img is None or tuple(img.size) != (w, h) or img.source != "FILE":
            img = bpy.data.images.new(name, w, h, alpha=False, float_buffer=True)
            rgba = np.ones((h, w, 4), dtype=np.float32)
            rgba[..., :3] = pixels[::-1]  # Blender's pixel row 0 is the bottom
            img.pixels.foreach_set(rgba.ravel())
            img.update()
            img.pack()  # a generated image with edited pixels would be lost on save otherwise
    else:
        path = Path(bpy.path.abspath(display.pattern))
        if not path.is_file():
            raise FileNotFoundError(f"display pattern image not found: {path}")
        img = bpy.data.images.load(str(path), check_existing=True)
    img.colorspace_settings.name = "Non-Color"  # pattern values are linear radiance factors
    return img


def _display_material(name: str) -> bpy.types.Material:
    """Emission from the pattern texture on the front, black diffuse on the back."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender < 5.0 creates the node tree on request only
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    mix = nodes.new("ShaderNodeMixShader")
    geometry = nodes.new("ShaderNodeNewGeometry")
    emission = nodes.new("ShaderNodeEmission")
    emission.name = emission.label = _EMISSION_NODE
    tex = nodes.new("ShaderNodeTexImage")
    tex.name = tex.label = _PATTERN_NODE
    tex.interpolation = "Closest"
    tex.extension = "EXTEND"
    back = nodes.new("ShaderNodeBsdfDiffuse")
    back.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    links.new(tex.outputs["Color"], emission.inputs["Color"])
    links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
    links.new(emission.outputs["Emission"], mix.inputs[1])
    links.new(back.outputs["BSDF"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    for i, node in enumerate((tex, geometry, emission, back, mix, out)):
        node.location = (-600 + 200 * i, 0)
    return mat


def display_nodes(disp_obj: bpy.types.Object) -> tuple[bpy.types.ShaderNodeTexImage, bpy.types.ShaderNodeEmission]:
    """``(pattern texture, emission)`` nodes of the display's material."""
    mat = disp_obj.data.materials[0] if disp_obj.data.materials else None
    if mat is None or mat.node_tree is None or _PATTERN_NODE not in mat.node_tree.nodes:
        raise ValueError(f"rig display {disp_obj.name!r} lost its pattern material")
    nodes = mat.node_tree.nodes
    return nodes[_PATTERN_NODE], nodes[_EMISSION_NODE]


def apply_rig(root: bpy.types.Object, rig: Rig) -> None:
    """Make the rig objects under ``root`` show ``rig`` and store it as the root's exact rig.

    Also sets the render resolution of every scene using the root to the sensor's ``W x H``.

    Raises:
        ValueError: missing rig parts.
        FileNotFoundError: a pattern file that does not exist (nothing is changed then).
    """
    cam_obj, disp_obj = rig_parts(root)
    image = _pattern_image(rig.display)  # may raise: before any change
    cam = rig.camera
    data = cam_obj.data
    data.type = "PERSP"
    data.lens_unit = "MILLIMETERS"
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = cam.sensor_width_m * 1e3
    data.sensor_height = cam.sensor_height_m * 1e3  # unused by the horizontal fit; kept consistent
    data.lens = cam.focal_length * 1e3
    data.shift_x = data.shift_y = 0.0
    data.clip_start, data.clip_end = 0.01, 100.0
    cam_obj.matrix_parent_inverse = Matrix.Identity(4)
    cam_obj.matrix_basis = _matrix(cam.camera_to_world())
    for scene in root.users_scene:
        scene.render.resolution_x, scene.render.resolution_y = cam.sensor_width_px, cam.sensor_height_px
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
        if scene.camera is None:
            scene.camera = cam_obj
    _display_mesh(disp_obj.data, rig.display)
    disp_obj.matrix_parent_inverse = Matrix.Identity(4)
    disp_obj.matrix_basis = _matrix(rig.display.display_to_world())
    tex, emission = display_nodes(disp_obj)
    tex.image = image
    emission.inputs["Strength"].default_value = rig.display.radiance
    root[RIG_KEY] = json.dumps(rig.to_dict())


def add_rig(scene: bpy.types.Scene, rig: Rig | None = None) -> bpy.types.Object:
    """Add the display-camera rig to ``scene`` (or update the existing one) and return its root.

    Args:
        scene: the scene.
        rig: the rig to show; default: the existing rig's current state, else :class:`Rig` ().

    The camera becomes the scene camera.
    """
    root = find_rig_root(scene)
    if root is not None:
        apply_rig(root, rig or rig_from_blender(root))
        scene.camera = rig_parts(root)[0]
        return root
    coll = bpy.data.collections.new(COLLECTION_NAME)
    scene.collection.children.link(coll)
    root = bpy.data.objects.new("PDIR Rig", None)
    root.empty_display_type = "ARROWS"
    root.empty_display_size = 0.1
    root[ROLE_KEY] = ROLE_ROOT
    root[RIG_KEY] = json.dumps(Rig().to_dict())
    root.matrix_basis = ROOT_MATRIX
    coll.objects.link(root)
    cam_obj = bpy.data.objects.new("PDIR Camera", bpy.data.cameras.new("PDIR Camera"))
    disp_mesh = bpy.data.meshes.new("PDIR Display")
    disp_mesh.materials.append(_display_material("PDIR Display"))
    disp_obj = bpy.data.objects.new("PDIR Display", disp_mesh)
    for obj, role in ((cam_obj, ROLE_CAMERA), (disp_obj, ROLE_DISPLAY)):
        obj[ROLE_KEY] = role
        coll.objects.link(obj)
        obj.parent = root
    disp_obj.visible_shadow = False  # the panel is a light source, not an occluder of the scene
    apply_rig(root, rig or Rig())
    scene.camera = cam_obj
    return root


# --------------------------------------------------------------------------- panel settings


def _f32(value: float, exponent: int = 0) -> float:
    """A float property read back as the decimal the user typed, times ``10**exponent``.

    Blender stores float properties as float32 (about 7 significant digits); printing 7 digits
    recovers the typed decimal, and parsing it with the exponent gives the nearest double, so
    3.45 um becomes exactly ``3.45e-6``.
    """
    return float(f"{value:.7g}e{exponent}")


def _f32_angle(value: float) -> float:
    """An angle property (radians, shown and typed in degrees) read back as the typed degrees."""
    return math.radians(float(f"{math.degrees(value):.7g}"))


def _pattern_kwargs(s: Any) -> dict:
    if s.display_pattern != "FILE":
        return {"pattern": s.display_pattern}
    if not s.display_pattern_file.strip():
        raise ValueError("choose a display pattern image file")
    return {"pattern": bpy.path.abspath(s.display_pattern_file.strip())}


#: Panel setting -> (rig part, function of the settings returning that part's changed fields).
_SETTING_FIELDS: dict[str, tuple[str, Callable[[Any], dict]]] = {
    "display_width": ("display", lambda s: {"width": _f32(s.display_width)}),
    "display_height": ("display", lambda s: {"height": _f32(s.display_height)}),
    "display_center": ("display", lambda s: {"center": tuple(_f32(v) for v in s.display_center)}),
    "display_yaw": ("display", lambda s: {"yaw": _f32_angle(s.display_yaw)}),
    "display_pitch": ("display", lambda s: {"pitch": _f32_angle(s.display_pitch)}),
    "display_curved": (
        "display",
        lambda s: {"curvature_radius": _f32(s.display_curvature_radius) if s.display_curved else None},
    ),
    "display_curvature_radius": (
        "display",
        lambda s: {"curvature_radius": _f32(s.display_curvature_radius) if s.display_curved else None},
    ),
    "display_pattern": ("display", _pattern_kwargs),
    "display_pattern_file": ("display", _pattern_kwargs),
    "display_brightness": ("display", lambda s: {"radiance": _f32(s.display_brightness)}),
    "display_polarization_angle": (
        "display",
        lambda s: {"polarization_angle": _f32_angle(s.display_polarization_angle)},
    ),
    "camera_focal_length": ("camera", lambda s: {"focal_length": _f32(s.camera_focal_length, -3)}),
    "camera_resolution": (
        "camera",
        lambda s: {"sensor_width_px": int(s.camera_resolution[0]), "sensor_height_px": int(s.camera_resolution[1])},
    ),
    "camera_pixel_pitch": ("camera", lambda s: {"pixel_pitch": _f32(s.camera_pixel_pitch, -6)}),
}


def _with_settings(rig: Rig, settings: Any, fields: list[str]) -> Rig:
    changes: dict[str, dict] = {"display": {}, "camera": {}}
    for name in fields:
        part, fn = _SETTING_FIELDS[name]
        changes[part].update(fn(settings))
    return Rig(
        display=dataclasses.replace(rig.display, **changes["display"]),
        camera=dataclasses.replace(rig.camera, **changes["camera"]),
    )


def rig_from_settings(settings: Any, base: Rig | None = None) -> Rig:
    """The rig described by the panel settings (``scene.pdir_rig``) on top of ``base``.

    The camera pose and model come from ``base`` (default :class:`Rig` ()).

    Raises:
        ValueError: settings that make an invalid rig (the message names the field).
    """
    return _with_settings(base or Rig(), settings, list(_SETTING_FIELDS))


def settings_from_rig(settings: Any, rig: Rig) -> None:
    """Show ``rig`` in the panel settings (without triggering their update callbacks)."""
    global _syncing
    d, c = rig.display, rig.camera
    _syncing = True
    try:
        settings.display_width, settings.display_height = d.width, d.height
        settings.display_center = d.center
        settings.display_yaw, settings.display_pitch = d.yaw, d.pitch
        settings.display_curved = d.curvature_radius is not None
        if d.curvature_radius is not None:
            settings.display_curvature_radius = d.curvature_radius
        if d.pattern in BUILTIN_PATTERNS:
            settings.display_pattern = d.pattern
        else:
            settings.display_pattern, settings.display_pattern_file = "FILE", d.pattern
        settings.display_brightness = d.radiance
        settings.display_polarization_angle = d.polarization_angle
        settings.camera_focal_length = c.focal_length * 1e3
        settings.camera_resolution = (c.sensor_width_px, c.sensor_height_px)
        settings.camera_pixel_pitch = c.pixel_pitch * 1e6
        settings.error = ""
    finally:
        _syncing = False


def update_from_setting(scene: bpy.types.Scene, name: str) -> None:
    """Apply the panel setting ``name`` to the scene's rig (the update callback of every setting).

    Only that setting's field changes, so edits made in the viewport (a moved display or
    camera) survive. Errors (an invalid combination) are shown in the panel, not raised.
    """
    if _syncing:
        return
    settings = scene.pdir_rig
    root = find_rig_root(scene)
    try:
        if root is None:
            rig_from_settings(settings)  # validate only: the settings seed the next new rig
        else:
            rig = _with_settings(rig_from_blender(root), settings, [name])
            apply_rig(root, rig)
            settings_from_rig(settings, rig)
        settings.error = ""
    except (ValueError, FileNotFoundError) as e:
        settings.error = str(e)


# --------------------------------------------------------------------------- operators


def _root_or_report(op: bpy.types.Operator, context: bpy.types.Context) -> bpy.types.Object | None:
    root = find_rig_root(context.scene)
    if root is None:
        op.report({"ERROR"}, "No display-camera rig in the scene: add one first")
    return root


class PDIR_OT_add_rig(bpy.types.Operator):
    """Add the polarized display and the polarization camera as one rig (or update the existing rig)."""

    bl_idname = "pdir.add_rig"
    bl_label = "Add Display-Camera Rig"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Build the rig from the panel settings."""
        scene = context.scene
        existed = find_rig_root(scene) is not None
        try:
            base = rig_from_blender(find_rig_root(scene)) if existed else None
            rig = rig_from_settings(scene.pdir_rig, base)
            root = add_rig(scene, rig)
        except (ValueError, FileNotFoundError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        settings_from_rig(scene.pdir_rig, rig)
        fov = math.degrees(rig.camera.fov_x)
        self.report({"INFO"}, f"{'Updated' if existed else 'Added'} rig {root.name!r} (horizontal FOV {fov:.2f} deg)")
        return {"FINISHED"}


class PDIR_OT_rig_to_json(bpy.types.Operator, ExportHelper):
    """Write the rig as it is in Blender to a rig JSON file (for the renderer and the decoder)."""

    bl_idname = "pdir.rig_to_json"
    bl_label = "Export Rig JSON"
    bl_options = {"REGISTER"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Write the file."""
        root = _root_or_report(self, context)
        if root is None:
            return {"CANCELLED"}
        try:
            save_rig_json(root, bpy.path.abspath(self.filepath))
        except (ValueError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Wrote rig to {self.filepath}")
        return {"FINISHED"}


class PDIR_OT_rig_from_json(bpy.types.Operator, ImportHelper):
    """Load a rig JSON file (complete or partial overrides) into the panel and the scene's rig."""

    bl_idname = "pdir.rig_from_json"
    bl_label = "Load Rig JSON"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Read the file and apply it."""
        scene = context.scene
        try:
            rig = Rig.load(bpy.path.abspath(self.filepath))
            root = add_rig(scene, rig)
        except (ValueError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        settings_from_rig(scene.pdir_rig, rig)
        self.report({"INFO"}, f"Loaded rig {self.filepath} into {root.name!r}")
        return {"FINISHED"}


CLASSES = (PDIR_OT_add_rig, PDIR_OT_rig_to_json, PDIR_OT_rig_from_json)
