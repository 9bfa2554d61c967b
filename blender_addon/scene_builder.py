"""Objaverse-like scenes in Blender: assets from a folder, random poses in view, pBRDF materials.

:func:`build_scene` imports assets through the same asset pipeline as the headless renderer
(:func:`.core.assets.load_mesh`; FBX through Blender's importer, then
:func:`.core.assets.build_render_mesh`), so both accept and refuse the same files and shade them
with the same normals (custom split normals here). A refused file is skipped with a warning. Each
asset becomes one object, normalised (centred on its bounding box, unit bounding-box diagonal), placed with
:func:`.core.placement.place` 50-100 cm from the camera with every corner of its bounding box inside
the view (so every vertex is), and assigns a material: an entry of a pBRDF library
(``materials.json`` read by :func:`.core.scenegen.load_material_library`) or, without one, a
random analytic material exactly as :func:`.core.scenegen.random_scene` draws it
(:func:`.core.scenegen.random_material`). The Blender material is a Principled BSDF preview of
the material's Disney parameters (base colour = albedo, roughness, metallic).

Convention (custom properties, read by the exporter):
    - object ``pdir_role = "scene_object"``, ``pdir_material`` = the material name,
      ``pdir_asset`` = the source file;
    - material ``pdir_material`` = JSON of :meth:`.core.spec.MaterialSpec.to_dict`;
    - scene ``pdir_seed`` = the seed of the last build.
    Objects are children of the rig root, so their pose in the rig frame is
    :func:`.rig_bpy.to_rig_frame` (rotation times a uniform scale equal to the bounding-box
    diagonal in metres, plus the translation).

Randomness: one ``numpy.random.default_rng(seed)`` draws, per object in order: the asset file,
the pose (redrawn while its bounding sphere overlaps an earlier object's, at most
:data:`MAX_OVERLAP_TRIES` times) and the material. Same inputs and seed, same scene.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import TYPE_CHECKING

import bpy
import numpy as np
from mathutils import Matrix
from numpy.typing import NDArray

from pbrdf.sensor.rig import Rig

from . import rig_bpy, texture_nodes
from .core.placement import place

if TYPE_CHECKING:
    from .core.spec import MaterialSpec

__all__ = [
    "IMPORTERS",
    "MAX_OVERLAP_TRIES",
    "blender_mesh",
    "build_scene",
    "triangle_corners",
    "import_asset",
    "import_asset_parts",
    "mesh_uvs",
    "list_asset_files",
]

#: File suffix -> Blender import operator (``bpy.ops`` path), as named in Blender 4.2-5.0.
IMPORTERS = {
    ".glb": "import_scene.gltf",
    ".gltf": "import_scene.gltf",
    ".obj": "wm.obj_import",
    ".ply": "wm.ply_import",
    ".fbx": "import_scene.fbx",
    ".stl": "wm.stl_import",
}
#: Core add-ons providing the importers that are add-ons rather than built-in operators.
_IMPORTER_ADDONS = {"import_scene.gltf": "io_scene_gltf2", "import_scene.fbx": "io_scene_fbx"}
#: Pose redraws while an object's bounding sphere overlaps an earlier one's; then it is kept.
MAX_OVERLAP_TRIES = 20

ROLE_OBJECT = "scene_object"
ROLE_COLLECTION = "scene_objects"
MATERIAL_KEY = "pdir_material"
ASSET_KEY = "pdir_asset"
SEED_KEY = "pdir_seed"
_METADATA_KEY = "pdir_metadata"  # export_spec.METADATA_KEY (export_spec imports this module)
# Data-blocks an importer may create; those left over after joining are removed.
_IMPORT_DATA = ("objects", "meshes", "materials", "images", "textures", "cameras", "lights", "armatures", "actions")


def _core() -> tuple[ModuleType, ModuleType]:
    """``(core.assets, core.scenegen)``, or a RuntimeError naming the missing package."""
    try:
        from .core import assets, scenegen  # noqa: PLC0415 - optional third-party imports inside
    except ImportError as e:
        name = e.name or "a dependency"
        raise RuntimeError(
            f"the scene builder needs the Python package '{name}': run '{sys.executable} -m pip install {name}'"
        ) from None
    return assets, scenegen


def list_asset_files(folder: str | os.PathLike) -> list[Path]:
    """Files under ``folder`` (recursively) that an importer of :data:`IMPORTERS` reads, sorted.

    Raises:
        FileNotFoundError: the folder does not exist or holds no such file.
        NotADirectoryError: it is a file.
    """
    files = _core()[0].list_assets(folder, suffixes=IMPORTERS)
    if not files:
        raise FileNotFoundError(f"{folder}: no assets ({', '.join(sorted(IMPORTERS))}) in the folder")
    return files


def _importer(path: Path) -> object:
    op_path = IMPORTERS[path.suffix.lower()]
    group, name = op_path.split(".")
    op = getattr(getattr(bpy.ops, group), name)
    try:
        op.get_rna_type()
    except KeyError:  # an importer add-on that is not enabled: enable the core add-on
        import addon_utils  # noqa: PLC0415

        addon_utils.enable(_IMPORTER_ADDONS.get(op_path, ""), default_set=True)
        op.get_rna_type()
    return op


def _world(obj: bpy.types.Object) -> Matrix:
    """World matrix from the parent chain (valid right after an import, without a depsgraph update)."""
    m = obj.matrix_parent_inverse @ obj.matrix_basis
    return m if obj.parent is None else _world(obj.parent) @ m


def triangle_corners(mesh: bpy.types.Mesh, *, uv: bool = False) -> dict[str, NDArray] | None:
    """A mesh's triangles as arrays, read with ``foreach_get``; None without triangles.

    Returns:
        ``co (N, 3)`` vertex positions, ``tri (T, 3)`` loop indices of the triangles,
        ``material_index (T,)``, ``loop_vert (L,)`` vertex of every loop, ``normals (L, 3)``
        corner normals and, with ``uv``, ``uv (L, 2)`` of the active UV layer (None without one).
    """
    mesh.calc_loop_triangles()
    if len(mesh.loop_triangles) == 0:
        return None
    nl = len(mesh.loops)
    out: dict = {}
    for key, seq, attr, dtype, width in (
        ("co", mesh.vertices, "co", np.float32, 3),
        ("tri", mesh.loop_triangles, "loops", np.int32, 3),
        ("material_index", mesh.loop_triangles, "material_index", np.int32, 1),
        ("loop_vert", mesh.loops, "vertex_index", np.int32, 1),
        ("normals", mesh.corner_normals, "vector", np.float32, 3),
    ):
        a = np.empty(width * len(seq), dtype=dtype)
        seq.foreach_get(attr, a)
        out[key] = a.reshape(-1, width) if width > 1 else a
    if uv:
        out["uv"] = None
        if mesh.uv_layers.active is not None:
            a = np.empty(2 * nl, dtype=np.float32)
            mesh.uv_layers.active.data.foreach_get("uv", a)
            out["uv"] = a.reshape(-1, 2)
    return out


def _blender_import_parts(path: Path) -> list:
    """Read a file only Blender reads (FBX) into :class:`.core.assets.MeshPart` triangles with corner normals.

    Everything the importer created (objects, materials, images, ...) is removed again.
    """
    assets = _core()[0]
    op = _importer(path)
    before = {attr: set(getattr(bpy.data, attr)) for attr in _IMPORT_DATA}
    try:
        op(filepath=str(path))
    except RuntimeError as e:
        raise ValueError(f"{path}: import failed: {' '.join(str(e).split())}") from None
    finally:
        created = {attr: [i for i in getattr(bpy.data, attr) if i not in before[attr]] for attr in _IMPORT_DATA}
    parts = []
    try:
        for obj in created["objects"]:
            if obj.type != "MESH":
                continue
            tmp = obj.data.copy()
            try:
                tmp.transform(_world(obj))
                c = triangle_corners(tmp)
            finally:
                bpy.data.meshes.remove(tmp)
            if c is None:
                continue
            tri = c["tri"]
            # One vertex per corner: the shared pipeline welds positions and keeps corner normals.
            parts.append(
                assets.MeshPart(
                    vertices=c["co"][c["loop_vert"][tri]].reshape(-1, 3).astype(np.float64),
                    faces=np.arange(tri.size, dtype=np.int64).reshape(-1, 3),
                    normals=c["normals"][tri].reshape(-1, 3).astype(np.float64),
                )
            )
    finally:
        bpy.data.batch_remove([i for attr in _IMPORT_DATA for i in created[attr]])
    if not parts:
        raise ValueError(f"{path}: degenerate mesh: no triangle geometry (empty file, point cloud or lines only)")
    return parts


def import_asset(path: str | os.PathLike, name: str | None = None) -> bpy.types.Mesh:
    """Import one asset file into a new mesh through the shared asset pipeline, then normalise it.

    GLB/GLTF/OBJ/PLY/STL/OFF go through :func:`.core.assets.load_mesh`, FBX through Blender's
    importer and then :func:`.core.assets.build_render_mesh`: the same accepted files, cleaning,
    outward orientation and shading normals as the headless renderer (authored normals kept,
    crease-angle normals otherwise), stored as custom split normals on a mesh welded by position,
    with the file's UVs when the pipeline keeps them (:data:`.texture_nodes.UV_LAYER`).
    Normalised: centred on its axis-aligned bounding box, scaled to a unit bounding-box diagonal.

    Raises:
        ValueError: one line naming the file: unsupported suffix, a failed import or a mesh the
            pipeline refuses (no triangles, flat, NaN coordinates, ...).
    """
    path = Path(path)
    return _to_blender(name or path.stem, _normalised(_import_core(path)))


def _import_core(path: Path):
    """The asset's render mesh (a trimesh) as the shared pipeline reads it, not normalised."""
    suffix = path.suffix.lower()
    if suffix not in IMPORTERS:
        raise ValueError(f"{path}: unsupported asset type; supported: {sorted(IMPORTERS)}")
    assets = _core()[0]
    if suffix in assets.MESH_SUFFIXES:
        return assets.load_mesh(path)
    return assets.build_render_mesh(_blender_import_parts(path), str(path))


