"""Meshes for synthetic scenes: mesh references, loading, cleaning, UVs, PLY output.

Objaverse-like scenes without Objaverse: :func:`load_mesh` reads GLB/GLTF/OBJ/PLY files (merging
scene parts with their transforms) or builds a ``builtin:`` shape (:mod:`.procedural`),
:func:`write_ply` writes what Mitsuba's ``ply`` plugin loads; :func:`.placement.place` puts a mesh
in view. Sizes follow the convention of :mod:`.procedural` (:func:`~.procedural.diameter`).

Convention (mesh strings):
    A mesh reference is a file path or ``builtin:<shape>[?key=value&...]``; values parse as
    int, then float, else stay strings:

    >>> parse_builtin("builtin:torus?seed=3&minor=0.3")
    ('torus', {'seed': 3, 'minor': 0.3})

trimesh is needed to build or load meshes (:func:`load_mesh`); without it the rest (mesh
references) still imports and works, so the Blender add-on can use the
scene spec in a Python without trimesh.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl

import numpy as np
from numpy.typing import ArrayLike, NDArray

try:
    import trimesh
except ModuleNotFoundError:  # Blender's Python: specs and PLY output work without it
    trimesh = None

from . import asset_io
from . import mesh_normals as _mn
from .generated_shapes import GENERATED_SHAPES, generated_shape
from .ply_io import write_ply_arrays
from .procedural import PROCEDURAL_SHAPES, diameter, normalize, procedural, require_trimesh
from .unseen_shapes import UNSEEN_SHAPES, unseen_shape

__all__ = [
    "CREASE_DEG",
    "MATERIAL_NONE",
    "MESH_SUFFIXES",
    "MIN_THICKNESS",
    "MeshPart",
    "build_render_mesh",
    "usable_assets",
    "weld",
    "ensure_uv",
    "list_assets",
    "load_mesh",
    "load_part",
    "material_keys",
    "mesh_file",
    "parse_builtin",
    "split_mesh_ref",
    "write_ply",
    # re-exported from .procedural (their home) for existing callers
    "PROCEDURAL_SHAPES",
    "diameter",
    "normalize",
    "procedural",
]

#: File types :func:`load_mesh` reads (lower case). FBX is read only inside Blender (the add-on).
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".off")
#: Dihedral angle (degrees) above which an edge of a mesh without authored normals is hard.
CREASE_DEG = 30.0
#: Thinnest accepted bounding-box extent as a fraction of the largest: flatter meshes are cards.
MIN_THICKNESS = 0.005

_BUILTIN_PREFIX = "builtin:"
#: Material key of a selector ``#material=none``: the primitives without a material.
MATERIAL_NONE = -1
_SELECTOR = re.compile(r"#material=(\d+|none)$")


def parse_builtin(mesh: str) -> tuple[str, dict[str, Any]] | None:
    """Split ``"builtin:<shape>?k=v&..."`` into ``(shape, params)``; None for other strings."""
    if not isinstance(mesh, str) or not mesh.startswith(_BUILTIN_PREFIX):
        return None
    shape, _, query = mesh[len(_BUILTIN_PREFIX) :].partition("?")
    params: dict[str, Any] = {}
    for key, raw in parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)):
        value: Any = raw
        for conv in (int, float):
            try:
                value = conv(raw)
                break
            except ValueError:
                continue
        params[key] = value
    return shape, params


def split_mesh_ref(mesh: str | os.PathLike) -> tuple[str, int | None]:
    """Split ``"<file>#material=<K>"`` (the triangles of material K of an asset) into ``(file, K)``.

    K is the material's index in the file (glTF ``materials``, MTL ``newmtl`` order) or ``none``
    (:data:`MATERIAL_NONE`: the primitives without a material); other references give ``(ref, None)``.

    >>> split_mesh_ref("chair.gltf#material=2"), split_mesh_ref("a.glb#material=none"), split_mesh_ref("a.ply")
    (('chair.gltf', 2), ('a.glb', -1), ('a.ply', None))
    """
    ref = os.fspath(mesh)
    m = _SELECTOR.search(ref) if not ref.startswith(_BUILTIN_PREFIX) else None
    if m is None:
        tail = ref.rpartition("#material=")[2] if "#material=" in ref else "/"
        if not ref.startswith(_BUILTIN_PREFIX) and "/" not in tail and os.sep not in tail:
            raise ValueError(f"{ref}: bad material selector; use <file>#material=<index> or #material=none")
        return ref, None
    return ref[: m.start()], MATERIAL_NONE if m.group(1) == "none" else int(m.group(1))


def mesh_file(mesh: str | os.PathLike) -> str:
    """The file a mesh reference reads (its material selector left out); the reference itself for a ``builtin:``."""
    return split_mesh_ref(mesh)[0]


# --------------------------------------------------------------------------- loading and cleaning


@dataclass
class MeshPart:
    """Triangles of one part of an asset, in the asset's frame (the scene transform applied).

    Attributes:
        vertices: ``(N, 3)`` positions.
        faces: ``(F, 3)`` vertex indices.
        normals: ``(N, 3)`` authored vertex normals, or None when the file has none.
        uvs: ``(N, 2)`` texture coordinates, or None.
        group: the part's material index in a per-material read (:func:`load_part`), else None.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    normals: NDArray[np.float64] | None = None
    uvs: NDArray[np.float64] | None = None
    group: int | None = None


