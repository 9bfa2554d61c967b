"""Shapes the shipped model never saw: concave, sharp-edged, thin and multi-part meshes.

The test split ``test-meshes`` draws its objects from these (``builtin:<shape>`` references, as
for :mod:`.procedural`); training splits use :data:`.procedural.PROCEDURAL_SHAPES` only. Every
shape is closed, consistently oriented outward (positive signed volume, per part) and
normalised to unit diameter.

==============  ==========================================================================
shape           what it tests
==============  ==========================================================================
``torus_knot``  a (2, 3) knot tube: self-occlusion, strongly curved, genus 1
``vase``        a cup revolved from a closed profile: an open cavity (concave inside)
``gear``        an extruded 12-tooth gear: sharp edges, flat faces, small features
``l_block``     an extruded L: a reflex (concave) edge and large flat faces
``dumbbell``    two spheres and a box, not touching: several parts in one object
``thin_plate``  a disc 4 % as thick as it is wide: thin, grazing silhouettes
==============  ==========================================================================
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .procedural import normalize, require_trimesh

try:
    import trimesh
except ModuleNotFoundError:  # pragma: no cover - trimesh is a dependency of the scene side
    trimesh = None

__all__ = ["UNSEEN_SHAPES", "unseen_shape"]

#: Shapes :func:`unseen_shape` builds.
UNSEEN_SHAPES = ("torus_knot", "vase", "gear", "l_block", "dumbbell", "thin_plate")


def _orient(vertices: NDArray, faces: NDArray) -> NDArray:
    """Flip all faces when the closed mesh's signed volume is negative (inward winding)."""
    tri = vertices[faces]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    return faces if volume > 0 else faces[:, ::-1].copy()


def _ring_quads(rows: int, cols: int, *, wrap_rows: bool) -> NDArray:
    """Triangles of a ``rows x cols`` vertex grid wrapped along columns (and rows if asked)."""
    r = np.arange(rows if wrap_rows else rows - 1)
    c = np.arange(cols)
    rr, cc = np.meshgrid(r, c, indexing="ij")
    a = rr * cols + cc
    b = ((rr + 1) % rows) * cols + cc
    d = rr * cols + (cc + 1) % cols
    e = ((rr + 1) % rows) * cols + (cc + 1) % cols
    return np.concatenate([np.stack([a, b, e], -1).reshape(-1, 3), np.stack([a, e, d], -1).reshape(-1, 3)])


def _torus_knot(p: int = 2, q: int = 3, *, tube: float = 0.18, n: int = 384, m: int = 20) -> tuple[NDArray, NDArray]:
    t = np.arange(n) * (2 * np.pi / n)
    r = 1.0 + 0.45 * np.cos(q * t)
    curve = np.stack([r * np.cos(p * t), r * np.sin(p * t), 0.45 * np.sin(q * t)], -1)
    tangent = np.roll(curve, -1, 0) - np.roll(curve, 1, 0)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    # Parallel transport of a normal along the closed curve (no Frenet flips), then a twist
    # correction so the frame closes up exactly.
    normal = np.empty_like(curve)
    seed = np.cross(tangent[0], [0.0, 0.0, 1.0])
    normal[0] = seed / np.linalg.norm(seed)
    for i in range(1, n):
        v = normal[i - 1] - tangent[i] * (normal[i - 1] @ tangent[i])
        normal[i] = v / np.linalg.norm(v)
    end = normal[-1] - tangent[0] * (normal[-1] @ tangent[0])
    end /= np.linalg.norm(end)
    twist = np.arctan2(np.cross(end, normal[0]) @ tangent[0], end @ normal[0])
    binormal = np.cross(tangent, normal)
    angle = twist * np.arange(n) / n
    normal, binormal = (
        np.cos(angle)[:, None] * normal + np.sin(angle)[:, None] * binormal,
        -np.sin(angle)[:, None] * normal + np.cos(angle)[:, None] * binormal,
    )
    phi = np.arange(m) * (2 * np.pi / m)
    offset = tube * (np.cos(phi)[None, :, None] * normal[:, None] + np.sin(phi)[None, :, None] * binormal[:, None])
    vertices = (curve[:, None] + offset).reshape(-1, 3)
    return vertices, _ring_quads(n, m, wrap_rows=True)


def _revolve(profile: NDArray, sections: int = 96) -> tuple[NDArray, NDArray]:
    """Closed surface of revolution about z of a profile ``(K, 2)`` of ``(r, z)`` from axis to axis."""
    inner = profile[1:-1]
    phi = np.arange(sections) * (2 * np.pi / sections)
    ring = np.stack(
        [inner[:, None, 0] * np.cos(phi), inner[:, None, 0] * np.sin(phi), np.repeat(inner[:, None, 1], sections, 1)],
        -1,
    ).reshape(-1, 3)
    bottom, top = len(ring), len(ring) + 1
    vertices = np.concatenate([ring, [[0.0, 0.0, profile[0, 1]]], [[0.0, 0.0, profile[-1, 1]]]])
    faces = [_ring_quads(len(inner), sections, wrap_rows=False)]
    c = np.arange(sections)
    faces.append(np.stack([np.full(sections, bottom), c, (c + 1) % sections], -1))
    last = (len(inner) - 1) * sections
    faces.append(np.stack([np.full(sections, top), last + (c + 1) % sections, last + c], -1))
    return vertices, np.concatenate(faces)


