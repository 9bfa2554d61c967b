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

Normals: the mesh is parented to the camera with an identity local rotation, so its object frame
IS the camera frame, and for the plane (facing the camera, UVs aligned with the image) the
tangent frame is too (tangent = +x, bitangent = +y, normal = +z). The normal image stores
``0.5 + 0.5 n`` and the Normal Map node decodes it into exactly the input normal, in either
space. A depth mesh is not flat, so its tangent frames are not the camera frame: it always uses
OBJECT space.
"""

from __future__ import annotations

import importlib.util
import os
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper
from mathutils import Matrix, Vector

from .core import map_io, map_names
from .core.frustum import Frustum, blender_frustum, depth_mesh

__all__ = [
    "CLASSES",
    "NORMAL_SPACES",
    "PBRImportWarning",
    "image_from_array",
    "import_pbr_maps",
    "ensure_camera",
    "camera_frustum",
]

#: Normal Map node spaces that reproduce camera-space normals on the imported plane.
NORMAL_SPACES = ("TANGENT", "OBJECT")
#: Name of the UV layer of imported and baked meshes.
UV_NAME = "UVMap"


class PBRImportWarning(UserWarning):
    """Something the user should know about an import that still succeeded (clipped values, ...)."""


# --------------------------------------------------------------------------- images


def image_from_array(name: str, array: np.ndarray, *, colorspace: str = "Non-Color", pack: bool = True):
    """A float Blender image holding ``array`` exactly.

    Args:
        name: image name (Blender makes it unique).
        array: ``(H, W)``, ``(H, W, 3)`` or ``(H, W, 4)``, row 0 at the top; a single channel is
            copied to R, G and B; alpha is 1 unless given.
        colorspace: ``"Non-Color"`` for data, ``"Linear Rec.709"`` for linear colour.
        pack: pack it into the .blend file (as a float EXR) so it survives saving.

    Returns:
        The ``bpy.types.Image``.
    """
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[-1] not in (1, 3, 4):
        raise ValueError(f"image {name!r}: expected (H, W), (H, W, 3) or (H, W, 4); got {a.shape}")
    h, w, c = a.shape
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = a[..., :3] if c >= 3 else a[..., :1]
    if c == 4:
        rgba[..., 3] = a[..., 3]
    img = bpy.data.images.new(name, width=w, height=h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = colorspace
    img.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())  # Blender's row 0 is the bottom
    if pack:
        img.file_format = "OPEN_EXR"
        img.pack()
    return img


def read_channels(path: Path) -> tuple[dict[str, np.ndarray], bool]:
    """Channels of a map file: :func:`blender_addon.core.map_io.read_channels`, or Blender's loader.

    Blender's bundled Python has numpy but neither Pillow nor OpenEXR: without Pillow, PNG/JPEG
    files are read with ``bpy.data.images.load`` (raw code values / 255); EXR needs OpenEXR.
    """
    if Path(path).suffix.lower() == ".exr" or importlib.util.find_spec("PIL") is not None:
        return map_io.read_channels(path)
    return read_channels_blender(path)


def read_channels_blender(path: Path) -> tuple[dict[str, np.ndarray], bool]:
    """PNG/JPEG channels ``R, G, B, A`` as float32 ``(H, W)`` in [0, 1] via ``bpy.data.images.load``."""
    try:
        img = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as e:
        raise ValueError(f"{path}: not a readable image: {e}") from None
    try:
        img.colorspace_settings.name = "Non-Color"  # raw code values / 255, no transfer function
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        px = px.reshape(h, w, 4)[::-1]  # Blender's row 0 is the bottom
        return {c: np.ascontiguousarray(px[..., i]) for i, c in enumerate("RGBA")}, False
    finally:
        bpy.data.images.remove(img)


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


def camera_frustum(camera, width: int, height: int) -> Frustum:
    """The frustum of a Blender camera object at ``width x height`` pixels."""
    cam = camera.data
    return blender_frustum(
        width,
        height,
        lens=cam.lens,
        sensor_width=cam.sensor_width,
        sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit,
        shift_x=cam.shift_x,
        shift_y=cam.shift_y,
    )


# --------------------------------------------------------------------------- mesh and material


def _mesh(name: str, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray):
    """A mesh with per-vertex UVs written to every loop of the UV layer :data:`UV_NAME`."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices.tolist(), [], faces.tolist())
    layer = mesh.uv_layers.new(name=UV_NAME)
    corner = np.empty(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", corner)
    layer.data.foreach_set("uv", np.asarray(uvs, np.float32)[corner].ravel())
    mesh.validate()
    mesh.update()
    return mesh


def _plane(name: str, frustum: Frustum, distance: float):
    """A plane mesh centred at its origin covering the frustum at ``distance`` (UV (0, 0) at the lower left)."""
    hw, hh = frustum.half_width * distance, frustum.half_height * distance
    vertices = np.array([[-hw, -hh, 0.0], [hw, -hh, 0.0], [hw, hh, 0.0], [-hw, hh, 0.0]])
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return _mesh(name, vertices, np.array([[0, 1, 2, 3]]), uvs)


def _tex(nodes, image, label: str, location: tuple[float, float]):
    node = nodes.new("ShaderNodeTexImage")
    node.image = image
    node.label = label
    node.interpolation = "Linear"
    node.extension = "EXTEND"
    node.location = location
    return node


def build_material(name: str, images: Mapping[str, object], *, normal_space: str, use_alpha: bool):
    """A Principled BSDF material reading ``images`` (kind -> Image) through the UV layer :data:`UV_NAME`.

    The normal image holds ``0.5 + 0.5 n``; it goes through a Normal Map node in ``normal_space``.
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
            tex = _tex(nodes, images[kind], kind, (-500, 300 - 280 * i))
            links.new(tex.outputs["Color"], bsdf.inputs[socket])
    if "normal" in images:
        tex = _tex(nodes, images["normal"], "normal", (-500, -850))
        nmap = nodes.new("ShaderNodeNormalMap")
        nmap.space = normal_space
        nmap.uv_map = UV_NAME
        nmap.location = (-200, -700)
        links.new(tex.outputs["Color"], nmap.inputs["Color"])
        links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def _asset_name(files: Mapping[str, Path]) -> str:
    stems = [p.stem for p in files.values()]
    prefix = os.path.commonprefix(stems).rstrip("_-. ")
    if len(stems) == 1:
        tokens = map_names.filename_tokens(stems[0])
        prefix = "_".join(t for t in tokens if not map_names.match_kinds((t,)))
    return prefix or "PBR asset"


# --------------------------------------------------------------------------- import


def import_pbr_maps(
    context,
    paths_or_folder: str | os.PathLike | Iterable[str | os.PathLike] | Mapping[str, str | os.PathLike],
    *,
    camera=None,
    distance: float = 1.0,
    normal_space: str = "TANGENT",
    use_depth: bool = True,
    match_resolution: bool = True,
    name: str | None = None,
):
    """Import PBR maps as a camera-parented plane (or depth mesh) with a Principled material.

    Args:
        context: ``bpy.context`` (its scene and collection receive the object).
        paths_or_folder: a folder, a list of files, or ``{kind: file}``; matched by filename
            tokens (see :func:`blender_addon.core.map_names.match_map_files`). A normal map is
            required; the others are optional (Principled defaults stand in).
        camera: the capture camera; default the scene camera, else a new one at the origin.
        distance: plane distance from the camera in metres (ignored for a depth mesh).
        normal_space: ``"TANGENT"`` or ``"OBJECT"`` (identical on the plane; a depth mesh uses OBJECT).
        use_depth: build a depth-displaced mesh when a depth map is present.
        match_resolution: set the scene's render size to the maps' size, so the camera frames the
            asset exactly (the plane is sized for the maps' aspect ratio either way).
        name: object name; default from the file names.

    Returns:
        The new object. Custom properties ``pdir_maps`` / ``pdir_missing`` list the imported
        and missing kinds. Clipped values or a changed normal space are reported as
        :class:`PBRImportWarning`.

    Raises:
        FileNotFoundError: missing folder, file or normal map.
        ValueError: ambiguous names, bad values, bad camera or arguments.
    """
    if normal_space not in NORMAL_SPACES:
        raise ValueError(f"normal_space must be one of {NORMAL_SPACES}, got {normal_space!r}")
    if not distance > 0:
        raise ValueError(f"distance must be > 0 metres, got {distance}")
    scene = context.scene
    files = map_names.match_map_files(paths_or_folder, required=("normal",))
    if not use_depth:
        files = map_names.MapFiles({k: v for k, v in files.files.items() if k != "depth"}, files.unmatched)
    maps = map_io.load_maps(files, reader=read_channels)
    for line in maps.warnings:
        warnings.warn(line, PBRImportWarning, stacklevel=2)
    camera = ensure_camera(scene, camera)
    h, w = maps.shape
    if match_resolution:
        scene.render.resolution_x, scene.render.resolution_y = w, h
        scene.render.resolution_percentage = 100
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    frustum = camera_frustum(camera, w, h)
    name = name or _asset_name(files.files)

    if maps.depth is not None:
        vertices, faces, uvs = depth_mesh(maps.depth, maps.valid, frustum)
        if len(faces) == 0:
            raise ValueError(f"{files.files['depth']}: the depth map gives no triangles inside the mask")
        mesh = _mesh(name, vertices, faces, uvs)
        local = Matrix.Identity(4)
        if normal_space != "OBJECT":
            warnings.warn(
                "depth mesh: normals use OBJECT space (tangent frames of a curved mesh are not the camera frame)",
                PBRImportWarning,
                stacklevel=2,
            )
            normal_space = "OBJECT"
    else:
        mesh = _plane(name, frustum, distance)
        local = Matrix.Translation(Vector((frustum.center_x * distance, frustum.center_y * distance, -distance)))

    obj = bpy.data.objects.new(name, mesh)
    (context.collection or scene.collection).objects.link(obj)
    obj.parent = camera
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.matrix_basis = local

    images = {}
    if maps.normal is not None:
        images["normal"] = image_from_array(f"{name}_normal", 0.5 + 0.5 * maps.normal)
    if maps.albedo is not None:
        images["albedo"] = image_from_array(f"{name}_albedo", maps.albedo, colorspace="Linear Rec.709")
    for kind in ("roughness", "metallic"):
        if getattr(maps, kind) is not None:
            images[kind] = image_from_array(f"{name}_{kind}", getattr(maps, kind))
    use_alpha = maps.mask_source != "none"
    if use_alpha:
        images["mask"] = image_from_array(f"{name}_mask", maps.mask)
    mesh.materials.append(build_material(name, images, normal_space=normal_space, use_alpha=use_alpha))

    present = maps.present()
    obj["pdir_maps"] = ",".join(present)
    obj["pdir_missing"] = ",".join(k for k in map_names.MAP_KINDS if k not in present)
    obj["pdir_source"] = ", ".join(str(p) for p in files.files.values())
    obj["pdir_normal_space"] = normal_space
    context.view_layer.update()  # matrix_world of the new child, for callers that place lights around it
    return obj


# --------------------------------------------------------------------------- operator


class PDIR_OT_import_pbr(bpy.types.Operator, ImportHelper):
    """Import normal/albedo/roughness/metallic/mask(/depth) maps as a camera-facing relightable asset."""

    bl_idname = "pdir.import_pbr"
    bl_label = "Import PBR Maps"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default="*.exr;*.png;*.jpg;*.jpeg", options={"HIDDEN"})
    directory: StringProperty(subtype="DIR_PATH", description="Folder with the maps")
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
                obj = import_pbr_maps(
                    context,
                    source,
                    distance=self.distance,
                    normal_space=self.normal_space,
                    use_depth=self.use_depth,
                    match_resolution=self.match_resolution,
                )
            except (ValueError, OSError) as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
        for w in caught:
            if issubclass(w.category, PBRImportWarning):
                self.report({"WARNING"}, str(w.message))
        missing = obj["pdir_missing"] or "none"
        self.report({"INFO"}, f"imported {obj.name!r}: maps {obj['pdir_maps']}; missing {missing}")
        return {"FINISHED"}


CLASSES = (PDIR_OT_import_pbr,)
