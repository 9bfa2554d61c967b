"""The lit display cut into planar patches: one home for the display's discretisation.

Two tilings of the pattern, one builder (:func:`rectangle_patches`: display-surface rectangles to
world patches with corners, centres, normals, areas and radiance):

* :func:`constant_patches`: rectangles of constant colour, exact polygons for Lambert's formula
  (:mod:`pbrdf.sensor.irradiance`): one per colour combination of a built-in pattern, a
  block-averaged grid of an image pattern, chords of :data:`STRIP_COLUMNS` pattern columns on a
  curved display.
* :func:`channel_patches`: each colour channel's lit rectangle
  (:meth:`~pbrdf.sensor.rig.DisplaySpec.lit_rectangle`) in ``nx x ny`` equal patches carrying only
  that channel, the quadrature of the re-renderer (:mod:`network.rerender`), so region edges fall
  on patch edges.

Convention: rectangles are ``(x0, x1, y0, y1)`` in display-surface coordinates (m; ``X`` to the
right seen from the front, the arc length on a curved display, ``Y`` up, origin at the centre of the
active area, :mod:`pbrdf.sensor.rig`). Patches are in world coordinates, their corners
counter-clockwise as seen from the front (from the objects); on a curved display the corners lie
on the cylinder (a patch is its chord) and the centre and normal are the surface's.

Example:
    >>> from pbrdf.sensor.rig import DisplaySpec
    >>> p = constant_patches(DisplaySpec())  # rgb_halves: cyan, magenta, green, red quadrants
    >>> len(p), p.radiance.tolist()
    (4, [[0.0, 1.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    >>> round(float(p.area.sum()), 6)  # the whole active area, 1.2096 m x 0.6804 m
    0.823012
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.sensor.rig import DEFAULT_PATTERN_SIZE

if TYPE_CHECKING:
    from pbrdf.sensor.rig import DisplaySpec

__all__ = ["MAX_PATCHES", "STRIP_COLUMNS", "DisplayPatches", "rectangle_patches", "constant_patches", "channel_patches"]

#: Largest number of constant patches kept from an image pattern before it is block-averaged.
MAX_PATCHES = 256
#: Pattern columns per planar strip on a curved display (each strip is a chord of the cylinder).
STRIP_COLUMNS = 4


@dataclass(frozen=True)
class DisplayPatches:
    """Planar patches of the display in world coordinates.

    Attributes:
        vertices: ``(Q, 4, 3)`` corners, counter-clockwise as seen from the front.
        centers: ``(Q, 3)`` centres on the display surface.
        normals: ``(Q, 3)`` unit front normals (toward the objects) at the centres.
        area: ``(Q,)`` surface areas in m^2.
        radiance: ``(Q, 3)`` emitted radiance ``s0`` per colour channel (pattern value times
            ``display.radiance``).
    """

    vertices: NDArray[np.float64]
    centers: NDArray[np.float64]
    normals: NDArray[np.float64]
    area: NDArray[np.float64]
    radiance: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.area)


def rectangle_patches(display: DisplaySpec, rectangles: ArrayLike, radiance: ArrayLike) -> DisplayPatches:
    """World patches of display-surface rectangles.

    Args:
        display: a :class:`pbrdf.sensor.rig.DisplaySpec`.
        rectangles: ``(Q, 4)`` ``(x0, x1, y0, y1)`` in m on the display surface.
        radiance: ``(Q, 3)`` emitted radiance per colour channel.

    Returns:
        :class:`DisplayPatches` with ``Q`` patches.
    """
    rect = np.asarray(rectangles, dtype=np.float64).reshape(-1, 4)
    x0, x1, y0, y1 = rect.T
    corners = np.stack([np.stack(c, axis=-1) for c in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))], axis=1)
    centre = np.stack([(x0 + x1) / 2, (y0 + y1) / 2], axis=-1)
    return DisplayPatches(
        vertices=display.surface_points_world(corners).reshape(-1, 4, 3),
        centers=display.surface_points_world(centre).reshape(-1, 3),
        normals=display.surface_normals_world(centre).reshape(-1, 3),
        area=np.abs((x1 - x0) * (y1 - y0)),
        radiance=np.asarray(radiance, dtype=np.float64).reshape(-1, 3),
    )


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


def constant_patches(display: DisplaySpec) -> DisplayPatches:
    """The lit display as planar patches of constant radiance (exact for Lambert's formula).

    Built-in patterns give one rectangle per colour combination (``rgb_halves``: cyan and magenta
    upper quadrants, green and red lower ones). An image pattern is block-averaged to at most 36 x
    64 cells, and coarser when it has more than :data:`MAX_PATCHES` constant rectangles. On a
    curved display every rectangle is cut into strips of :data:`STRIP_COLUMNS` pattern columns.

    Args:
        display: a :class:`pbrdf.sensor.rig.DisplaySpec`.

    Returns:
        :class:`DisplayPatches`, dark parts left out.
    """
    img = np.asarray(display.pattern_image(), dtype=np.float64)
    h, w = img.shape[:2]
    max_h, max_w = DEFAULT_PATTERN_SIZE
    if h > max_h or w > max_w:
        img = _block_average(img, min(h, max_h), min(w, max_w))
        h, w = img.shape[:2]
    rects = _constant_rectangles(img)
    if len(rects) > MAX_PATCHES:
        side = max(1, int(np.sqrt(MAX_PATCHES / (16 * 9))))  # a 16:9 grid of at most MAX_PATCHES cells
        img = _block_average(img, min(h, 9 * side), min(w, 16 * side))
        h, w = img.shape[:2]
        rects = _constant_rectangles(img)
    surface, rad = [], []
    step = w if display.curvature_radius is None else STRIP_COLUMNS
    for r0, r1, c0, c1, rgb in rects:
        for a in range(c0, c1, step):
            surface.append(display.pattern_rectangle((r0, r1), (a, min(a + step, c1)), (h, w)))
            rad.append(rgb)
    return rectangle_patches(display, np.reshape(surface, (-1, 4)), np.reshape(rad, (-1, 3)) * display.radiance)


def channel_patches(display: DisplaySpec, n: tuple[int, int], *, supersample: int = 4) -> DisplayPatches:
    """Each colour channel's lit rectangle in ``nx x ny`` equal patches that carry only that channel.

    Channel ``c``'s patches tile :meth:`~pbrdf.sensor.rig.DisplaySpec.lit_rectangle` ``(c)`` (in
    surface coordinates: arc length on a curved display); their radiance in channel ``c`` is
    ``display.radiance`` times the pattern averaged over ``supersample^2`` points of the patch
    (exact for the built-in patterns). A channel that is dark everywhere gets zero-area,
    zero-radiance patches, so the count stays ``3 nx ny``.

    Args:
        display: a :class:`pbrdf.sensor.rig.DisplaySpec`.
        n: ``(nx, ny)`` patches per channel along the display's X (width) and Y (height).
        supersample: pattern samples per patch and axis.

    Returns:
        :class:`DisplayPatches` with ``Q = 3 nx ny``, channel-major, then row-major over ``(y, x)``.

    Raises:
        ValueError: if ``n`` or ``supersample`` is not positive.

    Example:
        >>> from pbrdf.sensor.rig import DisplaySpec
        >>> p = channel_patches(DisplaySpec(), (2, 1))
        >>> p.radiance.tolist()  # red's two patches on the right half, green's on the left, blue's on top
        [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
    """
    nx, ny = (int(v) for v in n)
    if nx < 1 or ny < 1 or supersample < 1:
        raise ValueError(f"patch counts and supersample must be >= 1; got n={n}, supersample={supersample}")
    ix, iy = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy"))
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    rects, rad = [], []
    for c in range(3):
        lit = display.lit_rectangle(c)
        x0, x1, y0, y1 = lit if lit is not None else (0.0, 0.0, 0.0, 0.0)
        dx, dy = (x1 - x0) / nx, (y1 - y0) / ny
        rects.append(np.stack([x0 + ix * dx, x0 + (ix + 1) * dx, y0 + iy * dy, y0 + (iy + 1) * dy], axis=-1))
        r = np.zeros((nx * ny, 3))
        if lit is not None:
            centre = np.stack([x0 + (ix + 0.5) * dx, y0 + (iy + 0.5) * dy], axis=-1)  # (nx ny, 2)
            sx, sy = np.meshgrid(sub * dx, sub * dy, indexing="xy")
            samples = centre[:, None, :] + np.stack([sx.ravel(), sy.ravel()], axis=-1)[None]
            r[:, c] = display.radiance * display.pattern_rgb_at(samples)[..., c].mean(axis=1)
        rad.append(r)
    return rectangle_patches(display, np.concatenate(rects), np.concatenate(rad))
