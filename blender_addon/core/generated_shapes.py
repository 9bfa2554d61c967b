"""Seeded training shapes the procedural set lacks: sharp edges, concavities, thin walls, several parts.

Like :mod:`.procedural`, every shape is built from a seed (same seed, same mesh), is closed
(watertight), wound outward (positive signed volume, per part), free of degenerate faces and
normalised to unit :func:`~.procedural.diameter`, centred on its bounding box. Vertices are merged,
so sharp edges share their vertices; splitting normals at creases is the loader's business.
A scene spec refers to them as ``builtin:<shape>?seed=N[&key=value...]``.

They are training shapes: none of them is one of the held-out :data:`.unseen_shapes.UNSEEN_SHAPES`.

===================  =====================================================================
shape                what it adds to the training set
===================  =====================================================================
``heightfield_slab`` a slab with a smooth random top, flat bottom, vertical sides: 90-degree edges
``extrusion``        a random star polygon extruded (optionally tapered): reflex edges, flat caps
``multipart``        2-4 separate boxes, spheres and cylinders: several connected components
``bowl``             a spherical-cap shell 3-8 % of the diameter thick, rim closed: thin, concave
===================  =====================================================================
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .procedural import _check_params as _procedural_check_params
from .procedural import _param, normalize, require_trimesh

try:
    import trimesh
except ModuleNotFoundError:  # pragma: no cover - trimesh is a dependency of the scene side
    trimesh = None

__all__ = ["GENERATED_SHAPES", "generated_shape"]

#: Shapes :func:`generated_shape` builds.
GENERATED_SHAPES = ("heightfield_slab", "extrusion", "multipart", "bowl")


def _check_params(shape: str, params: dict, valid: tuple[str, ...]) -> None:
    _procedural_check_params(shape, params, valid, kind="generated")


def _signed_volume(vertices: NDArray, faces: NDArray) -> float:
    tri = vertices[faces]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def _outward(vertices: NDArray, faces: NDArray) -> NDArray:
    """Faces of one closed, consistently wound part, flipped when its signed volume is negative."""
    return faces if _signed_volume(vertices, faces) > 0 else faces[:, ::-1].copy()


def _cross2(a: NDArray, b: NDArray) -> NDArray:
    """z-component of the cross product of 2-D vectors (rows)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _ring_strip(a: NDArray, b: NDArray) -> NDArray:
    """Triangles joining two closed vertex rings ``a`` and ``b`` of equal length (index arrays)."""
    a1, b1 = np.roll(a, -1), np.roll(b, -1)
    return np.concatenate([np.stack([a, a1, b1], -1), np.stack([a, b1, b], -1)])


