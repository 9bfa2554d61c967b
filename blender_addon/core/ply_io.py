"""Binary PLY files Mitsuba 3's ``ply`` plugin loads, from plain arrays (numpy only: the add-on uses it too)."""

from __future__ import annotations

import os

import numpy as np
from numpy.typing import ArrayLike

from pbrdf.io.atomic import atomic_write_bytes

__all__ = ["write_ply_arrays"]


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