def _normalised(tm, box=None):
    """``tm`` centred on ``box``'s (default its own) bounding box, scaled to a unit bounding-box diagonal."""
    import trimesh  # noqa: PLC0415 - the core's dependency

    box = np.asarray(tm.vertices if box is None else box, dtype=np.float64)
    lo, hi = box.min(axis=0), box.max(axis=0)
    v = (np.asarray(tm.vertices, dtype=np.float64) - (lo + hi) / 2) / float(np.linalg.norm(hi - lo))
    out = trimesh.Trimesh(v, np.asarray(tm.faces), vertex_normals=np.asarray(tm.vertex_normals), process=False)
    out.visual = tm.visual.copy()
    out.metadata.update(tm.metadata)
    return out


def _to_blender(name: str, tm, *, textured: bool = False) -> bpy.types.Mesh:
    tm, uv = mesh_uvs(tm, textured)
    return blender_mesh(name, np.asarray(tm.vertices), np.asarray(tm.faces), np.asarray(tm.vertex_normals), uv)


def import_asset_parts(
    path: str | os.PathLike, name: str | None = None
) -> tuple[list[tuple[bpy.types.Mesh, MaterialSpec | None]], tuple[str, ...]] | None:
    """A glTF/OBJ file as one mesh per material with its UVs and its :class:`~.core.spec.MaterialSpec`.

    The parts are :func:`.core.asset_materials.asset_parts` (``"<file>#material=<K>"``, the
    headless engine's objects), normalised together as :func:`import_asset` normalises the file.

    Returns:
        ``([(mesh, material or None), ...], notes)``, or None for a file without materials.

    Raises:
        ValueError: one line naming the file (unreadable materials or textures, a refused mesh).
    """
    from .core.asset_materials import asset_parts  # noqa: PLC0415 - needs trimesh

    path = Path(path)
    if path.suffix.lower() not in (".glb", ".gltf", ".obj"):
        return None
    own = asset_parts(path)
    if own is None:
        return None
    assets = _core()[0]
    box = assets.load_mesh(path).vertices
    meshes = [
        (_to_blender(f"{name or path.stem}_part{j}", _normalised(assets.load_mesh(part.mesh), box)), part.material)
        for j, part in enumerate(own.parts)
    ]
    return meshes, own.notes