def _heightfield_slab(rng: np.random.Generator, params: dict) -> tuple[NDArray, NDArray]:
    """Slab over ``[-1, 1] x [-w, w]``: top ``z = base + h(x, y)``, bottom ``z = 0``, vertical sides.

    ``h`` is a sum of ``bumps`` Gaussians of random sign, centre and width plus one plane wave,
    scaled to ``max |h| = amplitude``; ``base = amplitude + thickness`` keeps the slab at least
    ``thickness`` thick. The top is a grid; the bottom a fan from its centre (a convex rectangle).
    """
    shape = "heightfield_slab"
    _check_params(shape, params, ("width", "amplitude", "thickness", "bumps", "resolution"))
    width = _param(params, "width", rng.uniform(0.5, 1.0), 0.1, 1.0, shape)
    amplitude = _param(params, "amplitude", rng.uniform(0.1, 0.3), 0.0, 1.0, shape)
    thickness = _param(params, "thickness", rng.uniform(0.08, 0.25), 0.02, 2.0, shape)
    bumps = int(_param(params, "bumps", rng.integers(2, 7), 1, 32, shape))
    res = int(_param(params, "resolution", 48, 2, 512, shape))
    centres = rng.uniform(-1.0, 1.0, (bumps, 2)) * [1.0, width]
    sigma = rng.uniform(0.15, 0.5, bumps)
    weight = rng.uniform(0.3, 1.0, bumps) * rng.choice([-1.0, 1.0], bumps)
    direction = rng.standard_normal(2)
    direction /= np.linalg.norm(direction)
    freq, phase, wave = rng.uniform(1.0, 4.0), rng.uniform(0.0, 2 * np.pi), rng.uniform(0.0, 0.5)
    x, y = np.meshgrid(np.linspace(-1.0, 1.0, res + 1), np.linspace(-width, width, res + 1), indexing="ij")
    d2 = (x[..., None] - centres[:, 0]) ** 2 + (y[..., None] - centres[:, 1]) ** 2
    h = (weight * np.exp(-d2 / (2 * sigma**2))).sum(-1) + wave * np.sin(
        freq * (direction[0] * x + direction[1] * y) + phase
    )
    peak = np.abs(h).max()
    h = h * (amplitude / peak) if peak > 0 else h
    top = np.stack([x, y, amplitude + thickness + h], -1).reshape(-1, 3)
    n = res + 1
    idx = np.arange(n * n).reshape(n, n)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    top_faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    # Boundary of the grid, counter-clockwise seen from +z: (x up, y fixed) edges, then around.
    ring = np.concatenate([idx[:-1, 0], idx[-1, :-1], idx[:0:-1, -1], idx[0, :0:-1]])
    bottom = top[ring] * [1.0, 1.0, 0.0]
    b0 = len(top)
    centre = len(top) + len(ring)
    vertices = np.concatenate([top, bottom, [[0.0, 0.0, 0.0]]])
    b = b0 + np.arange(len(ring))
    faces = np.concatenate(
        [top_faces, _ring_strip(b, ring), np.stack([np.full(len(b), centre), np.roll(b, -1), b], -1)]
    )
    return vertices, _outward(vertices, faces)


def _extrusion(rng: np.random.Generator, params: dict) -> tuple[NDArray, NDArray]:
    """A star polygon of ``points`` spikes extruded to ``height``, its top scaled by ``taper``.

    Corners alternate, at jittered angles, between an outer radius in [0.75, 1] and an inner one
    about ``inner`` times the reach of the chord between its outer neighbours, so the polygon is
    star-shaped about the origin with a reflex (concave) corner at every inner corner; both caps
    are fans from their centre (valid for a star-shaped polygon).
    """
    shape = "extrusion"
    _check_params(shape, params, ("points", "inner", "height", "taper"))
    points = int(_param(params, "points", rng.integers(3, 8), 3, 64, shape))
    inner = _param(params, "inner", rng.uniform(0.35, 0.8), 0.05, 0.95, shape)
    height = _param(params, "height", rng.uniform(0.25, 1.0), 0.02, 10.0, shape)
    taper = _param(params, "taper", rng.uniform(0.6, 1.0), 0.05, 1.0, shape)
    k = 2 * points
    step = 2 * np.pi / k
    angles = np.arange(k) * step + rng.uniform(-0.25, 0.25, k) * step
    outer = rng.uniform(0.75, 1.0, points)
    corner = outer[:, None] * np.stack([np.cos(angles[0::2]), np.sin(angles[0::2])], -1)
    chord = np.roll(corner, -1, axis=0) - corner
    ray = np.stack([np.cos(angles[1::2]), np.sin(angles[1::2])], -1)
    # Distance from the origin, along each inner corner's ray, to the chord of its outer neighbours:
    # an inner corner below it is a reflex corner.
    reach = _cross2(corner, np.roll(corner, -1, axis=0)) / _cross2(ray, chord)
    radii = np.empty(k)
    radii[0::2] = outer
    radii[1::2] = inner * reach * rng.uniform(0.85, 1.0, points)
    polygon = np.stack([radii * np.cos(angles), radii * np.sin(angles)], -1)
    bottom = np.concatenate([polygon, np.zeros((k, 1))], 1)
    top = np.concatenate([taper * polygon, np.full((k, 1), height)], 1)
    vertices = np.concatenate([bottom, top, [[0.0, 0.0, 0.0], [0.0, 0.0, height]]])
    i = np.arange(k)
    faces = np.concatenate(
        [
            np.stack([np.full(k, 2 * k), np.roll(i, -1), i], -1),  # bottom cap, seen from -z
            np.stack([np.full(k, 2 * k + 1), k + i, k + np.roll(i, -1)], -1),  # top cap
            _ring_strip(i, k + i),
        ]
    )
    return vertices, _outward(vertices, faces)