def _vase() -> tuple[NDArray, NDArray]:
    # Outer wall up from the bottom centre, over the rim, inner wall down to the inner bottom.
    z = np.linspace(0.0, 1.0, 24)
    outer = 0.32 + 0.12 * np.sin(np.pi * (0.2 + 1.3 * z))
    rim = [(outer[-1] - 0.02, 1.02), (outer[-1] - 0.06, 1.0)]
    zi = np.linspace(1.0, 0.12, 20)
    inner_r = np.interp(zi, z, outer) - 0.06
    profile = np.concatenate(
        [[[0.0, 0.0]], np.stack([outer, z], -1), rim, np.stack([inner_r, zi], -1)[1:], [[0.0, 0.12]]]
    )
    return _revolve(profile)


def _extrude_star(polygon: NDArray, centre: NDArray, height: float) -> tuple[NDArray, NDArray]:
    """Prism of a polygon ``(K, 2)`` star-shaped around ``centre``: fan caps plus side quads."""
    k = len(polygon)
    bottom = np.concatenate([polygon, np.zeros((k, 1))], 1)
    top = bottom + [0.0, 0.0, height]
    vertices = np.concatenate([bottom, top, [[*centre, 0.0], [*centre, height]]])
    i = np.arange(k)
    j = (i + 1) % k
    faces = np.concatenate(
        [
            np.stack([np.full(k, 2 * k), j, i], -1),  # bottom cap
            np.stack([np.full(k, 2 * k + 1), k + i, k + j], -1),  # top cap
            np.stack([i, j, k + j], -1),
            np.stack([i, k + j, k + i], -1),
        ]
    )
    return vertices, faces


def _gear(teeth: int = 12) -> tuple[NDArray, NDArray]:
    angles, radii = [], []
    step = 2 * np.pi / teeth
    for t in range(teeth):
        a = t * step
        angles += [a, a + 0.15 * step, a + 0.35 * step, a + 0.5 * step]
        radii += [0.8, 1.0, 1.0, 0.8]
    angles, radii = np.array(angles), np.array(radii)
    polygon = np.stack([radii * np.cos(angles), radii * np.sin(angles)], -1)
    return _extrude_star(polygon, np.zeros(2), 0.35)


def _l_block() -> tuple[NDArray, NDArray]:
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 0.8], [0.8, 0.8], [0.8, 2.0], [0.0, 2.0]])
    return _extrude_star(polygon, np.array([0.4, 0.4]), 0.7)


def _dumbbell() -> tuple[NDArray, NDArray]:
    parts = [
        trimesh.creation.icosphere(subdivisions=3, radius=0.35).apply_translation([-0.6, 0.0, 0.0]),
        trimesh.creation.icosphere(subdivisions=3, radius=0.25).apply_translation([0.55, 0.0, 0.0]),
        trimesh.creation.box(extents=(0.3, 0.3, 0.3)).apply_translation([0.0, 0.45, 0.0]),
    ]
    vertices, faces, offset = [], [], 0
    for part in parts:
        vertices.append(np.asarray(part.vertices))
        faces.append(np.asarray(part.faces) + offset)
        offset += len(part.vertices)
    return np.concatenate(vertices), np.concatenate(faces)


def _thin_plate(sections: int = 96) -> tuple[NDArray, NDArray]:
    phi = np.arange(sections) * (2 * np.pi / sections)
    polygon = np.stack([np.cos(phi), np.sin(phi)], -1)
    return _extrude_star(polygon, np.zeros(2), 0.08)


_BUILDERS = {
    "torus_knot": _torus_knot,
    "vase": _vase,
    "gear": _gear,
    "l_block": _l_block,
    "dumbbell": _dumbbell,
    "thin_plate": _thin_plate,
}


def unseen_shape(shape: str) -> trimesh.Trimesh:
    """Build one of :data:`UNSEEN_SHAPES`: closed, outward-facing, unit diameter, centred.

    Args:
        shape: the shape's name.

    Returns:
        A mesh with cached vertex normals (deterministic: no random parameters).

    Raises:
        ValueError: unknown shape (the message lists the valid ones).

    Example:
        >>> mesh = unseen_shape("gear")
        >>> bool(mesh.is_watertight), bool(mesh.volume > 0)
        (True, True)
    """
    require_trimesh()
    if shape not in _BUILDERS:
        raise ValueError(f"unknown unseen shape {shape!r}; valid: {list(UNSEEN_SHAPES)}")
    vertices, faces = _BUILDERS[shape]()
    vertices = np.asarray(vertices, dtype=np.float64)
    if shape != "dumbbell":  # each dumbbell part is outward already; one global test would not do
        faces = _orient(vertices, np.asarray(faces))
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
    mesh = normalize(mesh)
    _ = mesh.vertex_normals
    return mesh