def _degenerate(name: str, reason: str) -> ValueError:
    return ValueError(f"{name}: degenerate mesh: {reason}")


def _authored_normals(geom: trimesh.Trimesh) -> NDArray[np.float64] | None:
    """The vertex normals a file supplied (trimesh keeps them in its cache), else None."""
    cache = getattr(getattr(geom, "_cache", None), "cache", {})
    n = cache.get("vertex_normals") if hasattr(cache, "get") else None
    if n is None or np.shape(n) != np.shape(geom.vertices):
        return None
    return np.asarray(n, dtype=np.float64)


def _scene_parts(scene: trimesh.Scene, name: str, *, tagged: bool = False) -> list[MeshPart]:
    """Every triangle mesh of a scene with its scene-graph transform applied (normals and winding too).

    UVs are kept only when the scene holds exactly one textured triangle mesh: UV charts of
    separate parts overlap, so a merged multi-part mesh is left without UVs for :func:`ensure_uv`.
    ``tagged`` (a per-material read, :func:`load_part`): every part keeps its UVs and its
    material index (``metadata[asset_io.PART_TAG][0]``).
    """
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        m = np.asarray(transform, dtype=np.float64)
        v = np.asarray(geom.vertices, dtype=np.float64)
        f = np.asarray(geom.faces, dtype=np.int64)
        if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"{name}: face indices out of range (the file has {len(v)} vertices)")
        n = _authored_normals(geom)
        if not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:3, :3])) < 1e-300:
            raise ValueError(f"{name}: singular or non-finite node transform")
        if not np.all(np.isfinite(v)):
            bad = int(np.sum(~np.isfinite(v).all(axis=1)))
            raise _degenerate(name, f"{bad} vertex{'es' if bad != 1 else ''} with NaN or Inf coordinates")
        v = v @ m[:3, :3].T + m[:3, 3]
        if n is not None:
            n = n @ np.linalg.inv(m[:3, :3])  # inverse transpose, row vectors
        if np.linalg.det(m[:3, :3]) < 0:  # a mirroring transform turns the winding around
            f = f[:, ::-1]
        uv = getattr(geom.visual, "uv", None)
        uv = None if uv is None or len(uv) != len(geom.vertices) else np.asarray(uv, dtype=np.float64)
        group = (geom.metadata.get(asset_io.PART_TAG) or [None])[0] if tagged else None
        parts.append(MeshPart(v, f, n, uv, group))
    if not parts:
        raise _degenerate(name, "no triangle geometry (empty file, point cloud or lines only)")
    if len(parts) > 1 and not tagged:
        for p in parts:
            p.uvs = None
    return parts


