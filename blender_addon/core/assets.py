"""Meshes for synthetic scenes: loading, cleaning, UVs, placement in the camera's view, PLY output.

Objaverse-like scenes without Objaverse: :func:`load_mesh` reads GLB/GLTF/OBJ/PLY files (merging
scene parts with their transforms), :func:`procedural` builds a seeded set of shapes in code
(spheres, tori, superquadrics, displaced blobs, bevelled boxes), :func:`place` puts a mesh at a
random pose 50-100 cm in front of the camera and fully inside its view, :func:`write_ply` writes
what Mitsuba's ``ply`` plugin loads.

Convention (mesh strings): a mesh reference is a file path or ``builtin:<shape>[?key=value&...]``,
e.g. ``builtin:torus?seed=3&minor=0.3``; values parse as int, then float, else stay strings.

Convention (size): a mesh's *diameter* is twice the largest distance of a vertex from the centre
of its axis-aligned bounding box (:func:`diameter`); :func:`normalize` and :func:`place` use it.
It bounds the minimal enclosing sphere from above, so a normalised mesh fits in a unit sphere.

trimesh is needed to build or load meshes (:func:`procedural`, :func:`load_mesh`); without it
the rest (mesh references, :func:`place`, :func:`write_ply_arrays`) still imports and works, so
the Blender add-on can use the scene spec in a Python without trimesh.
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

__all__ = [
    "MESH_SUFFIXES",
    "PROCEDURAL_SHAPES",
    "diameter",
    "ensure_uv",
    "list_assets",
    "load_mesh",
    "normalize",
    "parse_builtin",
    "place",
    "procedural",
    "random_rotation",
    "write_ply",
    "write_ply_arrays",
]

#: File types :func:`load_mesh` reads (lower case).
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply")
#: Shapes :func:`procedural` builds.
PROCEDURAL_SHAPES = ("sphere", "torus", "superquadric", "blob", "bevel_box")

_BUILTIN_PREFIX = "builtin:"


# --------------------------------------------------------------------------- procedural shapes


def _require_trimesh() -> None:
    if trimesh is None:
        raise ModuleNotFoundError(
            "building or loading meshes needs the Python package 'trimesh' (pip install trimesh)", name="trimesh"
        )


def _orient_outward(vertices: NDArray, faces: NDArray) -> NDArray:
    """Flip faces whose normal points toward the origin (valid for convex shapes around it)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.einsum("ij,ij->i", n, tri.mean(axis=1)) < 0
    faces = faces.copy()
    faces[inward] = faces[inward][:, ::-1]
    return faces


def _cube_grid(coords: NDArray) -> tuple[NDArray, NDArray]:
    """Surface of the cube ``[-1, 1]^3`` gridded at ``coords`` (sorted, from -1 to 1) on each axis.

    Returns merged vertices ``(N, 3)`` and outward triangles ``(M, 3)``: a watertight mesh whose
    edges and corners are shared between the six faces.
    """
    n = len(coords)
    a, b = np.meshgrid(coords, coords, indexing="ij")
    idx = np.arange(n * n).reshape(n, n)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    grid_faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    verts, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            v = np.empty((n * n, 3))
            others = [i for i in range(3) if i != axis]
            v[:, axis] = sign
            v[:, others[0]] = a.ravel()
            v[:, others[1]] = b.ravel()
            faces.append(grid_faces + sum(len(x) for x in verts))
            verts.append(v)
    vertices = np.concatenate(verts)
    faces = np.concatenate(faces)
    # Merge the shared edge vertices exactly (grid coordinates are bit-identical across faces).
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    return unique, _orient_outward(unique, faces)


def _finish(vertices: NDArray, faces: NDArray) -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    mesh = normalize(mesh)
    _ = mesh.vertex_normals  # computed once and cached with the mesh
    return mesh


def _check_params(shape: str, params: dict, valid: tuple[str, ...]) -> None:
    unknown = set(params) - set(valid)
    if unknown:
        raise ValueError(f"unknown parameters {sorted(unknown)} for procedural shape {shape!r}; valid: {list(valid)}")


def _param(params: dict, key: str, default: Any, lo: float, hi: float, shape: str) -> float:
    value = params.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{shape}: parameter {key} must be a number, got {value!r}")
    value = float(value)
    if not lo <= value <= hi:
        raise ValueError(f"{shape}: parameter {key} must be in [{lo}, {hi}], got {value}")
    return value


def _sphere(rng: np.random.Generator, params: dict) -> trimesh.Trimesh:
    _check_params("sphere", params, ("subdivisions",))
    sub = int(_param(params, "subdivisions", 4, 1, 6, "sphere"))
    ico = trimesh.creation.icosphere(subdivisions=sub, radius=0.5)
    return _finish(np.asarray(ico.vertices), np.asarray(ico.faces))


