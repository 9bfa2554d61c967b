"""Procedural test shapes built in code, and the size convention every mesh is normalised to.

:func:`procedural` builds a seeded set of watertight, outward-facing shapes (spheres, tori,
superquadrics, displaced blobs, bevelled boxes) at unit :func:`diameter`, centred at the origin:
the objects of synthetic scenes when no asset folder is given. A scene spec refers to them as
``builtin:<shape>[?key=value&...]`` (:func:`.assets.parse_builtin`, :func:`.assets.load_mesh`).

Convention (size):
    A mesh's *diameter* is twice the largest distance of a vertex from the centre of its
    axis-aligned bounding box (:func:`diameter`); :func:`normalize` and :func:`.placement.place` use
    it. It bounds the minimal enclosing sphere from above, so a normalised mesh fits in a unit
    sphere. Example: the unit cube ``[0, 1]^3`` has diameter ``sqrt(3) = 1.732``.

trimesh is needed to build shapes; without it this module still imports (:func:`diameter` and
:func:`normalize` work on any object with ``vertices`` and ``copy()``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

try:
    import trimesh
except ModuleNotFoundError:  # Blender's Python: specs, placement and PLY output work without it
    trimesh = None

__all__ = [
    "PROCEDURAL_SHAPES",
    "diameter",
    "normalize",
    "procedural",
    "require_trimesh",
]

#: Shapes :func:`procedural` builds.
PROCEDURAL_SHAPES = ("sphere", "torus", "superquadric", "blob", "bevel_box")


def diameter(mesh: trimesh.Trimesh) -> float:
    """Twice the largest distance of a vertex from the bounding-box centre.

    Args:
        mesh: a mesh (anything with ``vertices (N, 3)``).

    Returns:
        The diameter in mesh units.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    return 2.0 * float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))


def normalize(mesh: trimesh.Trimesh, *, diameter: float = 1.0) -> trimesh.Trimesh:
    """Return a copy centred at its bounding-box centre and scaled to the given :func:`diameter`.

    Args:
        mesh: a mesh (anything with ``vertices (N, 3)`` and ``copy()``); left unchanged.
        diameter: the diameter of the copy, in mesh units.

    Returns:
        The scaled copy.

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


def require_trimesh() -> None:
    """Raise ModuleNotFoundError (naming the package and how to install it) when trimesh is missing."""
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


def _check_params(shape: str, params: dict, valid: tuple[str, ...], kind: str = "procedural") -> None:
    """Refuse parameters a ``kind`` shape (procedural, generated) does not take, naming the valid ones."""
    unknown = set(params) - set(valid)
    if unknown:
        raise ValueError(f"unknown parameters {sorted(unknown)} for {kind} shape {shape!r}; valid: {list(valid)}")


def _param(params: dict, key: str, default: Any, lo: float, hi: float, shape: str) -> float:
    """``params[key]`` (else ``default``) as a float in ``[lo, hi]``; one-line errors name the shape."""
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
    require_trimesh()
    if shape not in _SHAPES:
        raise ValueError(f"unknown procedural shape {shape!r}; valid: {list(PROCEDURAL_SHAPES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng([int(seed), PROCEDURAL_SHAPES.index(shape)])
    return _SHAPES[shape](rng, params)