def _unique_rows(keys: NDArray) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``(first, ids)`` of equal rows, ids numbered in order of first occurrence (keeps vertex order)."""
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    order = np.argsort(first, kind="stable")
    rank[order] = np.arange(len(first))
    return first[order], rank[inverse.reshape(-1)]


def weld(vertices: ArrayLike, scale: float | None = None) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Merge vertices at one position (UV seams, split normals), keeping the order of first use.

    Args:
        vertices: ``(N, 3)`` positions.
        scale: the mesh's size (default: its bounding-box diagonal); positions within about
            1e-7 of it are one.

    Returns:
        ``(first, ids)``: index of the first vertex of every welded vertex ``(M,)`` and the
        welded id of every vertex ``(N,)``, numbered in order of first occurrence.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if scale is None:
        scale = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) if len(v) else 1.0
    return _unique_rows(np.round(v / (max(scale, 1e-300) * 1e-7)).astype(np.int64))


def _flipped(before: NDArray[np.int64], after: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Which faces ``after`` lists in the opposite cyclic order of ``before`` (same vertices)."""
    same = np.zeros(len(before), dtype=bool)
    for r in range(3):
        same |= np.all(np.roll(before, r, axis=1) == after, axis=1)
    return ~same


def build_render_mesh(
    parts: list[MeshPart], name: str, *, crease_deg: float | None = None, keep_parts: bool = False
) -> trimesh.Trimesh:
    """Clean, orient and shade the parts of an asset: the one mesh every renderer gets.

    Steps: reject non-finite or empty input; weld vertices by position (UV seams and split
    normals join) for topology only; drop degenerate and duplicate faces (a card modelled as two
    coincident layers keeps one); refuse meshes with fewer than 4 faces or a flat bounding box;
    make the winding consistent and closed bodies outward (:func:`trimesh.repair.fix_normals`,
    per body); keep authored normals where they are finite and on the front of their face (a
    flipped face flips its corner normals), otherwise use crease-angle normals
    (:func:`.mesh_normals.crease_corner_normals`); split vertices where corner normals differ.

    Args:
        parts: the asset's parts in one frame.
        name: the asset's name for error messages (e.g. the file path).
        crease_deg: dihedral angle above which an edge without authored normals is hard
            (default :data:`CREASE_DEG`).
        keep_parts: keep every part's UVs (zeros for a part without) and record the part of every
            face in ``metadata["face_part"]`` (``(F,)`` indices into ``parts``); the faces, positions
            and normals are those of the default call.

    Returns:
        A trimesh with ``vertex_normals`` set to the shading normals (do not edit its vertices:
        that would recompute them) and, when the input had them, UVs. ``metadata["two_sided"]``
        is True for a mesh that is not closed (its back may be seen; render it two-sided),
        ``metadata["bodies"]`` counts its connected parts.

    Raises:
        ValueError: ``"<name>: degenerate mesh: <reason>"``.
    """
    crease = CREASE_DEG if crease_deg is None else float(crease_deg)
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    v = np.concatenate([p.vertices for p in parts]).astype(np.float64)
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=False)]).astype(np.int64)
    if len(faces) == 0 or len(v) == 0:
        raise _degenerate(name, "no triangles")
    if not np.all(np.isfinite(v)):
        bad = int(np.sum(~np.isfinite(v).all(axis=1)))
        raise _degenerate(name, f"{bad} vertex{'es' if bad != 1 else ''} with NaN or Inf coordinates")
    used = v[np.unique(faces)]
    extents = used.max(axis=0) - used.min(axis=0)
    diag = float(np.linalg.norm(extents))
    if not diag > 0:
        raise _degenerate(name, "all vertices coincide (zero extent)")
    authored = None
    if any(p.normals is not None for p in parts):
        authored = np.concatenate(
            [p.normals if p.normals is not None else np.full((len(p.vertices), 3), np.nan) for p in parts]
        )
    uv = parts[0].uvs if len(parts) == 1 else None
    if keep_parts:
        uv = np.concatenate([p.uvs if p.uvs is not None else np.zeros((len(p.vertices), 2)) for p in parts])
    face_part = np.repeat(np.arange(len(parts)), [len(p.faces) for p in parts])

    weld_first, weld_id = weld(v, diag)
    wf = weld_id[faces]
    _, area = _mn.face_normals(v, faces)
    ok = (wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 0] != wf[:, 2]) & (area > 1e-14 * diag**2)
    faces, wf, face_part = faces[ok], wf[ok], face_part[ok]
    if len(wf):
        _, first = np.unique(np.sort(wf, axis=1), axis=0, return_index=True)
        keep = np.sort(first)
        faces, wf, face_part = faces[keep], wf[keep], face_part[keep]
    if len(faces) < 4:
        n = len(faces)
        raise _degenerate(name, f"only {n} non-degenerate face{'s' if n != 1 else ''} (a solid needs at least 4)")
    used = v[np.unique(faces)]
    extents = used.max(axis=0) - used.min(axis=0)
    if extents.min() < MIN_THICKNESS * extents.max():
        axis = "xyz"[int(np.argmin(extents))]
        raise _degenerate(
            name,
            f"flat: thickness along {axis} is {extents.min() / extents.max():.2g} of the size "
            f"(a card, needs >= {MIN_THICKNESS:g}; bounding-box extents {np.round(extents, 6).tolist()})",
        )

    # Topology on the welded mesh: consistent winding, closed bodies outward.
    welded = trimesh.Trimesh(vertices=v[weld_first], faces=wf, process=False)
    before = wf.copy()
    trimesh.repair.fix_normals(welded, multibody=True)
    flip = _flipped(before, np.asarray(welded.faces))
    faces = np.where(flip[:, None], faces[:, ::-1], faces)
    two_sided = not welded.is_watertight

    corner = _mn.crease_corner_normals(v, faces, crease_deg=crease, weld=weld_id)
    if authored is not None:
        fn, _ = _mn.face_normals(v, faces)
        a = authored[faces]  # (F, 3, 3)
        a = np.where(flip[:, None, None], -a, a)
        length = np.linalg.norm(a, axis=-1, keepdims=True)
        a = a / np.where(length > 0, length, 1.0)
        valid = np.isfinite(a).all(axis=-1) & (length[..., 0] > 1e-6)
        valid &= np.einsum("fkj,fj->fk", np.nan_to_num(a), fn) > 0
        corner = np.where(valid[..., None], a, corner)
    # One source vertex per (position, UV): a triangle soup or a file's split normals join again.
    key = weld_id[:, None] if uv is None else np.concatenate([weld_id[:, None], np.round(uv * 1e7)], axis=1)
    canon_first, canon = _unique_rows(key)
    src, rfaces, rnormals = _mn.split_by_corner_normals(canon[faces], corner)
    src = canon_first[src]
    visual = trimesh.visual.TextureVisuals(uv=uv[src]) if uv is not None else None
    mesh = trimesh.Trimesh(vertices=v[src], faces=rfaces, vertex_normals=rnormals, visual=visual, process=False)
    mesh.metadata["two_sided"] = bool(two_sided)
    mesh.metadata["bodies"] = int(welded.body_count)
    if keep_parts:
        mesh.metadata["face_part"] = face_part
    return mesh