def _multipart(rng: np.random.Generator, params: dict) -> tuple[NDArray, NDArray]:
    """``parts`` boxes, spheres and cylinders at random poses, their bounding spheres ``gap`` apart.

    Each part is placed by rejection in a cube of side 3; a part that finds no free place there
    in 100 draws goes beside all earlier parts along +x.
    """
    shape = "multipart"
    _check_params(shape, params, ("parts", "gap"))
    count = int(_param(params, "parts", rng.integers(2, 5), 2, 8, shape))
    gap = _param(params, "gap", 0.1, 0.01, 1.0, shape)
    vertices: list[NDArray] = []
    faces: list[NDArray] = []
    spheres: list[tuple[NDArray, float]] = []
    offset = 0
    for _ in range(count):
        kind = int(rng.integers(3))
        size = rng.uniform(0.3, 0.8, 3)
        if kind == 0:
            part = trimesh.creation.box(extents=size)
        elif kind == 1:
            part = trimesh.creation.icosphere(subdivisions=3, radius=size[0] / 2)
        else:
            part = trimesh.creation.cylinder(radius=size[0] / 2, height=size[1], sections=32)
        rotation = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        v = np.asarray(part.vertices) @ rotation.T
        if np.linalg.det(rotation) < 0:  # a reflection would turn the part inside out
            v = -v
        radius = float(np.linalg.norm(v, axis=1).max())
        for _ in range(100):
            centre = rng.uniform(-1.5, 1.5, 3)
            if all(np.linalg.norm(centre - c) > radius + r + gap for c, r in spheres):
                break
        else:  # no free place drawn: beside all parts along +x, which is free
            centre = np.array([max(c[0] + r for c, r in spheres) + radius + gap, 0.0, 0.0])
        spheres.append((centre, radius))
        vertices.append(v + centre)
        faces.append(np.asarray(part.faces) + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def _bowl(rng: np.random.Generator, params: dict) -> tuple[NDArray, NDArray]:
    """Spherical-cap shell: polar angles up to ``opening`` degrees from the bottom pole, closed rim.

    The outer cap has radius 1; the inner one ``1 - t`` where ``t = thickness`` times the
    shape's diameter (which the outer cap alone sets), so after normalisation the wall is
    ``thickness`` thick. The rim is a flat radial band: the solid is an exact spherical-sector shell.
    """
    shape = "bowl"
    _check_params(shape, params, ("thickness", "opening", "rings", "sections"))
    frac = _param(params, "thickness", rng.uniform(0.03, 0.08), 0.005, 0.2, shape)
    opening = np.radians(_param(params, "opening", rng.uniform(60.0, 110.0), 20.0, 150.0, shape))
    rings = int(_param(params, "rings", 24, 2, 256, shape))
    sections = int(_param(params, "sections", 64, 6, 1024, shape))
    phi = np.linspace(0.0, opening, rings + 1)[1:]  # polar angle from the -z pole, pole excluded
    psi = np.arange(sections) * (2 * np.pi / sections)

    def cap(radius: float) -> NDArray:
        ring = np.stack(
            [
                np.sin(phi)[:, None] * np.cos(psi),
                np.sin(phi)[:, None] * np.sin(psi),
                np.repeat(-np.cos(phi)[:, None], sections, 1),
            ],
            -1,
        )
        return radius * ring.reshape(-1, 3)

    outer = cap(1.0)
    extent = 2.0 * np.sqrt(np.max(np.sum((outer - (outer.min(0) + outer.max(0)) / 2) ** 2, axis=1)))
    t = frac * extent
    if not t < 0.5:
        raise ValueError(f"{shape}: thickness {frac} is too large for opening {np.degrees(opening):.1f}")
    inner = cap(1.0 - t)
    n = rings * sections
    vertices = np.concatenate([outer, inner, [[0.0, 0.0, -1.0], [0.0, 0.0, -(1.0 - t)]]])
    rows = np.arange(rings)[:, None] * sections + np.arange(sections)
    faces = [_ring_strip(rows[r], rows[r + 1]) for r in range(rings - 1)]  # outer wall
    faces += [_ring_strip(n + rows[r + 1], n + rows[r]) for r in range(rings - 1)]  # inner wall, reversed
    faces.append(_ring_strip(rows[-1], n + rows[-1]))  # rim band
    c = np.arange(sections)
    faces.append(np.stack([np.full(sections, 2 * n), np.roll(c, -1), c], -1))  # outer pole fan
    faces.append(np.stack([np.full(sections, 2 * n + 1), n + c, n + np.roll(c, -1)], -1))  # inner pole fan
    faces = np.concatenate(faces)
    return vertices, _outward(vertices, faces)


_BUILDERS = {
    "heightfield_slab": _heightfield_slab,
    "extrusion": _extrusion,
    "multipart": _multipart,
    "bowl": _bowl,
}


def generated_shape(name: str, seed: int = 0, **params: Any) -> trimesh.Trimesh:
    """Build a generated training shape: watertight, outward, unit diameter, centred, vertices merged.

    Parameters not given are drawn from ``seed`` (same seed, same mesh):

    - ``heightfield_slab``: ``width`` (half depth over half length, random in [0.5, 1]),
      ``amplitude`` of the height field (random in [0.1, 0.3]), minimum ``thickness`` (random in
      [0.08, 0.25]), ``bumps`` (Gaussians, 2-6), ``resolution`` (48 quads per side of the top);
      lengths relative to the half length 1 before normalisation.
    - ``extrusion``: ``points`` of the star (3-7), ``inner`` radius ratio (random in [0.35, 0.8]),
      ``height`` (random in [0.25, 1] of the outer radius), ``taper`` of the top (random in [0.6, 1]).
    - ``multipart``: ``parts`` (2-4), ``gap`` between their bounding spheres (0.1 before
      normalisation).
    - ``bowl``: wall ``thickness`` as a fraction of the diameter (random in [0.03, 0.08]),
      ``opening`` polar angle in degrees (random in [60, 110]), ``rings`` (24), ``sections`` (64).

    Args:
        name: one of :data:`GENERATED_SHAPES`.
        seed: seed of the shape's random parameters.
        **params: shape parameters (see above).

    Returns:
        A mesh with cached vertex normals.

    Raises:
        ValueError: unknown shape or parameter (listing the valid ones), a value out of range, or a
            negative seed.

    Example:
        >>> mesh = generated_shape("extrusion", seed=2)
        >>> bool(mesh.is_watertight), bool(mesh.volume > 0)
        (True, True)
    """
    require_trimesh()
    if name not in _BUILDERS:
        raise ValueError(f"unknown generated shape {name!r}; valid: {list(GENERATED_SHAPES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng([int(seed), GENERATED_SHAPES.index(name)])
    vertices, faces = _BUILDERS[name](rng, params)
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, dtype=np.float64), faces=faces, process=True)
    mesh = normalize(mesh)
    _ = mesh.vertex_normals
    return mesh
