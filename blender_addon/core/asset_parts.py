"""Assets with their materials: one mesh per material of a glTF/OBJ file, with its UVs and MaterialSpec.

A scene holds a multi-material asset as one object per material: every object refers to the file
with a material selector, ``"<file>#material=<K>"`` (:func:`.assets.split_mesh_ref`), gets the
triangles of that material with their own UVs (:func:`load_part`) and the file's material K
(:func:`.asset_materials.read_materials`), and all of them share the asset's pose. The object
index of the ground truth then tells the parts apart.

The parts are cut from one render mesh of the whole file (:func:`.assets.build_render_mesh` with
``keep_parts``): their union has exactly the faces, positions and shading normals of
``load_mesh(file)``, so an asset renders the same whether it is one object or one per material.

Convention (UVs): OpenGL's, ``v`` up (:mod:`.textures`); trimesh's glTF reader turns glTF's ``v``
down into that. NaN or infinite UVs raise ValueError; UVs beyond ``+-UV_LIMIT`` are shifted by an
integer (exact for textures without a non-integer ``KHR_texture_transform``) and, if still beyond,
wrapped into [0, 1) per vertex (a triangle across a texture edge then shows a seam); both are noted.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import asset_materials, assets, gltf_io
from .spec import MaterialSpec

try:
    import trimesh
except ModuleNotFoundError:  # Blender's Python: only load_mesh needs trimesh
    trimesh = None

__all__ = ["UV_LIMIT", "AssetPart", "AssetParts", "asset_parts", "load_part", "material_keys", "tagged_scene"]

#: Largest UV magnitude kept as it is (float32 still resolves 1e-4 of a texture repeat there).
UV_LIMIT = 1024.0
_FLOAT = 5126  # glTF componentType FLOAT


@dataclass(frozen=True)
class AssetPart:
    """One material's share of an asset.

    Attributes:
        mesh: the mesh reference, ``"<file>#material=<K>"``.
        key: K, the material index (:data:`.assets.MATERIAL_NONE` for triangles without one).
        material: the file's material K, or None (no material: the caller picks one).
    """

    mesh: str
    key: int
    material: MaterialSpec | None


@dataclass(frozen=True)
class AssetParts:
    """The parts of an asset file, one per material with triangles, and the notes of its reading.

    Attributes:
        file: the asset file.
        parts: the parts in material order (triangles without a material last).
        notes: one line per thing read differently from the file (the sample's sidecar records them).
    """

    file: str
    parts: tuple[AssetPart, ...]
    notes: tuple[str, ...] = ()


def _check_uv_accessors(doc: dict, texcoord: dict[int, int], name: str) -> None:
    """Refuse integer (quantised) UVs: trimesh reads them without their normalisation."""
    accessors = doc.get("accessors") or []
    for i, mesh in enumerate(doc.get("meshes") or []):
        for j, p in enumerate(mesh.get("primitives") or []):
            mat = p.get("material")
            t = texcoord.get(mat, 0) if isinstance(mat, int) else 0
            a = (p.get("attributes") or {}).get(f"TEXCOORD_{t}")
            if isinstance(a, int) and 0 <= a < len(accessors) and accessors[a].get("componentType", _FLOAT) != _FLOAT:
                raise ValueError(f"{name}: mesh {i} primitive {j}: integer (quantised) UVs are not supported")


def tagged_scene(path: Path, name: str) -> trimesh.Scene:
    """The file as a trimesh scene whose every geometry holds one material's triangles with their UVs.

    Each geometry's ``metadata[gltf_io.PART_TAG][0]`` is its material index
    (:data:`.assets.MATERIAL_NONE` for none): glTF primitives are tagged through
    :func:`.gltf_io.tagged_document`, OBJ groups by their MTL material name.

    Raises:
        ValueError: a file type without materials, integer glTF UVs.
    """
    suffix = path.suffix.lower()
    if suffix in (".gltf", ".glb"):
        doc, binary = gltf_io.read_gltf(path, name)
        texcoord = asset_materials.gltf_texcoord_sets(doc)
        _check_uv_accessors(doc, texcoord, name)
        tagged = gltf_io.tagged_document(doc, texcoord)
        data = gltf_io.glb_bytes(tagged, binary) if suffix == ".glb" else json.dumps(tagged).encode("utf-8")
        resolver = trimesh.resolvers.FilePathResolver(str(path))
        return trimesh.load(io.BytesIO(data), file_type=suffix[1:], resolver=resolver, force="scene", process=False)
    if suffix == ".obj":
        scene = trimesh.load(path, file_type="obj", force="scene", process=False)
        names = asset_materials.mtl_names(path)
        for geom in scene.geometry.values():
            mname = getattr(getattr(getattr(geom, "visual", None), "material", None), "name", None)
            geom.metadata[gltf_io.PART_TAG] = [names.index(mname) if mname in names else assets.MATERIAL_NONE]
        return scene
    raise ValueError(f"{name}: material selectors need a glTF/GLB or OBJ file, got {suffix!r}")


def _clean_uvs(parts: list[assets.MeshPart], name: str) -> list[str]:
    """Check the parts' UVs in place: NaN/Inf raise, huge ones are shifted or wrapped; returns notes."""
    notes = []
    for p in parts:
        if p.uvs is None:
            continue
        bad = int(np.sum(~np.isfinite(p.uvs).all(axis=1)))
        if bad:
            raise ValueError(
                f"{name}: {bad} UV coordinate{'s' if bad != 1 else ''} NaN or infinite (material {p.group})"
            )
        if np.abs(p.uvs).max(initial=0.0) <= UV_LIMIT:
            continue
        uv = p.uvs - np.floor(np.median(p.uvs, axis=0))
        how = "shifted by an integer"
        if np.abs(uv).max() > UV_LIMIT:
            uv, how = uv - np.floor(uv), "wrapped into [0, 1) per vertex"
        notes.append(f"UVs beyond +-{UV_LIMIT:g} {how} (material {p.group})")
        p.uvs = uv
    return notes


_GROUPED: dict[tuple, tuple] = {}
_GROUPED_SIZE = 8


def _grouped(path: Path, crease_deg: float | None) -> tuple[trimesh.Trimesh, np.ndarray, tuple[str, ...], set[int]]:
    """The whole file's render mesh with UVs, the material of every face, the UV notes and the materials without UVs."""
    name = str(path)
    st = os.stat(path)
    key = (name, st.st_mtime_ns, st.st_size, crease_deg)
    if key not in _GROUPED:
        parts = assets._read_file(path, path.suffix.lower(), name, tagged=True)
        notes = tuple(_clean_uvs(parts, name))
        no_uv = {p.group for p in parts if p.uvs is None}
        mesh = assets.build_render_mesh(parts, name, crease_deg=crease_deg, keep_parts=True)
        groups = np.array([assets.MATERIAL_NONE if p.group is None else p.group for p in parts], dtype=np.int64)
        _GROUPED[key] = (mesh, groups[mesh.metadata["face_part"]], notes, no_uv)
        while len(_GROUPED) > _GROUPED_SIZE:
            _GROUPED.pop(next(iter(_GROUPED)))
    return _GROUPED[key]


def material_keys(path: str | os.PathLike, *, crease_deg: float | None = None) -> list[int]:
    """The materials of a file that have triangles, in index order (:data:`.assets.MATERIAL_NONE` last)."""
    keys = np.unique(_grouped(Path(path), crease_deg)[1]).tolist()
    return sorted(keys, key=lambda k: (k == assets.MATERIAL_NONE, k))


def load_part(path: str | os.PathLike, material: int, *, crease_deg: float | None = None) -> trimesh.Trimesh:
    """The triangles of material ``material`` of a glTF/OBJ file, with their UVs (``load_mesh("<file>#material=K")``).

    Returns:
        A trimesh with ``vertex_normals`` (the whole file's shading normals), UVs (zeros where
        the file has none) and ``metadata``: ``two_sided`` and ``bodies`` of the whole file,
        ``material`` (the key) and ``uv_notes``.

    Raises:
        ValueError: ``"<file>: <reason>"``: no triangles of that material, NaN UVs, a file the
            asset pipeline refuses.
    """
    path = Path(path)
    whole, groups, notes, _ = _grouped(path, crease_deg)
    sel = groups == material
    if not sel.any():
        label = "none" if material == assets.MATERIAL_NONE else material
        raise ValueError(f"{path}: no triangles with material {label}; materials with triangles: "
                         f"{material_keys(path, crease_deg=crease_deg)}")  # fmt: skip
    faces = np.asarray(whole.faces)[sel]
    used, inverse = np.unique(faces, return_inverse=True)
    mesh = trimesh.Trimesh(
        vertices=np.asarray(whole.vertices)[used],
        faces=inverse.reshape(-1, 3),
        vertex_normals=np.asarray(whole.vertex_normals)[used],
        visual=trimesh.visual.TextureVisuals(uv=np.asarray(whole.visual.uv)[used]),
        process=False,
    )
    mesh.metadata.update(two_sided=whole.metadata["two_sided"], bodies=whole.metadata["bodies"], material=int(material),
                         uv_notes=list(notes))  # fmt: skip
    return mesh


def asset_parts(path: str | os.PathLike, *, crease_deg: float | None = None) -> AssetParts | None:
    """The per-material parts of a glTF/OBJ file with their MaterialSpecs; None for a file without materials.

    Raises:
        FileNotFoundError: no such file.
        ValueError: one line ``"<file>: <reason>"``: unreadable materials or textures
            (:func:`.asset_materials.read_materials`), a mesh the asset pipeline refuses, NaN UVs.
    """
    path = Path(path)
    mats = asset_materials.read_materials(path)
    if mats is None:
        return None
    _, _, uv_notes, no_uv = _grouped(path, crease_deg)
    parts = []
    for k in material_keys(path, crease_deg=crease_deg):
        material = mats.materials[k] if 0 <= k < len(mats.materials) else None
        selector = "none" if k == assets.MATERIAL_NONE else str(k)
        parts.append(AssetPart(f"{path}#material={selector}", k, material))
    notes = list(mats.notes) + list(uv_notes)
    lost = sorted(k for k in no_uv if 0 <= k < len(mats.materials) and mats.materials[k].textures is not None)
    if lost:
        notes.append(f"textured materials {lost} have triangles without UVs (their textures read one texel there)")
    return AssetParts(str(path), tuple(parts), tuple(notes))
