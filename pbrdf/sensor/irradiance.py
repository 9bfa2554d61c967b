"""Irradiance from the display: constant planar patches and Lambert's polygon formula, horizon-clipped.

The display (flat or curved) is cut into planar patches of constant RGB radiance
(:func:`display_patches`; one rectangle per colour combination for the built-in patterns, a
block-averaged grid for image patterns, chords for a curved display). The irradiance vector of a
uniform planar polygon seen from a point has a closed form (Lambert's polygon formula,
:func:`polygon_irradiance_vectors`):

.. math:: \\Phi = \\tfrac12 \\sum_i \\theta_i \\gamma_i, \\qquad E(n) = L \\, n \\cdot \\Phi

with ``theta_i`` the angle subtended by edge ``i`` and ``gamma_i`` the unit normal of the plane
through the point and that edge. :func:`irradiance_vectors` sums it over the patches per colour
channel, optionally clipping every patch to the part above a surface's horizon first (then
``E`` is exact for that normal). Frames: whatever frame the vertices and points share (the
baseline uses the camera frame of :mod:`pbrdf.sensor.projection`).

References:
    J. H. Lambert, Photometria (1760); J. Arvo, "Applications of irradiance tensors to the
    simulation of non-Lambertian phenomena", SIGGRAPH 1995.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["display_patches", "polygon_irradiance_vectors", "irradiance_vectors", "region_light_directions"]

#: Largest number of constant patches kept from an image pattern before it is block-averaged.
MAX_PATCHES = 256
#: Pattern columns per planar strip on a curved display (each strip is a chord of the cylinder).
STRIP_COLUMNS = 4
#: Points per chunk of the vectorised geometry (bounds the temporary arrays to some tens of MB).
CHUNK = 8192

# --------------------------------------------------------------------------- display geometry


def _block_average(img: NDArray, rows: int, cols: int) -> NDArray:
    """Average ``img (h, w, 3)`` over a ``rows x cols`` grid of (nearly) equal blocks."""
    h, w = img.shape[:2]
    re = np.linspace(0, h, rows + 1).round().astype(int)
    ce = np.linspace(0, w, cols + 1).round().astype(int)
    out = np.zeros((rows, cols, img.shape[2]))
    for i in range(rows):
        for j in range(cols):
            out[i, j] = img[re[i] : re[i + 1], ce[j] : ce[j + 1]].reshape(-1, img.shape[2]).mean(0)
    return out


def _constant_rectangles(img: NDArray) -> list[tuple[int, int, int, int, tuple[float, ...]]]:
    """Rectangles ``(r0, r1, c0, c1, rgb)`` of one non-zero colour that tile the lit part of ``img``.

    Runs of equal colour along each row, merged with the identical runs of the following rows.
    """
    h, w = img.shape[:2]
    rects: list[tuple[int, int, int, int, tuple[float, ...]]] = []
    open_: dict[tuple, int] = {}
    for r in range(h):
        row = img[r]
        change = np.flatnonzero(np.any(row[1:] != row[:-1], axis=-1)) + 1
        starts, ends = np.concatenate([[0], change]), np.concatenate([change, [w]])
        runs = {(int(a), int(b), tuple(float(v) for v in row[a])) for a, b in zip(starts, ends, strict=True)}
        nxt = {run: open_.pop(run, r) for run in runs if any(v > 0 for v in run[2])}
        rects += [(r0, r, a, b, rgb) for (a, b, rgb), r0 in open_.items()]
        open_ = nxt
    rects += [(r0, h, a, b, rgb) for (a, b, rgb), r0 in open_.items()]
    return sorted(rects)


def display_patches(display, *, max_patches: int = MAX_PATCHES) -> tuple[NDArray, NDArray]:
    """The lit display as planar patches of constant radiance, in world coordinates.

    Built-in patterns give one rectangle per colour combination (``rgb_halves``: magenta and cyan
    upper quadrants, red and green lower ones). An image pattern is block-averaged to at most 36 x
    64 cells, and coarser when it has more than ``max_patches`` constant rectangles. On a curved
    display every rectangle is cut into strips of :data:`STRIP_COLUMNS` pattern columns whose
    corners lie on the cylinder.

    Args:
        display: a :class:`pbrdf.sensor.rig.DisplaySpec`.
        max_patches: largest number of patches kept from an image pattern.

    Returns:
        ``(vertices (Q, 4, 3), radiance (Q, 3))``: corners counter-clockwise as seen from the
        front (from the objects), and the emitted radiance ``s0`` per colour channel (pattern
        value times ``display.radiance``).

    Example:
        >>> from pbrdf.sensor.rig import DisplaySpec
        >>> verts, radiance = display_patches(DisplaySpec())
        >>> verts.shape, radiance.tolist()
        ((4, 4, 3), [[0.0, 1.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    """
    img = np.asarray(display.pattern_image(), dtype=np.float64)
    h, w = img.shape[:2]
    if h > 36 or w > 64:
        img = _block_average(img, min(h, 36), min(w, 64))
        h, w = img.shape[:2]
    rects = _constant_rectangles(img)
    if len(rects) > max_patches:
        side = max(1, int(np.sqrt(max_patches / (16 * 9))))
        img = _block_average(img, min(h, 9 * side), min(w, 16 * side))
        h, w = img.shape[:2]
        rects = _constant_rectangles(img)
    xy, rad = [], []
    step = w if display.curvature_radius is None else STRIP_COLUMNS
    for r0, r1, c0, c1, rgb in rects:
        y_top = display.height / 2 - display.height * r0 / h  # pattern row 0 is the top
        y_bot = display.height / 2 - display.height * r1 / h
        for a in range(c0, c1, step):
            b = min(a + step, c1)
            x0 = -display.width / 2 + display.width * a / w
            x1 = -display.width / 2 + display.width * b / w
            xy.append([[x0, y_bot], [x1, y_bot], [x1, y_top], [x0, y_top]])
            rad.append(rgb)
    if not xy:
        return np.zeros((0, 4, 3)), np.zeros((0, 3))
    verts = display.surface_points_world(np.asarray(xy, dtype=np.float64))
    return verts, np.asarray(rad, dtype=np.float64) * display.radiance


# --------------------------------------------------------------------------- irradiance


def polygon_irradiance_vectors(rel: ArrayLike, valid: NDArray | None = None) -> NDArray:
    """Irradiance vectors ``(..., 3)`` of unit-radiance planar polygons (Lambert's formula).

    ``n . Phi`` is the irradiance of a surface element with normal ``n`` at the origin (the
    polygon's projected solid angle), exact while the polygon lies above the element's horizon.

    Args:
        rel: ``(..., V, 3)`` polygon vertices relative to the lit point, counter-clockwise as
            seen from the point.
        valid: ``(..., V)`` which vertex slots are used (a clipped polygon); an unused slot is
            replaced by the previous used one (cyclically), which only adds zero-length edges.
            None: all.

    Example:
        A unit-radiance square of side 2 at distance 1 straight above the point:

        >>> sq = np.array([[-1.0, 1, 1], [1, 1, 1], [1, -1, 1], [-1, -1, 1]])
        >>> np.round(polygon_irradiance_vectors(sq), 4) + 0.0
        array([0.    , 0.    , 1.7408])
    """
    rel = np.asarray(rel, dtype=np.float64)
    empty = None
    if valid is not None:
        idx = np.where(valid, np.arange(rel.shape[-2]), -1)
        ff = np.maximum.accumulate(idx, axis=-1)
        ff = np.where(ff < 0, ff[..., -1:], ff)
        empty = ff[..., 0] < 0
        rel = np.take_along_axis(rel, np.maximum(ff, 0)[..., None], axis=-2)
    u = rel / np.maximum(np.sqrt(np.sum(rel * rel, axis=-1, keepdims=True)), 1e-300)
    v = np.roll(u, -1, axis=-2)
    cross = np.stack(
        [u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
         u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
         u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1,
    )  # fmt: skip
    sin = np.sqrt(np.sum(cross * cross, axis=-1, keepdims=True))
    theta = np.arctan2(sin, np.sum(u * v, axis=-1, keepdims=True))
    phi = -0.5 * np.sum(theta / np.maximum(sin, 1e-300) * cross, axis=-2)
    if empty is not None:
        phi[empty] = 0.0
    return phi


def _clip(rel: NDArray, normals: NDArray) -> tuple[NDArray, NDArray]:
    """Clip polygons ``(..., V, 3)`` (relative to the point) to ``n . x >= 0``: ``(..., 2V, 3)`` and the used slots."""
    s = np.einsum("...vk,...k->...v", rel, normals)
    s_next = np.roll(s, -1, axis=-1)
    inside = s >= 0
    crosses = inside != (s_next >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(crosses, s / (s - s_next), 0.0)
    x = rel + t[..., None] * (np.roll(rel, -1, axis=-2) - rel)
    out = np.stack([rel, x], axis=-2).reshape(*rel.shape[:-2], 2 * rel.shape[-2], 3)
    used = np.stack([inside, crosses], axis=-1).reshape(*s.shape[:-1], 2 * s.shape[-1])
    return out, used


def irradiance_vectors(vertices: ArrayLike, radiance: ArrayLike, points: ArrayLike,
                       normals: ArrayLike | None = None) -> NDArray:  # fmt: skip
    """Per-channel irradiance vectors ``(P, 3, 3)`` (channel, xyz) of display patches at points.

    Args:
        vertices: ``(Q, 4, 3)`` patch corners (:func:`display_patches`), in the frame of ``points``.
        radiance: ``(Q, 3)`` patch radiance per channel.
        points: ``(P, 3)`` lit points.
        normals: ``(P, 3)`` unit surface normals, or None. With normals, every patch is clipped to
            its part above the point's horizon, so ``normals . Phi_c`` is the exact irradiance of
            channel ``c`` on that surface (no occlusion); without, the unclipped vectors.

    Returns:
        ``Phi (P, 3, 3)``: ``Phi[p, c]`` is the irradiance vector of channel ``c`` at point ``p``.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    rad = np.asarray(radiance, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    nrm = None if normals is None else np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((len(pts), 3, 3))
    chunk = max(1, CHUNK // max(1, len(verts) // 4))
    for a in range(0, len(pts), chunk):
        rel = verts[None] - pts[a : a + chunk, None, None, :]  # (p, Q, 4, 3)
        if nrm is None:
            phi = polygon_irradiance_vectors(rel)
        else:  # patches wholly above the horizon as they are, partly above clipped, wholly below dropped
            n = np.broadcast_to(nrm[a : a + chunk, None, :], rel.shape[:2] + (3,))
            above = np.einsum("pqvk,pqk->pqv", rel, n) >= 0
            whole, part = np.all(above, axis=-1), np.any(above, axis=-1) & ~np.all(above, axis=-1)
            phi = np.zeros(rel.shape[:2] + (3,))
            phi[whole] = polygon_irradiance_vectors(rel[whole])
            if part.any():
                phi[part] = polygon_irradiance_vectors(*_clip(rel[part], n[part]))
        out[a : a + chunk] = np.einsum("pqk,qc->pck", phi, rad)
    return out


def region_light_directions(display, point: ArrayLike) -> tuple[NDArray, NDArray]:
    """Unit irradiance directions ``(3, 3)`` of the colour regions at ``point`` and their magnitudes ``(3,)``.

    The direction of channel ``c`` is that of its irradiance vector (the irradiance-weighted
    direction toward its lit region), the magnitude its irradiance on a surface facing it, both
    in the frame of ``point`` (world for a :class:`~pbrdf.sensor.rig.DisplaySpec`).

    Example:
        >>> from pbrdf.sensor.rig import DisplaySpec
        >>> dirs, mag = region_light_directions(DisplaySpec(), [0.0, 0.0, -0.7])
        >>> bool(dirs[0, 0] < 0 < dirs[1, 0] and dirs[2, 1] > 0)  # red at world -x, green +x, blue up
        True
    """
    verts, rad = display_patches(display)
    phi = irradiance_vectors(verts, rad, np.asarray(point, dtype=np.float64)[None])[0]
    mag = np.linalg.norm(phi, axis=-1)
    return phi / np.maximum(mag, 1e-300)[:, None], mag
