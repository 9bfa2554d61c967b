"""Meshes for synthetic scenes: mesh references, loading, cleaning, UVs, placement in view, PLY output.

Objaverse-like scenes without Objaverse: :func:`load_mesh` reads GLB/GLTF/OBJ/PLY files (merging
scene parts with their transforms) or builds a ``builtin:`` shape (:mod:`.procedural`),
:func:`place` puts a mesh at a random pose 50-100 cm in front of the camera and fully inside
its view, :func:`write_ply` writes what Mitsuba's ``ply`` plugin loads. Sizes follow the
convention of :mod:`.procedural` (:func:`~.procedural.diameter`).

Convention (mesh strings):
    A mesh reference is a file path or ``builtin:<shape>[?key=value&...]``; values parse as
    int, then float, else stay strings:

    >>> parse_builtin("builtin:torus?seed=3&minor=0.3")
    ('torus', {'seed': 3, 'minor': 0.3})

trimesh is needed to build or load meshes (:func:`load_mesh`); without it the rest (mesh
references, :func:`place`, :func:`write_ply_arrays`) still imports and works, so the Blender
add-on can use the scene spec in a Python without trimesh.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl

import numpy as np
from numpy.typing import ArrayLike, NDArray

try:
    import trimesh
except ModuleNotFoundError:  # Blender's Python: specs, placement and PLY output work without it
    trimesh = None

from pbrdf.sensor.rig import Rig, atomic_write_bytes

from .procedural import PROCEDURAL_SHAPES, diameter, normalize, procedural, require_trimesh
from .unseen_shapes import UNSEEN_SHAPES, unseen_shape

__all__ = [
    "MESH_SUFFIXES",
    "ensure_uv",
    "list_assets",
    "load_mesh",
    "parse_builtin",
    "place",
    "random_rotation",
    "write_ply",
    "write_ply_arrays",
    # re-exported from .procedural (their home) for existing callers
    "PROCEDURAL_SHAPES",
    "diameter",
    "normalize",
    "procedural",
]

#: File types :func:`load_mesh` reads (lower case).
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply")

_BUILTIN_PREFIX = "builtin:"


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


# --------------------------------------------------------------------------- loading and cleaning


def _degenerate(name: str, reason: str) -> ValueError:
    return ValueError(f"{name}: degenerate mesh: {reason}")


def _clean(mesh: trimesh.Trimesh, name: str) -> trimesh.Trimesh:
    """Merge duplicate vertices, drop degenerate/duplicate faces and unused vertices; reject non-solids."""
    v = np.asarray(mesh.vertices)
    if len(mesh.faces) == 0 or len(v) == 0:
        raise _degenerate(name, "no triangles")
    if not np.all(np.isfinite(v)):
        bad = int(np.sum(~np.isfinite(v).all(axis=1)))
        raise _degenerate(name, f"{bad} vertex{'es' if bad != 1 else ''} with NaN or Inf coordinates")
    mesh.merge_vertices(merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) < 4:
        n = len(mesh.faces)
        plural = "s" if n != 1 else ""
        raise _degenerate(name, f"only {n} non-degenerate face{plural} (a closed solid needs at least 4)")
    extents = np.asarray(mesh.extents, dtype=np.float64)
    if not extents.max() > 0:
        raise _degenerate(name, "all vertices coincide (zero extent)")
    if extents.min() <= 1e-6 * extents.max():
        axis = "xyz"[int(np.argmin(extents))]
        raise _degenerate(name, f"flat: zero extent along {axis} (bounding-box extents {extents.tolist()})")
    # Consistent winding, outward for closed meshes (the renderer's normals come from the faces).
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
    if mesh.is_watertight and mesh.volume < 0:
        mesh.invert()
    return mesh


def _scene_to_mesh(scene: trimesh.Scene, name: str) -> trimesh.Trimesh:
    """Concatenate every triangle mesh of a scene with its scene-graph transform applied.

    UVs are kept only when the scene holds exactly one textured triangle mesh: UV charts of
    separate parts overlap, so a merged multi-part mesh is left without UVs for :func:`ensure_uv`.
    """
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        uv = getattr(geom.visual, "uv", None)
        part = trimesh.Trimesh(vertices=np.asarray(geom.vertices), faces=np.asarray(geom.faces), process=False)
        part.apply_transform(np.asarray(transform, dtype=np.float64))
        parts.append((part, None if uv is None or len(uv) != len(geom.vertices) else np.asarray(uv)))
    if not parts:
        raise _degenerate(name, "no triangle geometry (empty file, point cloud or lines only)")
    if len(parts) == 1:
        mesh, uv = parts[0]
        if uv is not None:
            mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
        return mesh
    return trimesh.util.concatenate([p for p, _ in parts])


def load_mesh(path_or_builtin: str | os.PathLike) -> trimesh.Trimesh:
    """Load a mesh file (GLB, GLTF, OBJ, PLY) or a ``builtin:`` shape as one clean triangle mesh.

    Files are read as scenes and all parts merged with their scene transforms applied; then
    duplicate vertices are merged (by position), degenerate and duplicate faces and unreferenced
    vertices removed, the winding made consistent and, for closed meshes, outward. The mesh keeps
    its file's scale and position (see :func:`normalize`).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unsupported file type, unreadable file, or ``"<file>: degenerate mesh: <reason>"``
            for an empty file, no triangles, fewer than 4 faces, NaN vertices, or a flat or
            zero-extent bounding box.
    """
    require_trimesh()
    builtin = parse_builtin(str(path_or_builtin)) if isinstance(path_or_builtin, str) else None
    if builtin is not None:
        shape, params = builtin
        if shape in UNSEEN_SHAPES:
            if params:
                raise ValueError(f"builtin:{shape} takes no parameters, got {sorted(params)}")
            return unseen_shape(shape)
        return procedural(shape, **params)
    path = Path(path_or_builtin)
    name = str(path)
    if not path.is_file():
        raise FileNotFoundError(f"{name}: mesh file not found")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"{name}: unsupported mesh type {suffix!r}; supported: {list(MESH_SUFFIXES)}")
    if path.stat().st_size == 0:
        raise _degenerate(name, "empty file (0 bytes)")
    try:
        scene = trimesh.load(path, file_type=suffix[1:], force="scene", process=False)
    except Exception as e:  # trimesh raises many types for malformed files; report them as bad content
        raise ValueError(f"{name}: cannot read mesh: {type(e).__name__}: {e}") from None
    return _clean(_scene_to_mesh(scene, name), name)


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


# --------------------------------------------------------------------------- placement


def random_rotation(rng: np.random.Generator) -> NDArray[np.float64]:
    """Rotation matrix ``(3, 3)`` uniform on SO(3): a normalised Gaussian quaternion (Shoemake 1992)."""
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _range(value: Any, name: str) -> tuple[float, float]:
    lo, hi = (float(v) for v in value)
    if not 0 < lo <= hi or not math.isfinite(hi):
        raise ValueError(f"{name} must be (min, max) with 0 < min <= max, got {value!r}")
    return lo, hi


def place(
    mesh: trimesh.Trimesh,
    rig: Rig,
    rng: np.random.Generator,
    *,
    distance: tuple[float, float] = (0.5, 1.0),
    size: tuple[float, float] = (0.15, 0.35),
    margin: float = 0.03,
    max_tries: int = 100,
) -> NDArray[np.float64]:
    """Random pose of a mesh in front of the camera, fully inside its view.

    The rotation is uniform on SO(3), the :func:`diameter` uniform in ``size`` metres, and the
    bounding-box centre lies at a distance uniform in ``distance`` from the camera centre, on the
    ray through a pixel drawn uniformly among those that keep the object's bounding sphere
    inside the view. Every vertex then projects inside the sensor at least
    ``margin * min(W, H)`` pixels from each edge (checked exactly).

    Args:
        mesh: the object in its own units (any scale and position).
        rig: supplies the camera (its pose and intrinsics).
        rng: random generator; the same state gives the same pose.
        distance: (min, max) distance in m from the camera to the object's centre.
        size: (min, max) object diameter in m.
        margin: fraction of the shorter sensor side kept free on every edge.
        max_tries: draws of (rotation, size, distance) before giving up.

    Returns:
        ``to_world`` ``(4, 4)``: object coordinates to world (rotation times uniform scale plus
        translation).

    Raises:
        ValueError: bad ranges, or no pose found in ``max_tries`` (the object cannot fit at that
            size and distance).
    """
    d_lo, d_hi = _range(distance, "distance")
    s_lo, s_hi = _range(size, "size")
    if not 0 <= margin < 0.5:
        raise ValueError(f"margin must be in [0, 0.5), got {margin}")
    cam = rig.camera
    w, h, f = cam.sensor_width_px, cam.sensor_height_px, cam.focal_length_px
    margin_px = margin * min(w, h)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    local = v - centre
    radius = float(np.sqrt(np.max(np.sum(local**2, axis=1))))
    if not radius > 0:
        raise ValueError("cannot place a mesh whose vertices all coincide")
    # Inward unit normals of the four side planes of the frustum shrunk by the margin (camera frame).
    tx = (w / 2 - margin_px) / f
    ty = (h / 2 - margin_px) / f
    planes = np.array([[-1.0, 0.0, -tx], [1.0, 0.0, -tx], [0.0, -1.0, -ty], [0.0, 1.0, -ty]])
    planes /= np.linalg.norm(planes, axis=1, keepdims=True)
    cam_to_world = cam.camera_to_world()
    candidates = 64
    for _ in range(int(max_tries)):
        rot = random_rotation(rng)
        scale = rng.uniform(s_lo, s_hi) / (2.0 * radius)
        dist = rng.uniform(d_lo, d_hi)
        u = rng.uniform(margin_px, w - margin_px, candidates)
        vv = rng.uniform(margin_px, h - margin_px, candidates)
        dirs = np.stack([(u - w / 2) / f, (h / 2 - vv) / f, -np.ones(candidates)], axis=-1)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        sphere_ok = np.all(dirs @ planes.T >= scale * radius / dist, axis=1)
        # The bounding sphere inside the view implies every vertex is; without such a candidate
        # (a large object close by) test the vertices of every candidate.
        ks = np.flatnonzero(sphere_ok) if sphere_ok.any() else np.arange(candidates)
        pts_obj = local @ (scale * rot).T
        for k in ks:
            to_cam = np.eye(4)
            to_cam[:3, :3] = scale * rot
            to_cam[:3, 3] = dist * dirs[k] - to_cam[:3, :3] @ centre
            to_world = cam_to_world @ to_cam
            pts = pts_obj + dist * dirs[k]
            pts_world = pts @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
            if cam.out_of_view_px(pts_world, margin_px) <= 0:
                return to_world
    raise ValueError(
        f"place: no pose inside the view after {max_tries} tries "
        f"(size {size} m at distance {distance} m with a {margin:.0%} margin)"
    )


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


def write_ply_arrays(
    path: str | os.PathLike,
    vertices: ArrayLike,
    faces: ArrayLike,
    *,
    normals: ArrayLike | None = None,
    uvs: ArrayLike | None = None,
) -> None:
    """Write triangles as a binary little-endian PLY (Mitsuba 3's ``ply`` plugin reads it), atomically.

    Args:
        path: output file.
        vertices: ``(N, 3)`` positions.
        faces: ``(F, 3)`` vertex indices, counter-clockwise seen from the front.
        normals: optional ``(N, 3)`` vertex normals (``nx ny nz``); without them Mitsuba shades flat.
        uvs: optional ``(N, 2)`` texture coordinates (``u v``, v up).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"write_ply: need vertices (N, 3) and faces (F, 3), got {v.shape} and {f.shape}")
    if len(v) == 0 or len(f) == 0:
        raise ValueError("write_ply: the mesh has no triangles")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"write_ply: face indices must be in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    extra = {"n": normals, "uv": uvs}
    fields = [(k, "<f4") for k in ("x", "y", "z")]
    if normals is not None:
        extra["n"] = np.asarray(normals, dtype=np.float64).reshape(len(v), 3)
        fields += [(k, "<f4") for k in ("nx", "ny", "nz")]
    if uvs is not None:
        extra["uv"] = np.asarray(uvs, dtype=np.float64).reshape(len(v), 2)
        fields += [("u", "<f4"), ("v", "<f4")]
    vert = np.empty(len(v), dtype=fields)
    for i, k in enumerate("xyz"):
        vert[k] = v[:, i]
        if normals is not None:
            vert["n" + k] = extra["n"][:, i]
    if uvs is not None:
        vert["u"], vert["v"] = extra["uv"][:, 0], extra["uv"][:, 1]
    face = np.empty(len(f), dtype=[("n", "u1"), ("i", "<u4", (3,))])
    face["n"] = 3
    face["i"] = f
    props = "".join(f"property float {k}\n" for k, _ in fields)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by blender_addon.core.assets\n"
        f"element vertex {len(v)}\n{props}"
        f"element face {len(f)}\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    atomic_write_bytes(path, header.encode("ascii") + vert.tobytes() + face.tobytes())