def blender_mesh(
    name: str, vertices: NDArray, faces: NDArray, normals: NDArray, uvs: NDArray | None = None
) -> bpy.types.Mesh:
    """A Blender mesh from a render mesh: vertices welded by position, the normals as custom split normals.

    Args:
        name: the mesh data-block's name.
        vertices: ``(N, 3)`` render-mesh positions (split at hard edges and seams).
        faces: ``(F, 3)`` triangles.
        normals: ``(N, 3)`` shading normals per render vertex.
        uvs: ``(N, 2)`` OpenGL UVs per render vertex (Blender's convention), or None.

    Returns:
        The new mesh: connected where the render mesh was split, smooth-shaded, with corner
        normals equal to ``normals`` (so Blender shades what Mitsuba renders) and the UVs per
        corner in the UV layer :data:`.texture_nodes.UV_LAYER`.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.asarray(normals, dtype=np.float64)
    first, ids = _core()[0].weld(v)  # in order of first use: keeps the vertex order
    loops = ids[f].astype(np.int32)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(first))
    mesh.vertices.foreach_set("co", v[first].astype(np.float32).ravel())
    mesh.loops.add(loops.size)
    mesh.loops.foreach_set("vertex_index", loops.ravel())
    mesh.polygons.add(len(f))
    mesh.polygons.foreach_set("loop_start", np.arange(0, loops.size, 3, dtype=np.int32))
    mesh.update()
    mesh.polygons.foreach_set("use_smooth", np.ones(len(f), dtype=bool))
    # Loop k is corner k of the faces (loop_start above), so the corner normals line up.
    mesh.normals_split_custom_set(n[f.ravel()].tolist())
    if uvs is not None:
        layer = mesh.uv_layers.new(name=texture_nodes.UV_LAYER)
        layer.data.foreach_set("uv", np.asarray(uvs, dtype=np.float32)[f.ravel()].ravel())
    mesh.update()
    return mesh


def mesh_uvs(tm, textured: bool) -> tuple:
    """A render mesh (trimesh) with its per-vertex UVs.

    Args:
        tm: the mesh.
        textured: unwrap a mesh without UVs (:func:`.core.assets.ensure_uv`), as the headless
            renderer does for a textured material.

    Returns:
        ``(mesh, uvs (N, 2) or None)``.
    """
    assets = _core()[0]
    if textured:
        unwrapped = assets.ensure_uv(tm)
        if unwrapped is not tm:
            unwrapped.metadata.update(tm.metadata)
        tm = unwrapped
    uv = getattr(tm.visual, "uv", None)
    return tm, (None if uv is None or len(uv) != len(tm.vertices) else np.asarray(uv, dtype=np.float64))


def _bbox_corners(mesh: bpy.types.Mesh) -> NDArray[np.float64]:
    v = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.vertices.foreach_get("co", v)
    v = v.reshape(-1, 3).astype(np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])


def material_from_spec(spec: MaterialSpec) -> bpy.types.Material:
    """A Principled BSDF material previewing ``spec``'s Disney parameters (reused if identical).

    A textured spec gets Image Texture nodes on Base Color, Roughness, Metallic and Normal
    (:func:`.texture_nodes.add_texture_nodes`); the meshes need the UV layer
    :data:`.texture_nodes.UV_LAYER` (:func:`blender_mesh` with ``uvs``).
    """
    payload = json.dumps(spec.to_dict(), sort_keys=True)
    for mat in bpy.data.materials:
        if mat.get(MATERIAL_KEY) == payload:
            return mat
    mat = bpy.data.materials.new(f"PDIR {spec.name}")
    mat[MATERIAL_KEY] = payload
    if mat.node_tree is None:  # Blender < 5.0 creates the node tree on request only
        mat.use_nodes = True
    bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        bsdf = mat.node_tree.nodes.new("ShaderNodeBsdfPrincipled")
        out = next(n for n in mat.node_tree.nodes if n.type == "OUTPUT_MATERIAL")
        mat.node_tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    bsdf.inputs["Base Color"].default_value = (*spec.albedo, 1.0)  # linear RGB, as the spec
    bsdf.inputs["Roughness"].default_value = spec.roughness
    bsdf.inputs["Metallic"].default_value = spec.metallic
    if spec.kind == "pplastic":
        bsdf.inputs["IOR"].default_value = spec.ior
    mat.diffuse_color = (*spec.albedo, 1.0)  # solid-mode viewport colour
    mat.roughness, mat.metallic = spec.roughness, spec.metallic
    if spec.textures is not None:  # image nodes on the inputs; the constants above are the textures' means
        texture_nodes.add_texture_nodes(mat, bsdf, spec.textures)
    return mat


def material_spec_of(mat: bpy.types.Material) -> MaterialSpec:
    """The :class:`~.core.spec.MaterialSpec` stored on a material by :func:`material_from_spec`.

    Raises:
        ValueError: the material carries no (valid) spec.
    """
    from .core.spec import MaterialSpec  # noqa: PLC0415

    payload = mat.get(MATERIAL_KEY)
    if payload is None:
        raise ValueError(
            f"material {mat.name!r} has no pBRDF material ({MATERIAL_KEY}); build the scene with the add-on"
        )
    return MaterialSpec.from_dict(json.loads(payload))


def _objects_collection(scene: bpy.types.Scene) -> bpy.types.Collection:
    for coll in scene.collection.children:
        if coll.get(rig_bpy.ROLE_KEY) == ROLE_COLLECTION:
            return coll
    coll = bpy.data.collections.new("PDIR Objects")
    coll[rig_bpy.ROLE_KEY] = ROLE_COLLECTION
    scene.collection.children.link(coll)
    return coll


def clear_scene_objects(scene: bpy.types.Scene) -> int:
    """Remove the objects a previous :func:`build_scene` made in ``scene``; returns how many."""
    objs = [o for o in scene.objects if o.get(rig_bpy.ROLE_KEY) == ROLE_OBJECT]
    meshes = {o.data for o in objs}
    bpy.data.batch_remove(objs)
    bpy.data.batch_remove([m for m in meshes if m.users == 0])
    bpy.data.batch_remove([m for m in bpy.data.materials if MATERIAL_KEY in m and m.users == 0])
    bpy.data.batch_remove([i for i in bpy.data.images if texture_nodes.IMAGE_KEY in i and i.users == 0])
    return len(objs)


def _overlaps(centre: NDArray, radius: float, placed: list[tuple[NDArray, float]]) -> bool:
    return any(np.linalg.norm(centre - c) < radius + r for c, r in placed)


class _Asset:
    """One asset file imported for a build: a normalised trimesh, or its parts with their materials."""

    def __init__(self, path: Path, asset_materials: bool) -> None:
        own = import_asset_parts(path, name=f"PDIR source {path.stem}") if asset_materials else None
        self.tm = None if own is not None else _normalised(_import_core(path))
        self.parts, self.notes = own if own is not None else ([], ())
        self._plain: dict[bool, bpy.types.Mesh] = {}

    def bbox(self) -> NDArray[np.float64]:
        """Corners of the bounding boxes of its parts (or of the whole), ``(8 k, 3)``."""
        return np.concatenate([_bbox_corners(m) for m in ([p for p, _ in self.parts] or [self.mesh(False)])])

    def mesh(self, textured: bool) -> bpy.types.Mesh:
        """The whole file as a mesh; with ``textured``, unwrapped when it has no UVs."""
        if textured not in self._plain:
            self._plain[textured] = _to_blender(f"PDIR source {textured}", self.tm, textured=textured)
        return self._plain[textured]

    def sources(self) -> list[bpy.types.Mesh]:
        return [m for m, _ in self.parts] + list(self._plain.values())


def build_scene(
    scene: bpy.types.Scene,
    folder: str | os.PathLike,
    count: int,
    seed: int,
    library: str | os.PathLike | None = None,
    *,
    distance: tuple[float, float] = (0.5, 1.0),
    size: tuple[float, float] = (0.15, 0.35),
    replace: bool = True,
    skipped: dict[str, str] | None = None,
    asset_materials: bool = False,
    texture_fraction: float = 0.0,
    notes: dict[str, list[str]] | None = None,
) -> list[bpy.types.Object]:
    """Place ``count`` random assets from ``folder`` in front of the rig's camera (see the module docstring).

    Args:
        scene: the scene; a default rig is added when it has none.
        folder: asset folder (GLB/GLTF/OBJ/PLY/FBX/STL, recursive).
        count: number of objects (assets drawn with replacement).
        seed: random seed (non-negative integer).
        library: folder with ``materials.json`` (pBRDF tables with Disney parameters); None or
            empty: random analytic materials.
        distance: (min, max) distance in m from the camera centre to an object's bounding-box centre.
        size: (min, max) bounding-box diagonal of an object in m.
        replace: remove the objects of the previous build first.
        skipped: if given, filled with ``{file: reason}`` for asset files the pipeline refused;
            a refused file is dropped from the draw and another drawn in its place.
        asset_materials: a glTF/OBJ file with materials becomes one object per material
            (``<stem>_<i>_part<j>``) with its UVs and the file's own material
            (:func:`import_asset_parts`; parts without one get a random analytic material), as
            :func:`.core.scenegen.random_scene` with ``asset_materials``.
        texture_fraction: probability that a drawn material (not an asset's own) gets seeded
            procedural textures (:func:`.core.random_textures.textured_material`); drawn after
            the material, only when above 0, so 0 keeps the scenes of earlier builds.
        notes: if given, filled with ``{file: [note, ...]}``: what an asset's materials lost.

    Returns:
        The new objects, in draw order.

    Raises:
        ValueError: bad count, seed or texture fraction, every asset file refused, an asset that
            cannot fit in view.
        FileNotFoundError: missing asset folder, no assets, missing library or tables.
        RuntimeError: a Python package the core needs is missing (the message says which).
    """
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be a positive integer, got {count!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not 0.0 <= texture_fraction <= 1.0:
        raise ValueError(f"texture_fraction must be in [0, 1], got {texture_fraction}")
    _, scenegen = _core()
    files = list_asset_files(folder)
    materials = scenegen.load_material_library(library) if library else None
    root = rig_bpy.find_rig_root(scene) or rig_bpy.add_rig(scene)
    rig: Rig = rig_bpy.rig_from_blender(root)
    if replace:
        clear_scene_objects(scene)
    coll = _objects_collection(scene)
    rng = np.random.default_rng(seed)
    imported: dict[Path, _Asset] = {}  # one import per file; objects get copies
    placed: list[tuple[NDArray, float]] = []
    out: list[bpy.types.Object] = []
    refused: dict[str, str] = {} if skipped is None else skipped
    try:
        for i in range(count):
            path = _draw_file(rng, files, imported, refused, folder, asset_materials)
            asset = imported[path]
            if asset.notes and notes is not None:
                notes[str(path)] = list(asset.notes)
            corners = SimpleNamespace(vertices=asset.bbox())
            for _ in range(MAX_OVERLAP_TRIES):
                pose = place(corners, rig, rng, distance=distance, size=size)
                centre, radius = pose[:3, 3], float(np.cbrt(abs(np.linalg.det(pose[:3, :3])))) / 2
                if not _overlaps(centre, radius, placed):
                    break
            placed.append((centre, radius))
            if asset.parts:
                for j, (source, own) in enumerate(asset.parts):
                    spec = own if own is not None else scenegen.random_material(rng, name=f"obj{i:02d}_part{j}")
                    out.append(_add_object(source, f"{path.stem}_{i:02d}_part{j}", spec, path, pose, coll, root))
                continue
            spec = (
                materials[int(rng.integers(len(materials)))]
                if materials
                else scenegen.random_material(rng, name=f"obj{i:02d}")
            )
            if texture_fraction > 0 and rng.random() < texture_fraction:
                from .core.random_textures import textured_material  # noqa: PLC0415

                spec = textured_material(rng, spec, materials or ())
            source = asset.mesh(spec.textures is not None)
            out.append(_add_object(source, f"{path.stem}_{i:02d}", spec, path, pose, coll, root))
    finally:
        bpy.data.batch_remove([m for a in imported.values() for m in a.sources()])
    scene[SEED_KEY] = int(seed)
    if asset_materials:
        _record_notes(scene, {str(p): list(a.notes) for p, a in imported.items() if a.notes})
    return out


def _record_notes(scene: bpy.types.Scene, notes: dict[str, list[str]]) -> None:
    """Set the scene metadata's ``asset_notes`` (what the assets' materials lost), as the headless engine does."""
    meta = json.loads(scene.get(_METADATA_KEY, "{}"))
    meta.pop("asset_notes", None)
    scene[_METADATA_KEY] = json.dumps({**meta, **({"asset_notes": notes} if notes else {})})


def _draw_file(rng, files: list[Path], imported: dict, refused: dict[str, str], folder, asset_materials: bool) -> Path:
    """Draw an asset file, importing it on its first draw; a refused file is dropped and another drawn."""
    while True:
        good = [p for p in files if str(p) not in refused]
        if not good:
            first = next(iter(refused.values()))
            raise ValueError(f"{folder}: every asset file was refused ({len(refused)}; first: {first})")
        path = good[int(rng.integers(len(good)))]
        if path in imported:
            return path
        try:
            imported[path] = _Asset(path, asset_materials)
            return path
        except ValueError as e:  # one bad file does not abort the build
            refused[str(path)] = str(e)


def _add_object(source, name: str, spec, path: Path, pose: NDArray, coll, root) -> bpy.types.Object:
    """A copy of ``source`` as a scene object with ``spec``'s material at ``pose`` under the rig root."""
    mesh = source.copy()
    mesh.name = name
    mesh.materials.clear()
    mesh.materials.append(material_from_spec(spec))
    obj = bpy.data.objects.new(mesh.name, mesh)
    obj[rig_bpy.ROLE_KEY] = ROLE_OBJECT
    obj[MATERIAL_KEY] = spec.name
    obj[ASSET_KEY] = str(path)
    coll.objects.link(obj)
    obj.parent = root
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.matrix_basis = Matrix(pose.tolist())
    return obj