def _read_file(path: Path, suffix: str, name: str, *, tagged: bool = False) -> list[MeshPart]:
    """Parse a mesh file into parts; every failure becomes one ``ValueError`` naming the file.

    ``tagged``: every part with its UVs and material index (:func:`.asset_io.tagged_scene`).
    """
    if suffix in (".gltf", ".glb"):
        _check_gltf(path, suffix, name)
    try:
        if tagged:
            scene = asset_io.tagged_scene(path, name)
        else:
            scene = trimesh.load(path, file_type=suffix[1:], force="scene", process=False)
        return _scene_parts(scene, name, tagged=tagged)
    except Exception as e:  # trimesh raises many types for malformed files; report them as bad content
        if isinstance(e, ValueError) and str(e).startswith(name):
            raise
        why = " ".join(str(e).split())[:200] or "malformed content"
        raise ValueError(f"{name}: cannot read mesh: {type(e).__name__}: {why}") from None


def _check_gltf(path: Path, suffix: str, name: str) -> None:
    """Refuse glTF features trimesh would silently misread: version 1 and Draco-compressed meshes."""
    doc = asset_io.read_gltf(path, name)[0]
    version = str((doc.get("asset") or {}).get("version", "")) if isinstance(doc.get("asset"), dict) else ""
    if not version.startswith("2"):
        raise ValueError(f"{name}: unsupported glTF version {version or '1.0'!r} (glTF 2.0 only; re-export it)")
    used = doc.get("extensionsRequired") or doc.get("extensionsUsed") or []
    if isinstance(used, list) and "KHR_draco_mesh_compression" in used:
        raise ValueError(f"{name}: Draco-compressed glTF is not supported (re-export without Draco compression)")


