"""Blender meshes from arrays in bulk: positions, faces and UVs, and exact custom vertex normals.

A capture's relief mesh has about 10^6 vertices and 2 x 10^6 triangles. Python lists
(``Mesh.from_pydata``), ``MeshLoop`` writes, ``Mesh.validate`` and
``normals_split_custom_set_from_vertices`` take seconds over that many; the mesh's attributes
(``position``, ``.corner_vert``, the UV map, ``custom_normal``) take numpy buffers in one copy each.
"""

from __future__ import annotations

import bpy
import numpy as np

__all__ = ["mesh_from_arrays", "set_vertex_normals"]


def mesh_from_arrays(name: str, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_name: str):
    """A new mesh of ``faces``, with per-vertex UVs on every corner of the UV map ``uv_name``.

    Not validated (``Mesh.validate`` would take seconds): the caller's faces are valid, i.e. in
    range, with distinct corners and no face twice (what :func:`pbrdf.geometry.relief.relief_mesh`
    builds).

    Args:
        name: the mesh's name.
        vertices: ``(N, 3)`` positions.
        faces: ``(F, k)`` vertex indices, ``k >= 3`` corners per face.
        uvs: ``(N, 2)`` per-vertex UVs.
        uv_name: the UV map's name.

    Returns:
        The ``bpy.types.Mesh`` with its edges computed.
    """
    v = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    f = np.asarray(faces, np.int32)
    corners = np.ascontiguousarray(f.ravel())
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(v))
    mesh.loops.add(len(corners))
    mesh.polygons.add(len(f))
    mesh.attributes["position"].data.foreach_set("vector", v.ravel())
    mesh.polygons.foreach_set("loop_start", np.arange(0, len(corners), f.shape[1], dtype=np.int32))
    mesh.attributes[".corner_vert"].data.foreach_set("value", corners)
    mesh.update(calc_edges=True)
    mesh.uv_layers.new(name=uv_name)
    corner_uvs = np.ascontiguousarray(np.asarray(uvs, np.float32)[corners])
    mesh.attributes[uv_name].data.foreach_set("vector", corner_uvs.ravel())
    return mesh


def set_vertex_normals(mesh, normals: np.ndarray) -> None:
    """Smooth shading with ``normals (N, 3)`` (object frame, renormalised) as the custom normals of the N vertices.

    Stored as Blender's ``custom_normal`` attribute on the points, in float32 (the older
    ``normals_split_custom_set_from_vertices`` encodes each corner's normal in two int16).
    """
    mesh.shade_smooth()
    n = np.asarray(normals, np.float32).reshape(-1, 3)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    mesh.attributes.new("custom_normal", "FLOAT_VECTOR", "POINT").data.foreach_set("vector", n.ravel())
