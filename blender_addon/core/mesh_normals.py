"""Shading normals of triangle meshes: crease-angle corner normals and the split render mesh.

A renderer interpolates one normal per vertex. Smooth surfaces want the normals of the faces
around a vertex averaged; a hard edge (a cube's) wants each side to keep its own face normal, so
the vertex is split. :func:`crease_corner_normals` gives every face corner the angle-weighted
mean of the normals of the faces around its vertex that lie within ``crease_deg`` of its own
face, and :func:`split_by_corner_normals` builds the render mesh: one vertex per distinct
(source vertex, corner normal) pair, sorted by source vertex, so a mesh without hard edges keeps
its vertex order.

Convention:
    Faces are counter-clockwise seen from the front (outside); face normals follow the
    right-hand rule. Vertex adjacency is by a ``weld`` map (vertices at the same position share an
    id), so a UV seam is not mistaken for a hard edge.

>>> import numpy as np
>>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
>>> f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
>>> n = crease_corner_normals(v, f, crease_deg=30.0)  # a tetrahedron: every edge is hard
>>> bool(np.allclose(n[0], [0, 0, -1]))
True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["face_normals", "corner_angles", "crease_corner_normals", "split_by_corner_normals"]

#: Pairs of corners handled at once by :func:`crease_corner_normals` (bounds its memory).
_PAIR_CHUNK = 4_000_000


def face_normals(vertices: ArrayLike, faces: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit face normals and areas of triangles.

    Args:
        vertices: ``(N, 3)`` positions.
        faces: ``(F, 3)`` vertex indices, counter-clockwise from the front.

    Returns:
        ``(normals (F, 3), areas (F,))``; a zero-area face gets the normal ``(0, 0, 0)``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, length[:, None], out=np.zeros_like(cross), where=length[:, None] > 0)
    return normals, 0.5 * length


def corner_angles(vertices: ArrayLike, faces: ArrayLike) -> NDArray[np.float64]:
    """Interior angle (radians) of every face corner, ``(F, 3)``; 0 for coincident vertices."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    out = np.empty(f.shape, dtype=np.float64)
    for k in range(3):
        a = v[f[:, (k + 1) % 3]] - v[f[:, k]]
        b = v[f[:, (k + 2) % 3]] - v[f[:, k]]
        # atan2(|a x b|, a . b) stays accurate for angles near 0 and pi, unlike acos.
        out[:, k] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    return out


def crease_corner_normals(
    vertices: ArrayLike,
    faces: ArrayLike,
    *,
    crease_deg: float = 30.0,
    weld: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Normal of every face corner: the angle-weighted mean of the faces around its vertex within the crease.

    For the corner of face ``f`` at vertex ``v``, every face ``g`` touching ``v`` (by ``weld`` id)
    whose normal is within ``crease_deg`` of ``f``'s contributes its unit normal times its interior
    angle at ``v`` (Thuermer and Wuethrich 1998); ``f`` itself always does, so the result is never
    zero and is within ``crease_deg`` of the face normal. ``crease_deg >= 180`` smooths everything,
    ``0`` gives flat faces.

    Args:
        vertices: ``(N, 3)`` positions.
        faces: ``(F, 3)`` vertex indices, counter-clockwise from the front, no zero-area faces.
        crease_deg: dihedral angle in degrees above which an edge is hard.
        weld: ``(N,)`` id per vertex; vertices with equal ids are one vertex for adjacency (e.g.
            the two sides of a UV seam). Default: the vertex index itself.

    Returns:
        ``(F, 3, 3)`` unit normals per face corner.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn, _ = face_normals(v, f)
    angles = corner_angles(v, f).ravel()
    ids = np.arange(len(v)) if weld is None else np.asarray(weld, dtype=np.int64)
    cv = ids[f].ravel()  # welded vertex of every corner, (3F,)
    cf = np.repeat(np.arange(len(f)), 3)  # face of every corner
    order = np.argsort(cv, kind="stable")
    counts = np.bincount(cv, minlength=int(cv.max()) + 1 if len(cv) else 0)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    deg = counts[cv]  # corners sharing each corner's vertex (itself included)
    cos_crease = np.cos(np.radians(min(max(float(crease_deg), 0.0), 180.0)))
    acc = np.zeros((len(cv), 3))
    # Every (corner, corner at the same vertex) pair, in chunks of corners to bound memory.
    ends = np.cumsum(deg)
    lo = 0
    while lo < len(cv):
        hi = int(np.searchsorted(ends, (ends[lo - 1] if lo else 0) + _PAIR_CHUNK, side="right"))
        hi = max(hi, lo + 1)
        src = np.repeat(np.arange(lo, hi), deg[lo:hi])
        first = np.cumsum(deg[lo:hi]) - deg[lo:hi]
        offs = np.arange(len(src)) - np.repeat(first, deg[lo:hi])
        dst = order[starts[cv[src]] + offs]
        gf, df = cf[src], cf[dst]
        keep = np.einsum("ij,ij->i", fn[gf], fn[df]) >= cos_crease - 1e-12
        keep |= gf == df
        src, df, w = src[keep], df[keep], angles[dst[keep]]
        for k in range(3):
            acc[lo:hi, k] = np.bincount(src - lo, weights=w * fn[df, k], minlength=hi - lo)
        lo = hi
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    # A corner with zero angle (a sliver) contributes nothing; fall back to its face normal.
    out = np.where(norm > 1e-300, acc / np.maximum(norm, 1e-300), fn[cf])
    return out.reshape(len(f), 3, 3)


def split_by_corner_normals(
    faces: ArrayLike,
    corner_normals: ArrayLike,
    *,
    decimals: int = 6,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Render mesh with one vertex per distinct (source vertex, corner normal).

    Args:
        faces: ``(F, 3)`` source vertex indices.
        corner_normals: ``(F, 3, 3)`` unit normal per face corner.
        decimals: normals equal to this many decimals share a vertex.

    Returns:
        ``(source, faces, normals)``: for each render vertex the source vertex index ``(M,)``
        (copy positions and UVs with it), the render faces ``(F, 3)`` and the unit vertex normals
        ``(M, 3)``. Render vertices are sorted by source vertex (copies of a split vertex next to
        each other), so a mesh without splits keeps its vertex order.

    >>> f = np.array([[0, 1, 2], [0, 2, 3]])
    >>> n = np.zeros((2, 3, 3)); n[0, :, 2] = 1; n[1, :, 0] = 1  # a fold along the edge 0-2
    >>> src, rf, rn = split_by_corner_normals(f, n)
    >>> src.tolist(), rf.tolist()
    ([0, 0, 1, 2, 2, 3], [[0, 2, 3], [1, 4, 5]])
    """
    f = np.asarray(faces, dtype=np.int64).ravel()
    n = np.asarray(corner_normals, dtype=np.float64).reshape(-1, 3)
    q = np.round(n, decimals) + 0.0  # + 0.0 turns -0.0 into 0.0 so equal normals compare equal
    keys = np.concatenate([f[:, None].astype(np.float64), q], axis=1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    normals = n[first]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return f[first], inverse.reshape(-1, 3), normals