def usable_assets(files: Iterable[str | os.PathLike]) -> tuple[list[Path], dict[str, str]]:
    """Split asset files into those :func:`load_mesh` loads and those it refuses.

    Returns:
        ``(loadable files in the given order, {file: the one-line reason})``.
    """
    ok, refused = [], {}
    for f in files:
        try:
            load_mesh(f)
            ok.append(Path(f))
        except (ValueError, OSError) as e:
            refused[str(f)] = str(e)
    return ok, refused


#: Meshes :func:`load_mesh` keeps per process (scene generation and rendering load each twice).
_CACHE_SIZE = 32


def load_mesh(path_or_builtin: str | os.PathLike, *, crease_deg: float | None = None) -> trimesh.Trimesh:
    """Load a mesh file (GLB, GLTF, OBJ, PLY, STL, OFF) or a ``builtin:`` shape as one render-ready mesh.

    Files are read as scenes, their parts put in one frame by the scene transforms, and then
    cleaned, oriented and shaded by :func:`build_render_mesh` (authored normals kept, crease-angle
    normals otherwise; ``metadata["two_sided"]`` marks open meshes). Built-in shapes go through
    the same step. The mesh keeps its file's scale and position (see :func:`normalize`).

    Meshes are cached per process (the last :data:`_CACHE_SIZE`, files keyed by path, size and
    modification time): treat the result as read-only.

    ``"<file>#material=<K>"`` (:func:`split_mesh_ref`) is the part of a glTF/OBJ file drawn with
    its material K, with that part's UVs (:func:`load_part`); the parts of all
    materials together are the file's mesh.

    Args:
        path_or_builtin: a file path (with an optional material selector) or
            ``builtin:<shape>[?key=value&...]``.
        crease_deg: crease angle for meshes without authored normals (default :data:`CREASE_DEG`).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: one line ``"<file>: <reason>"``: unsupported type, unreadable or malformed
            content, or ``degenerate mesh: ...`` (no triangles, fewer than 4 faces, NaN vertices,
            flat or zero extent).
    """
    require_trimesh()
    ref = str(path_or_builtin)
    key: tuple = (ref, crease_deg)
    if not ref.startswith(_BUILTIN_PREFIX):
        try:
            st = os.stat(mesh_file(ref))
            key += (st.st_mtime_ns, st.st_size)
        except OSError:
            key = ()
    if key and key in _MESH_CACHE:
        _MESH_CACHE[key] = _MESH_CACHE.pop(key)  # most recently used last
        return _MESH_CACHE[key]
    mesh = _load_mesh(path_or_builtin, crease_deg)
    if key:
        _MESH_CACHE[key] = mesh
        while len(_MESH_CACHE) > _CACHE_SIZE:
            _MESH_CACHE.pop(next(iter(_MESH_CACHE)))
    return mesh


