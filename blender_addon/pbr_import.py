"""Import predicted PBR maps as a relightable asset seen by the capture camera.

:func:`import_pbr_maps` matches and validates the map files (:mod:`.core.map_names`, :mod:`.core.map_io`), turns them
into float images packed into the .blend file (exact values, no colour transform: data maps
``Non-Color``, albedo scene-linear), and builds

* a plane parented to the camera at ``distance`` metres, its mesh sized to the camera frustum
  (object scale stays 1: a scaled object would bend the normals) with UVs aligned to the image,
  or, when a depth map is present, a mesh with one vertex per pixel displaced to its depth;
* a Principled BSDF material: albedo -> Base Color, roughness (GGX alpha = r^2 in both the
  project and Blender), metallic, mask -> Alpha, and the camera-space normals through a Normal
  Map node.

Camera: when ``<name>_camera.json`` lies beside the normal map (``headless/infer.py`` writes it;
:func:`blender_addon.core.map_names.camera_file`), the camera gets its intrinsics
(:func:`blender_addon.core.frustum.camera_from_intrinsics`: lens, 36 mm sensor fitted
horizontally, lens shift for the principal point, square pixels), so the relief mesh, integrated
with those intrinsics, keeps the capture's shape and its vertices project onto their pixel
centres. Intrinsics with ``fx != fy`` use ``fx`` for both axes, with a warning.

Sequences: a folder with ``<name>_sequence.json`` (``<name>_NNNN_<map>.exr`` per frame) gives
one material whose maps are Blender image sequences read from the files (``image_user``:
``frame_duration`` n, ``frame_start`` 1, auto refresh), with the scene's frame range set to
1..n: playing the timeline plays the frames. Blender numbers a sequence by the last digits of a
file name, so ``_0001_normal`` works. The EXR normals hold ``n`` itself: a Multiply Add node
encodes ``0.5 + 0.5 n`` for the Normal Map node. Every frame's normal, mask and depth maps are
read and validated: they must have frame 1's size, and a frame's own camera file frame 1's
intrinsics (one camera serves the sequence). With depth maps, scene frame f shows frame f's relief:
shape keys on one mesh when every frame's relief has the same vertices and triangles, else one
object per frame shown only at its frame (:mod:`.sequence_mesh`). Without depth maps (``--card``)
frame 1's plane serves every frame. Frame rate: the sequence file records no capture rate (its
``frames_per_second`` is the prediction's throughput), so the scene keeps its own frame rate,
Blender's default 24 fps in a new file. The other maps (albedo, roughness, metallic) of later
frames must exist and are read by Blender as they play.

Normals: the mesh is parented to the camera with an identity local rotation, so its object frame
IS the camera frame, and for the plane (facing the camera, UVs aligned with the image) the
tangent frame is too (tangent = +x, bitangent = +y, normal = +z). The normal image stores
``0.5 + 0.5 n`` and the Normal Map node decodes it into exactly the input normal, in either
space. A depth mesh is not flat, so its tangent frames are not the camera frame: it always uses
OBJECT space, and (imported from files, not a sequence) it carries the normals itself, as custom
normals of its smooth-shaded vertices (one per pixel); its Normal Map node stays in the material,
unlinked (why: docs/measurements/blender_addon.md, "the dark blotches").

Outline: the maps go on two pixels past the mask (:func:`blender_addon.core.map_io.extend_past_mask`)
and a depth mesh one pixel past it, so bilinear texture lookups at the outline never blend in the
values outside the mask and the mesh does not stop at the edge pixels' centres; the mask, as
alpha, cuts the asset where the mask's pixels end.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper
from mathutils import Matrix, Vector

from pbrdf.data.predictions import MAP_NAMES

from . import sequence_mesh
from .core import map_io, map_names
from .core.frustum import BlenderCamera, Frustum, blender_frustum, depth_mesh, read_camera_json
from .images import image_from_array, read_channels, sequence_image
from .mesh_arrays import mesh_from_arrays, set_vertex_normals

__all__ = [
    "CLASSES",
    "NORMAL_SPACES",
    "ImportOptions",
    "PBRImportWarning",
    "import_pbr_maps",
    "ensure_camera",
    "camera_frustum",
    "match_camera",
]

#: Normal Map node spaces that reproduce camera-space normals on the imported plane.
NORMAL_SPACES = ("TANGENT", "OBJECT")
#: Name of the UV layer of imported and baked meshes.
UV_NAME = "UVMap"


class PBRImportWarning(UserWarning):
    """Something the user should know about an import that still succeeded (clipped values, ...)."""


# --------------------------------------------------------------------------- camera


def ensure_camera(scene, camera=None):
    """``camera``, else the scene camera, else a new camera at the origin looking down -z.

    Raises:
        ValueError: not a perspective camera, or its object has a scale other than 1 (children
            would inherit it and their normals would bend).
    """
    if camera is None:
        camera = scene.camera
    if camera is None:
        data = bpy.data.cameras.new("PDIR Capture Camera")
        camera = bpy.data.objects.new("PDIR Capture Camera", data)
        scene.collection.objects.link(camera)
        scene.camera = camera
    if camera.type != "CAMERA":
        raise ValueError(f"{camera.name!r} is not a camera object (type {camera.type})")
    if camera.data.type != "PERSP":
        raise ValueError(f"camera {camera.name!r} must be a perspective camera, not {camera.data.type}")
    scale = camera.matrix_world.to_scale()
    if max(abs(s - 1.0) for s in scale) > 1e-6:
        raise ValueError(f"camera {camera.name!r} has scale {tuple(round(s, 6) for s in scale)}; set it to 1")
    return camera


def camera_frustum(camera, width: int, height: int, *, scene=None) -> Frustum:
    """The frustum of a Blender camera object at ``width x height`` pixels (``scene``'s pixel aspect, else square)."""
    cam = camera.data
    render = scene.render if scene is not None else None
    return blender_frustum(
        width,
        height,
        lens=cam.lens,
        sensor_width=cam.sensor_width,
        sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit,
        shift_x=cam.shift_x,
        shift_y=cam.shift_y,
        pixel_aspect_x=render.pixel_aspect_x if render else 1.0,
        pixel_aspect_y=render.pixel_aspect_y if render else 1.0,
    )


def match_camera(scene, camera, blender_camera: BlenderCamera) -> None:
    """Give ``camera`` the settings of ``blender_camera`` (and ``scene`` square pixels)."""
    cam = camera.data
    cam.sensor_fit = blender_camera.sensor_fit
    cam.sensor_width = blender_camera.sensor_width
    cam.sensor_height = blender_camera.sensor_height
    cam.lens_unit = "MILLIMETERS"
    cam.lens = blender_camera.lens
    cam.shift_x, cam.shift_y = blender_camera.shift_x, blender_camera.shift_y
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0


# --------------------------------------------------------------------------- mesh and material


def _plane(name: str, frustum: Frustum, distance: float):
    """A plane mesh centred at its origin covering the frustum at ``distance`` (UV (0, 0) at the lower left)."""
    hw, hh = frustum.half_width * distance, frustum.half_height * distance
    vertices = np.array([[-hw, -hh, 0.0], [hw, -hh, 0.0], [hw, hh, 0.0], [-hw, hh, 0.0]])
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return mesh_from_arrays(name, vertices, np.array([[0, 1, 2, 3]]), uvs, UV_NAME)


def _tex(nodes, image, label: str, location: tuple[float, float], frames: int = 0):
    node = nodes.new("ShaderNodeTexImage")
    node.image = image
    node.label = label
    node.interpolation = "Linear"
    node.extension = "EXTEND"
    node.location = location
    if frames:  # scene frame f shows file number f
        user = node.image_user
        user.frame_duration, user.frame_start, user.frame_offset = frames, 1, 0
        user.use_cyclic, user.use_auto_refresh = False, True
    return node


def build_material(
    name: str,
    images: Mapping[str, object],
    *,
    normal_space: str,
    use_alpha: bool,
    frames: int = 0,
    normal_raw: bool = False,
    normals_on_mesh: bool = False,
):
    """A Principled BSDF material reading ``images`` (kind -> Image) through the UV layer :data:`UV_NAME`.

    The normal image holds ``0.5 + 0.5 n`` (or ``n`` itself with ``normal_raw``: a Multiply Add
    node encodes it); it goes through a Normal Map node in ``normal_space``. ``frames`` > 0: the
    images are sequences of that many frames, scene frame f showing frame f. ``normals_on_mesh``:
    the Normal Map node is not linked to the BSDF (the mesh's own normals are the map's).
    """
    mat = bpy.data.materials.new(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (400, 0)
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.location = (100, 0)
    links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    targets = {"albedo": "Base Color", "roughness": "Roughness", "metallic": "Metallic", "mask": "Alpha"}
    for i, (kind, socket) in enumerate(targets.items()):
        if kind in images and (kind != "mask" or use_alpha):
            tex = _tex(nodes, images[kind], kind, (-500, 300 - 280 * i), frames)
            links.new(tex.outputs["Color"], bsdf.inputs[socket])
    if "normal" in images:
        tex = _tex(nodes, images["normal"], "normal", (-500, -850), frames)
        nmap = nodes.new("ShaderNodeNormalMap")
        nmap.space = normal_space
        nmap.uv_map = UV_NAME
        nmap.location = (-200, -700)
        color = tex.outputs["Color"]
        if normal_raw:
            encode = nodes.new("ShaderNodeVectorMath")
            encode.operation = "MULTIPLY_ADD"
            encode.label = "0.5 n + 0.5"
            encode.inputs[1].default_value = encode.inputs[2].default_value = (0.5, 0.5, 0.5)
            encode.location = (-350, -850)
            links.new(color, encode.inputs[0])
            color = encode.outputs["Vector"]
        links.new(color, nmap.inputs["Color"])
        if normals_on_mesh:
            nmap.label = "normal (on the mesh; unlinked)"
        else:
            links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def _asset_name(files: Mapping[str, Path]) -> str:
    stems = [p.stem for p in files.values()]
    prefix = os.path.commonprefix(stems).rstrip("_-. ")
    if len(stems) == 1:
        tokens = map_names.filename_tokens(stems[0])
        prefix = "_".join(t for t in tokens if not map_names.match_kinds((t,)))
    return prefix or "PBR asset"


def _packed_images(name: str, maps: map_io.PBRMaps) -> dict[str, object]:
    """The validated maps as packed float images (mask only from a file or the normals)."""
    images = {}
    if maps.normal is not None:
        images["normal"] = image_from_array(f"{name}_normal", 0.5 + 0.5 * maps.normal)
    if maps.albedo is not None:
        images["albedo"] = image_from_array(f"{name}_albedo", maps.albedo, colorspace="Linear Rec.709")
    for kind in ("roughness", "metallic"):
        if getattr(maps, kind) is not None:
            images[kind] = image_from_array(f"{name}_{kind}", getattr(maps, kind))
    if maps.mask_source != "none":
        images["mask"] = image_from_array(f"{name}_mask", maps.mask)
    return images


# --------------------------------------------------------------------------- import


@dataclass(frozen=True)
class ImportOptions:
    """How :func:`import_pbr_maps` builds the asset.

    Attributes:
        distance: plane distance from the camera in metres (ignored for a depth mesh).
        normal_space: ``"TANGENT"`` or ``"OBJECT"`` (identical on the plane; a depth mesh uses OBJECT).
        use_depth: build a depth-displaced mesh when a depth map is present.
        match_resolution: set the scene's render size to the maps' size, so the camera frames the
            asset exactly (the plane is sized for the maps' aspect ratio either way).
        use_camera_file: give the camera the intrinsics of the maps' ``<prefix>_camera.json``
            when there is one (else, and with False, the mesh is built in the camera's own frustum).

    Raises:
        ValueError: an unknown normal space or a distance that is not > 0.
    """

    distance: float = 1.0
    normal_space: str = "TANGENT"
    use_depth: bool = True
    match_resolution: bool = True
    use_camera_file: bool = True

    def __post_init__(self) -> None:
        if self.normal_space not in NORMAL_SPACES:
            raise ValueError(f"normal_space must be one of {NORMAL_SPACES}, got {self.normal_space!r}")
        if not self.distance > 0:
            raise ValueError(f"distance must be > 0 metres, got {self.distance}")


def import_pbr_maps(
    context,
    source: str | os.PathLike | Iterable[str | os.PathLike] | Mapping[str, str | os.PathLike],
    options: ImportOptions | None = None,
    *,
    camera=None,
    name: str | None = None,
):
    """Import PBR maps as a camera-parented plane (or depth mesh) with a Principled material.

    Args:
        context: ``bpy.context`` (its scene and collection receive the object).
        source: a folder, a list of files, or ``{kind: file}``; matched by filename tokens (see
            :func:`blender_addon.core.map_names.match_map_files`). A normal map is required; the
            others are optional (Principled defaults stand in). A folder holding a
            ``<name>_sequence.json`` (or that file) imports the sequence (module docstring).
        options: how to build the asset (default :class:`ImportOptions`).
        camera: the capture camera; default the scene camera, else a new one at the origin.
        name: object name; default from the file names (a sequence: its name).

    Returns:
        The new object. Custom properties ``pdir_maps`` / ``pdir_missing`` list the imported
        and missing kinds, ``pdir_camera`` the camera file used (empty: none), ``pdir_frames``
        the number of frames (1 without a sequence); a sequence's object (frame 1's) also has
        ``pdir_geometry`` (``plane``, ``relief``, ``shape_keys`` or ``objects``) and
        ``pdir_frame_objects`` (the names of the frames' objects). Clipped values or a changed
        normal space are reported as :class:`PBRImportWarning`.

    Raises:
        FileNotFoundError: missing folder, file, normal map or frame.
        ValueError: ambiguous names, bad values, a malformed camera or sequence file (one line
            naming the file and the field), a sequence frame of another size or camera, bad camera or
            arguments.
    """
    options = ImportOptions() if options is None else options
    sequence_file = map_names.find_sequence(source)
    if sequence_file is not None:
        return _import_sequence(context, map_names.match_sequence_files(sequence_file), options, camera, name)
    files = map_names.match_map_files(source, required=("normal",))
    return _import_view(context, files, options, camera, name)


def _import_view(context, files: map_names.MapFiles, options: ImportOptions, camera, name: str | None):
    """One view's maps: packed float images, the normals on a depth mesh's vertices."""
    files = _used_files(files, options)
    maps = _load(files)
    camera, frustum, camera_path = _place_camera(context.scene, camera, files, maps, options)
    name = name or _asset_name(files.files)
    mesh, local, normal_space = _asset_mesh(name, files, maps, frustum, options, custom_normals=True)
    obj = _link(context, name, mesh, camera, local)
    images = _packed_images(name, maps)
    mesh.materials.append(build_material(
        name, images, normal_space=normal_space, use_alpha="mask" in images, normals_on_mesh=maps.depth is not None
    ))  # fmt: skip
    source = ", ".join(str(p) for p in files.files.values())
    return _tag(context, obj, maps, source, normal_space, camera_path, frames=1)


def _import_sequence(context, sequence: map_names.SequenceFiles, options: ImportOptions, camera, name: str | None):
    """A sequence: per-frame relief geometry (or one plane), image sequences in the material, frames 1..n."""
    files = _used_files(sequence.first, options)
    maps = _load(files)  # the other frames' textures: Blender reads them as they play
    first_camera = map_names.camera_file(files.files) if options.use_camera_file else None
    k = None if first_camera is None else read_camera_json(first_camera).intrinsics
    later = [_frame_maps(sequence, i, options, maps.shape, k) for i in range(2, sequence.frames + 1)]
    camera, frustum, camera_path = _place_camera(context.scene, camera, files, maps, options)
    name = name or sequence.name
    reliefs = [] if maps.depth is None else [_relief(f, m, frustum) for f, m in [(files, maps), *later]]
    mesh, local, normal_space = _asset_mesh(name, files, maps, frustum, options, custom_normals=False)
    objects = [_link(context, name, mesh, camera, local)]
    geometry = "plane" if maps.depth is None else "shape_keys" if len(reliefs) > 1 else "relief"
    if len(reliefs) > 1 and sequence_mesh.same_topology(reliefs):
        sequence_mesh.key_shapes(objects[0], reliefs)
    elif len(reliefs) > 1:
        geometry = "objects"
        for i, r in enumerate(reliefs[1:], start=2):
            frame_mesh = mesh_from_arrays(f"{name}_{i:04d}", r.vertices, r.faces, r.uvs, UV_NAME)
            objects.append(_link(context, frame_mesh.name, frame_mesh, camera, local))
        sequence_mesh.key_visibility(objects)
    images = {k: sequence_image(p, k) for k, p in files.files.items() if k != "depth"}
    normal_raw = files.files["normal"].suffix.lower() == ".exr"
    material = build_material(
        name, images, normal_space=normal_space, use_alpha="mask" in images, frames=sequence.frames,
        normal_raw=normal_raw,
    )  # fmt: skip
    for obj in objects:
        obj.data.materials.append(material)
    scene = context.scene
    scene.frame_start, scene.frame_end = 1, sequence.frames
    scene.frame_set(1)
    objects[0]["pdir_geometry"] = geometry
    objects[0]["pdir_frame_objects"] = ",".join(o.name for o in objects)
    return _tag(context, objects[0], maps, str(sequence.path), normal_space, camera_path, frames=sequence.frames)


def _frame_maps(sequence: map_names.SequenceFiles, i: int, options: ImportOptions, shape: tuple[int, int], k):
    """Frame ``i``'s normal, mask and depth maps (what its relief needs), checked against frame 1's.

    Args:
        sequence: the sequence's files.
        i: the frame (2..n).
        options: the import's options (``use_depth``).
        shape: frame 1's ``(H, W)``: every frame must have it.
        k: frame 1's camera intrinsics ``(3, 3)``, or None: a frame's own camera file must agree.

    Returns:
        ``(files, maps)`` as :func:`_relief` takes them.
    """
    frame = _used_files(sequence.frame(i), options).files
    files = map_names.MapFiles({kind: p for kind, p in frame.items() if kind in ("normal", "mask", "depth")})
    maps = _load(files)
    if maps.shape != shape:
        (h, w), (h1, w1) = maps.shape, shape
        raise ValueError(
            f"{files.files['normal']}: frame {i} is {w} x {h}, but frame 1 is {w1} x {h1}; "
            f"a sequence's frames must share one size"
        )
    camera = map_names.camera_file(files.files) if k is not None else None
    if camera is not None and not np.allclose(read_camera_json(camera).intrinsics, k, rtol=1e-6, atol=0.0):
        raise ValueError(f"{camera}: intrinsics differ from frame 1's; one camera serves the whole sequence")
    return files, maps


def _relief(files: map_names.MapFiles, maps: map_io.PBRMaps, frustum: Frustum) -> sequence_mesh.Relief:
    """The depth mesh of ``maps`` one pixel past its mask (module docstring), as a :class:`~.sequence_mesh.Relief`.

    Raises:
        ValueError: the depth map gives no triangles (names the depth file).
    """
    vertices, faces, uvs = depth_mesh(maps.depth, map_io.dilate(maps.valid), frustum)
    if len(faces) == 0:
        raise ValueError(f"{files.files['depth']}: the depth map gives no triangles inside the mask")
    return sequence_mesh.Relief(vertices, faces, uvs)


def _used_files(files: map_names.MapFiles, options: ImportOptions) -> map_names.MapFiles:
    """The matched files to import (the depth map left out without ``use_depth``)."""
    if options.use_depth:
        return files
    return map_names.MapFiles({k: v for k, v in files.files.items() if k != "depth"}, files.unmatched)


def _load(files: map_names.MapFiles) -> map_io.PBRMaps:
    """Read and validate the maps (warning about clipped values), extended past the mask (module docstring)."""
    maps = map_io.load_maps(files, reader=read_channels)
    for line in maps.warnings:
        warnings.warn(line, PBRImportWarning, stacklevel=3)
    return map_io.extend_past_mask(maps)


def _place_camera(scene, camera, files: map_names.MapFiles, maps: map_io.PBRMaps, options: ImportOptions):
    """The capture camera, with the intrinsics of the maps' camera file when used; and the render size.

    Returns:
        ``(camera, frustum, camera_path)``: the camera object, the frustum the mesh is built in
        (the camera file's, in float64, else the camera's own), the camera file used or None.
    """
    h, w = maps.shape
    camera_path = map_names.camera_file(files.files) if options.use_camera_file else None
    capture = None if camera_path is None else read_camera_json(camera_path)
    if capture is not None and (capture.height, capture.width) != (h, w):
        raise ValueError(
            f"{camera_path}: width, height: {capture.width} x {capture.height}, but the maps are {w} x {h}"
        )
    camera = ensure_camera(scene, camera)
    if options.match_resolution:
        scene.render.resolution_x, scene.render.resolution_y = w, h
        scene.render.resolution_percentage = 100
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    if capture is None:
        return camera, camera_frustum(camera, w, h, scene=scene), None
    match_camera(scene, camera, capture.blender)
    ratio = capture.blender.fy_over_fx
    if abs(ratio - 1.0) > 1e-6:
        warnings.warn(
            f"{camera_path.name}: fx != fy; Blender's camera has square pixels, so the camera and the relief "
            f"use fx for both axes (the relief's height is fy / fx = {ratio:.6g} of the capture's)",
            PBRImportWarning,
            stacklevel=3,
        )
    return camera, capture.blender.frustum(w, h), camera_path  # in float64 (the camera holds it in float32)


def _asset_mesh(name: str, files: map_names.MapFiles, maps: map_io.PBRMaps, frustum: Frustum,
                options: ImportOptions, *, custom_normals: bool):  # fmt: skip
    """The depth mesh (when there is a depth map) or the plane, its local matrix and the normal space it uses.

    Args:
        name: the mesh's name.
        files: the matched files (named in errors).
        maps: the validated maps.
        frustum: the camera frustum the mesh is built in.
        options: the import's options (distance, normal space).
        custom_normals: give a depth mesh the normals as custom vertex normals (not for a sequence).

    Returns:
        ``(mesh, local, normal_space)``: a depth mesh always uses OBJECT space (with a warning
        when another was asked for).
    """
    if maps.depth is None:
        d = options.distance
        local = Matrix.Translation(Vector((frustum.center_x * d, frustum.center_y * d, -d)))
        return _plane(name, frustum, d), local, options.normal_space
    relief = _relief(files, maps, frustum)
    mesh = mesh_from_arrays(name, relief.vertices, relief.faces, relief.uvs, UV_NAME)
    if custom_normals:
        set_vertex_normals(mesh, maps.normal[map_io.dilate(maps.valid)])  # the relief's support, vertex order
    if options.normal_space != "OBJECT":
        warnings.warn(
            "depth mesh: normals use OBJECT space (tangent frames of a curved mesh are not the camera frame)",
            PBRImportWarning,
            stacklevel=3,
        )
    return mesh, Matrix.Identity(4), "OBJECT"


def _link(context, name: str, mesh, camera, local):
    """A new object of ``mesh`` in the context's collection, parented to ``camera`` at ``local``."""
    obj = bpy.data.objects.new(name, mesh)
    (context.collection or context.scene.collection).objects.link(obj)
    obj.parent = camera
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.matrix_basis = local
    return obj


def _tag(context, obj, maps: map_io.PBRMaps, source: str, normal_space: str, camera_path: Path | None, frames: int):
    """Record what was imported as the object's custom properties (see :func:`import_pbr_maps`); return it."""
    present = maps.present()
    obj["pdir_maps"] = ",".join(present)
    obj["pdir_missing"] = ",".join(k for k in MAP_NAMES if k not in present)
    obj["pdir_source"] = source
    obj["pdir_normal_space"] = normal_space
    obj["pdir_camera"] = str(camera_path) if camera_path is not None else ""
    obj["pdir_frames"] = frames
    context.view_layer.update()  # matrix_world of the new child, for callers that place lights around it
    return obj


# --------------------------------------------------------------------------- operator


class PDIR_OT_import_pbr(bpy.types.Operator, ImportHelper):
    """Import normal/albedo/roughness/metallic/mask(/depth) maps or a sequence as a camera-facing relightable asset."""

    bl_idname = "pdir.import_pbr"
    bl_label = "Import PBR Maps"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default="*.exr;*.png;*.jpg;*.jpeg;*_sequence.json", options={"HIDDEN"})
    directory: StringProperty(subtype="DIR_PATH", description="Folder with the maps (or a <name>_sequence.json)")
    files: CollectionProperty(
        type=bpy.types.OperatorFileListElement, description="Map files (none selected: every map in the folder)"
    )
    distance: FloatProperty(
        name="Distance",
        description="Distance of the plane from the camera (a depth map places the mesh itself)",
        default=1.0,
        min=1e-4,
        soft_max=100.0,
        unit="LENGTH",
    )
    normal_space: EnumProperty(
        name="Normal Space",
        description="Normal Map node space; both reproduce the camera-space normals on the plane",
        items=(
            ("TANGENT", "Tangent", "Tangent space (equal to camera space on the camera-facing plane)"),
            ("OBJECT", "Object", "Object space (the object frame is the camera frame)"),
        ),
        default="TANGENT",
    )
    use_depth: BoolProperty(
        name="Use Depth", description="Build a depth-displaced mesh when a depth map is present", default=True
    )
    match_resolution: BoolProperty(
        name="Match Resolution", description="Set the render resolution to the maps' size", default=True
    )
    use_camera_file: BoolProperty(
        name="Match Capture Camera",
        description="Give the camera the capture's intrinsics from the maps' <name>_camera.json when present",
        default=True,
    )

    def execute(self, context):
        """Import the selected files (or the whole folder) and report what was found."""
        folder = Path(bpy.path.abspath(self.directory)) if self.directory else None
        names = [f.name for f in self.files if f.name]
        if folder is None and not self.filepath:
            self.report({"ERROR"}, "choose a folder or map files")
            return {"CANCELLED"}
        if folder is None:
            source = Path(bpy.path.abspath(self.filepath))
            source = source if source.is_dir() else [source]
        else:
            source = [folder / n for n in names] if names else folder
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", PBRImportWarning)
            try:
                options = ImportOptions(
                    distance=self.distance,
                    normal_space=self.normal_space,
                    use_depth=self.use_depth,
                    match_resolution=self.match_resolution,
                    use_camera_file=self.use_camera_file,
                )
                obj = import_pbr_maps(context, source, options)
            except (ValueError, OSError) as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
        for w in caught:
            if issubclass(w.category, PBRImportWarning):
                self.report({"WARNING"}, str(w.message))
        missing = obj["pdir_missing"] or "none"
        frames = f"; {obj['pdir_frames']} frames ({obj['pdir_geometry']})" if obj["pdir_frames"] > 1 else ""
        camera = f"; camera from {Path(obj['pdir_camera']).name}" if obj["pdir_camera"] else ""
        self.report({"INFO"}, f"imported {obj.name!r}: maps {obj['pdir_maps']}; missing {missing}{frames}{camera}")
        return {"FINISHED"}


CLASSES = (PDIR_OT_import_pbr,)