def _torus(rng: np.random.Generator, params: dict) -> trimesh.Trimesh:
    _check_params("torus", params, ("minor", "major_sections", "minor_sections"))
    ratio = _param(params, "minor", rng.uniform(0.2, 0.5), 0.05, 0.95, "torus")  # tube / ring radius
    nu = int(_param(params, "major_sections", 64, 8, 1024, "torus"))
    nv = int(_param(params, "minor_sections", 32, 6, 1024, "torus"))
    u = np.arange(nu) * (2 * np.pi / nu)
    v = np.arange(nv) * (2 * np.pi / nv)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = 1.0 + ratio * np.cos(vv)
    vertices = np.stack([ring * np.cos(uu), ring * np.sin(uu), ratio * np.sin(vv)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    # Outward = away from the tube's centre line; (u, v) as above gives that winding for a -> b -> c.
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre_line = np.stack([np.cos(uu), np.sin(uu), np.zeros_like(uu)], -1).reshape(-1, 3)[faces[:, 0]]
    if np.einsum("ij,ij->i", n, tri[:, 0] - centre_line).sum() < 0:
        faces = faces[:, ::-1]
    return _finish(vertices, faces)


def _superquadric(rng: np.random.Generator, params: dict) -> trimesh.Trimesh:
    """Superellipsoid ``(|x/a|^(2/e2) + |y/b|^(2/e2))^(e2/e1) + |z/c|^(2/e1) = 1`` (Barr 1981).

    The inside-outside function F is homogeneous of degree ``2/e1``, so the surface point along a
    unit direction d is ``F(d)^(-e1/2) d``: a radial map of a gridded cube, watertight and outward.
    """
    _check_params("superquadric", params, ("e1", "e2", "a", "b", "c", "resolution"))
    e1 = _param(params, "e1", rng.uniform(0.3, 1.5), 0.1, 3.0, "superquadric")
    e2 = _param(params, "e2", rng.uniform(0.3, 1.5), 0.1, 3.0, "superquadric")
    axes = np.array(
        [_param(params, k, rng.uniform(0.6, 1.0), 0.05, 10.0, "superquadric") for k in ("a", "b", "c")],
    )
    res = int(_param(params, "resolution", 24, 2, 256, "superquadric"))
    cube_v, faces = _cube_grid(np.linspace(-1.0, 1.0, res + 1))
    d = cube_v / np.linalg.norm(cube_v, axis=1, keepdims=True)
    q = np.abs(d / axes)
    f = (q[:, 0] ** (2 / e2) + q[:, 1] ** (2 / e2)) ** (e2 / e1) + q[:, 2] ** (2 / e1)
    return _finish(d * f[:, None] ** (-e1 / 2), faces)


def _blob(rng: np.random.Generator, params: dict) -> trimesh.Trimesh:
    """Sphere displaced along its normal by seeded low-frequency noise, ``r(d) = 1 + A n(d)``.

    ``n`` is a sum of plane waves ``sin(f_i (w_i . d) + phi_i)`` with random unit ``w_i``,
    frequencies ``f_i`` in [1, 3] and weights normalised so that ``|n| <= 1``: with ``A < 1`` the
    radius stays positive, the surface star-shaped, watertight and outward.
    """
    _check_params("blob", params, ("amplitude", "terms", "subdivisions"))
    amp = _param(params, "amplitude", 0.25, 0.0, 0.9, "blob")
    terms = int(_param(params, "terms", 6, 1, 64, "blob"))
    sub = int(_param(params, "subdivisions", 4, 1, 6, "blob"))
    w = rng.standard_normal((terms, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    freq = rng.uniform(1.0, 3.0, terms)
    phase = rng.uniform(0.0, 2 * np.pi, terms)
    weight = rng.uniform(0.5, 1.0, terms)
    weight /= weight.sum()
    ico = trimesh.creation.icosphere(subdivisions=sub, radius=1.0)
    d = np.asarray(ico.vertices)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    noise = np.sin((d @ w.T) * freq + phase) @ weight
    return _finish(d * (1.0 + amp * noise)[:, None], np.asarray(ico.faces))


def _bevel_box(rng: np.random.Generator, params: dict) -> trimesh.Trimesh:
    """Box with rounded (bevelled) edges and corners: the inner box grown by a ball of radius r.

    A gridded box surface is mapped by ``p -> clamp(p, inner) + r * normalise(p - clamp(p, inner))``;
    the grid has ``bevel_sections`` rows inside each bevel band so the rounding is resolved.
    """
    _check_params("bevel_box", params, ("x", "y", "z", "bevel", "sections", "bevel_sections"))
    half = np.array([_param(params, k, rng.uniform(0.5, 1.0), 0.05, 10.0, "bevel_box") for k in ("x", "y", "z")])
    bevel = _param(params, "bevel", 0.15, 0.01, 0.5, "bevel_box")  # fraction of the smallest half extent
    sections = int(_param(params, "sections", 8, 1, 256, "bevel_box"))
    bevel_sections = int(_param(params, "bevel_sections", 4, 1, 64, "bevel_box"))
    r = bevel * half.min()
    inner = half - r
    # Symbolic grid coordinate s per axis on the cube |s| <= 2: |s| <= 1 is the flat part of a
    # face (scaled by the inner half extent), 1 < |s| <= 2 the bevel band (b = sign(s)(|s| - 1)).
    t = np.sin(np.linspace(0.0, np.pi / 2, bevel_sections + 1))[1:]
    coords = np.unique(np.concatenate([np.linspace(-1.0, 1.0, 2 * sections + 1), -1.0 - t, 1.0 + t]))
    cube_v, faces = _cube_grid(coords / 2.0)
    s = 2.0 * cube_v
    band = np.sign(s) * np.clip(np.abs(s) - 1.0, 0.0, 1.0)  # one entry is +-1 (the face's axis)
    p = np.clip(s, -1.0, 1.0) * inner + r * band / np.linalg.norm(band, axis=1, keepdims=True)
    return _finish(p, faces)


_SHAPES = {
    "sphere": _sphere,
    "torus": _torus,
    "superquadric": _superquadric,
    "blob": _blob,
    "bevel_box": _bevel_box,
}


def procedural(shape: str, *, seed: int = 0, **params: Any) -> trimesh.Trimesh:
    """Build a procedural test shape: watertight, outward-facing, unit diameter, centred at the origin.

    Parameters not given are drawn from ``seed`` (same seed, same mesh, bit for bit):

    - ``sphere``: ``subdivisions`` (4: 2562 vertices); the seed is unused.
    - ``torus``: ``minor`` (tube/ring radius ratio, random in [0.2, 0.5]), ``major_sections`` (64),
      ``minor_sections`` (32).
    - ``superquadric``: exponents ``e1``, ``e2`` (random in [0.3, 1.5]), axes ``a``, ``b``, ``c``
      (random in [0.6, 1]), ``resolution`` (24 quads per cube edge).
    - ``blob``: ``amplitude`` (0.25), ``terms`` (6), ``subdivisions`` (4); the noise is seeded.
    - ``bevel_box``: half extents ``x``, ``y``, ``z`` (random in [0.5, 1]), ``bevel`` (0.15 of the
      smallest half extent), ``sections`` (8), ``bevel_sections`` (4).

    Args:
        shape: one of :data:`PROCEDURAL_SHAPES`.
        seed: seed of the shape's random parameters.
        **params: shape parameters (see above).

    Returns:
        A mesh with cached vertex normals.

    Raises:
        ValueError: unknown shape or parameter (listing the valid ones), or a value out of range.
    """
    _require_trimesh()
    if shape not in _SHAPES:
        raise ValueError(f"unknown procedural shape {shape!r}; valid: {list(PROCEDURAL_SHAPES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng([int(seed), PROCEDURAL_SHAPES.index(shape)])
    return _SHAPES[shape](rng, params)


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
    _require_trimesh()
    builtin = parse_builtin(str(path_or_builtin)) if isinstance(path_or_builtin, str) else None
    if builtin is not None:
        shape, params = builtin
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


def diameter(mesh: trimesh.Trimesh) -> float:
    """Twice the largest distance of a vertex from the bounding-box centre, in mesh units."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    return 2.0 * float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))


def normalize(mesh: trimesh.Trimesh, *, diameter: float = 1.0) -> trimesh.Trimesh:
    """Return a copy centred at its bounding-box centre and scaled to the given :func:`diameter`.

    Raises:
        ValueError: ``diameter <= 0`` or a mesh whose vertices all coincide.
    """
    if not diameter > 0:
        raise ValueError(f"diameter must be > 0, got {diameter}")
    out = mesh.copy()
    v = np.asarray(out.vertices, dtype=np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    radius = float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))
    if not radius > 0:
        raise ValueError("cannot normalise a mesh whose vertices all coincide")
    out.vertices = (v - centre) * (diameter / (2.0 * radius))
    return out


def _has_uv(mesh: trimesh.Trimesh) -> bool:
    uv = getattr(mesh.visual, "uv", None)
    return uv is not None and len(uv) == len(mesh.vertices)


def ensure_uv(mesh: trimesh.Trimesh, *, force: bool = False) -> trimesh.Trimesh:
    """Return the mesh with per-vertex UVs, unwrapping it with xatlas when it has none.

    xatlas splits vertices along chart seams; positions and vertex normals are copied to the
    split vertices, so shading is unchanged. UVs lie in [0, 1] (OpenGL convention, v up).
    Cost: about 0.4 s for a 5k-face blob (chart building dominates; xatlas options do not change it
    much), growing roughly linearly with the face count: decimate large assets first.

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