_MESH_CACHE: dict[tuple, trimesh.Trimesh] = {}


def _load_mesh(path_or_builtin: str | os.PathLike, crease_deg: float | None) -> trimesh.Trimesh:
    builtin = parse_builtin(str(path_or_builtin)) if isinstance(path_or_builtin, str) else None
    if builtin is not None:
        shape, params = builtin
        if shape in UNSEEN_SHAPES:
            if params:
                raise ValueError(f"builtin:{shape} takes no parameters, got {sorted(params)}")
            raw = unseen_shape(shape)
        elif shape in GENERATED_SHAPES:
            raw = generated_shape(shape, **params)
        else:
            raw = procedural(shape, **params)
        part = MeshPart(np.asarray(raw.vertices, dtype=np.float64), np.asarray(raw.faces, dtype=np.int64))
        return build_render_mesh([part], str(path_or_builtin), crease_deg=crease_deg)
    file, material = split_mesh_ref(path_or_builtin)
    path = Path(file)
    name = str(path)
    if not path.is_file():
        raise FileNotFoundError(f"{name}: mesh file not found")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"{name}: unsupported mesh type {suffix!r}; supported: {list(MESH_SUFFIXES)}")
    if path.stat().st_size == 0:
        raise _degenerate(name, "empty file (0 bytes)")
    if material is not None:
        return load_part(path, material, crease_deg=crease_deg)
    return build_render_mesh(_read_file(path, suffix, name), name, crease_deg=crease_deg)


#: Whole-file meshes :func:`load_part` cuts parts from, kept per process (large files: few).
_GROUPED_SIZE = 4
_GROUPED: dict[tuple, tuple] = {}


def _grouped(path: Path, crease_deg: float | None) -> tuple[trimesh.Trimesh, NDArray[np.int64], list[str], set]:
    """The file's render mesh with UVs, each face's material, the UV notes and the materials lacking UVs (cached)."""
    st = os.stat(path)
    key = (str(path), st.st_mtime_ns, st.st_size, crease_deg)
    if key not in _GROUPED:
        parts = _read_file(path, path.suffix.lower(), str(path), tagged=True)
        notes = asset_io.clean_uvs(parts, str(path))
        mesh = build_render_mesh(parts, str(path), crease_deg=crease_deg, keep_parts=True)
        groups = np.array([MATERIAL_NONE if p.group is None else p.group for p in parts], dtype=np.int64)
        _GROUPED[key] = (mesh, groups[mesh.metadata["face_part"]], notes, {p.group for p in parts if p.uvs is None})
        while len(_GROUPED) > _GROUPED_SIZE:
            _GROUPED.pop(next(iter(_GROUPED)))
    return _GROUPED[key]


def material_keys(path: str | os.PathLike, *, crease_deg: float | None = None) -> list[int]:
    """The materials of a glTF/OBJ file that have triangles, in index order (:data:`MATERIAL_NONE` last)."""
    keys = np.unique(_grouped(Path(path), crease_deg)[1]).tolist()
    return sorted(keys, key=lambda k: (k == MATERIAL_NONE, k))


def load_part(path: str | os.PathLike, material: int, *, crease_deg: float | None = None) -> trimesh.Trimesh:
    """The triangles of material ``material`` of a glTF/OBJ file with their UVs: ``load_mesh("<file>#material=K")``.

    The parts are cut from one render mesh of the whole file (:func:`build_render_mesh` with
    ``keep_parts``), so the parts of all materials together have the faces, positions (within
    the weld tolerance) and shading normals of ``load_mesh(file)``: an asset renders the same as
    one object or as one object per material. UVs: :func:`.asset_io.tagged_scene`,
    :func:`.asset_io.clean_uvs`.

    Returns:
        A trimesh with ``vertex_normals`` (the whole file's shading normals), UVs (zeros where
        the file has none) and ``metadata``: ``two_sided`` and ``bodies`` of the whole file,
        ``material`` (the key), ``uv_notes`` (:func:`.asset_io.clean_uvs`) and ``has_uv`` (False:
        some of its triangles come without UVs).

    Raises:
        ValueError: ``"<file>: <reason>"``: no triangles of that material, NaN UVs, a file the
            asset pipeline refuses.
    """
    path = Path(path)
    whole, groups, notes, no_uv = _grouped(path, crease_deg)
    sel = groups == material
    if not sel.any():
        label = "none" if material == MATERIAL_NONE else material
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
    meta = {k: whole.metadata[k] for k in ("two_sided", "bodies")}
    mesh.metadata.update(meta, material=int(material), uv_notes=list(notes), has_uv=material not in no_uv)
    return mesh


# --------------------------------------------------------------------------- scale, UVs
def _has_uv(mesh: trimesh.Trimesh) -> bool:
    uv = getattr(mesh.visual, "uv", None)
    return uv is not None and len(uv) == len(mesh.vertices)


def ensure_uv(mesh: trimesh.Trimesh, *, force: bool = False) -> trimesh.Trimesh:
    """Return the mesh with per-vertex UVs, unwrapping it with xatlas when it has none.

    xatlas splits vertices along chart seams; positions and vertex normals are copied to the
    split vertices, so shading is unchanged. UVs lie in [0, 1] (OpenGL convention, v up).
    The cost grows roughly linearly with the face count (chart building dominates): decimate
    large assets first.

    Args:
        mesh: input mesh (returned unchanged when it already has UVs and ``force`` is False).
        force: unwrap even when UVs exist (e.g. overlapping charts of merged parts).
    """
    if _has_uv(mesh) and not force:
        return mesh
    import xatlas

    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    vmapping, indices, uvs = xatlas.parametrize(
        np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.uint32)
    )
    out = trimesh.Trimesh(
        vertices=np.asarray(mesh.vertices)[vmapping],
        faces=np.asarray(indices, dtype=np.int64),
        vertex_normals=normals[vmapping],
        visual=trimesh.visual.TextureVisuals(uv=np.clip(np.asarray(uvs, dtype=np.float64), 0.0, 1.0)),
        process=False,
    )
    return out


# --------------------------------------------------------------------------- files


def list_assets(folder: str | os.PathLike, suffixes: Iterable[str] = MESH_SUFFIXES) -> list[Path]:
    """Files under ``folder`` (recursively) with one of ``suffixes`` (any case), sorted by relative path.

    Raises:
        FileNotFoundError: the folder does not exist.
        NotADirectoryError: it is a file.
    """
    root = Path(folder)
    if not root.exists():
        raise FileNotFoundError(f"{root}: asset folder not found")
    if not root.is_dir():
        raise NotADirectoryError(f"{root}: not a folder")
    wanted = {x.lower() for x in suffixes}
    files = [p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in wanted]
    return sorted(files, key=lambda p: p.relative_to(root).as_posix())


def write_ply(mesh: trimesh.Trimesh, path: str | os.PathLike) -> None:
    """Write a binary little-endian PLY that Mitsuba 3's ``ply`` plugin loads, atomically.

    Vertex properties: ``x y z nx ny nz`` (float32) plus ``u v`` when the mesh has per-vertex
    UVs (as stored by trimesh, v up); faces as ``list uchar uint vertex_indices``.
    """
    uv = np.asarray(mesh.visual.uv, dtype=np.float64) if _has_uv(mesh) else None
    if len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise ValueError("write_ply: the mesh has no triangles")
    write_ply_arrays(path, mesh.vertices, mesh.faces, normals=mesh.vertex_normals, uvs=uv)
