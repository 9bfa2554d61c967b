"""A Blender camera's frustum without bpy: pixel rays, projection and depth-map meshes.

:func:`blender_frustum` turns a Blender camera's lens, sensor, fit and shift into a
:class:`Frustum`, whose camera maths is :mod:`pbrdf.sensor.projection`'s (the one home of the
pinhole model); :func:`depth_mesh` lifts a depth map into a camera-frame triangle mesh.

Convention (camera):
    A Blender camera looks down its local -z with x right and y up; :class:`Frustum` is its image
    rectangle at unit distance. Pixel ``(u, v)``: u right, v down, pixel ``(0, 0)`` covers
    ``[0, 1] x [0, 1]``. Example: a 4 x 2 image with a 36 mm sensor and a 36 mm lens has the
    rectangle ``x in [-0.5, 0.5], y in [-0.25, 0.25]`` at ``z = -1``, and pixel ``(0, 0)``'s centre is
    ``(-0.375, 0.125, -1)``:

    >>> f = blender_frustum(4, 2, lens=36.0, sensor_width=36.0, sensor_height=24.0)
    >>> f.half_width, f.half_height
    (0.5, 0.25)
    >>> [float(v) for v in f.pixel_xy()[0, 0]]
    [-0.375, 0.125]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pbrdf.sensor import projection

__all__ = ["Frustum", "blender_frustum", "depth_mesh"]


@dataclass(frozen=True)
class Frustum:
    """A pinhole camera's image rectangle at unit distance (camera frame: x right, y up, looking down -z).

    Attributes:
        width: image columns W.
        height: image rows H.
        half_width: half the rectangle's width at ``z = -1``.
        half_height: half its height at ``z = -1``.
        center_x: rectangle centre x at ``z = -1`` (lens shift).
        center_y: rectangle centre y at ``z = -1``.
    """

    width: int
    height: int
    half_width: float
    half_height: float
    center_x: float = 0.0
    center_y: float = 0.0

    def intrinsics(self) -> NDArray[np.float64]:
        """Pinhole matrix ``K (3, 3)`` of this frustum (:mod:`pbrdf.sensor.projection` convention)."""
        fx = self.width / (2.0 * self.half_width)
        fy = self.height / (2.0 * self.half_height)
        return np.array(
            [
                [fx, 0.0, self.width / 2 - self.center_x * fx],
                [0.0, fy, self.height / 2 + self.center_y * fy],
                [0, 0, 1.0],
            ]
        )

    def pixel_xy(self) -> NDArray[np.float64]:
        """``(H, W, 2)`` x, y of every pixel centre at ``z = -1`` (row 0 at the top)."""
        return projection.pixel_rays(self.intrinsics(), self.height, self.width)[..., :2]

    def project(self, points: NDArray) -> NDArray[np.float64]:
        """Continuous pixel coordinates ``(..., 2)`` = (u right, v down) of camera-frame points ``(..., 3)``.

        Points must lie in front of the camera (``z < 0``); others give NaN.
        """
        return projection.camera_to_pixel(points, self.intrinsics())[0]


def blender_frustum(
    width: int,
    height: int,
    *,
    lens: float,
    sensor_width: float,
    sensor_height: float,
    sensor_fit: str = "AUTO",
    shift_x: float = 0.0,
    shift_y: float = 0.0,
) -> Frustum:
    """The frustum of a Blender perspective camera rendering ``width x height`` square pixels.

    Blender fits the sensor to one image axis: ``HORIZONTAL`` (sensor_width spans the width),
    ``VERTICAL`` (sensor_height spans the height), ``AUTO`` (sensor_width spans the larger axis).
    Lens shift is in units of the fitted axis.

    Args:
        width: image columns.
        height: image rows.
        lens: focal length in mm.
        sensor_width: mm.
        sensor_height: mm.
        sensor_fit: ``AUTO``, ``HORIZONTAL`` or ``VERTICAL``.
        shift_x: horizontal lens shift.
        shift_y: vertical lens shift.
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    if not (lens > 0 and sensor_width > 0 and sensor_height > 0):
        raise ValueError(f"lens and sensor must be positive, got lens {lens}, sensor {sensor_width} x {sensor_height}")
    if sensor_fit == "AUTO":
        sensor_fit = "HORIZONTAL" if width >= height else "VERTICAL"
        sensor_height = sensor_width
    if sensor_fit == "HORIZONTAL":
        hw = 0.5 * sensor_width / lens
        hh = hw * height / width
        fitted = 2.0 * hw
    elif sensor_fit == "VERTICAL":
        hh = 0.5 * sensor_height / lens
        hw = hh * width / height
        fitted = 2.0 * hh
    else:
        raise ValueError(f"unknown sensor_fit {sensor_fit!r}; valid: AUTO, HORIZONTAL, VERTICAL")
    return Frustum(int(width), int(height), hw, hh, shift_x * fitted, shift_y * fitted)


def depth_mesh(
    depth: NDArray, valid: NDArray, frustum: Frustum, *, max_jump: float = 0.05
) -> tuple[NDArray, NDArray, NDArray]:
    """A camera-frame triangle mesh with one vertex per valid pixel centre, displaced to its depth.

    Two triangles per 2x2 block of valid pixels (one where three are valid), none across depth
    jumps larger than ``max_jump`` (relative), so silhouettes do not become skirts.

    Args:
        depth: ``(H, W)`` metres along the optical axis.
        valid: ``(H, W)`` bool.
        frustum: the camera's frustum (same size).
        max_jump: largest relative depth difference inside one triangle.

    Returns:
        ``(vertices (N, 3), faces (F, 3) counter-clockwise seen from the camera, uvs (N, 2))``;
        the UVs are the pixel centres (u right, v up, in [0, 1]), so a texture of the same size
        is sampled at its texel centres.
    """
    h, w = depth.shape
    if (frustum.height, frustum.width) != (h, w) or valid.shape != (h, w):
        raise ValueError(
            f"depth {depth.shape}, valid {valid.shape} and frustum {frustum.height}x{frustum.width} differ"
        )
    index = -np.ones((h, w), np.int64)
    index[valid] = np.arange(int(valid.sum()))
    xy = frustum.pixel_xy()
    d = depth.astype(np.float64)
    vertices = np.concatenate([xy[valid] * d[valid][:, None], -d[valid][:, None]], axis=1)
    rows, cols = np.nonzero(valid)
    uvs = np.stack([(cols + 0.5) / w, 1.0 - (rows + 0.5) / h], axis=1)
    # corners of each 2x2 block: a top-left, b top-right, c bottom-left, e bottom-right (image rows down)
    a, b, c, e = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    da, db, dc, de = d[:-1, :-1], d[:-1, 1:], d[1:, :-1], d[1:, 1:]
    ok = (a >= 0, b >= 0, c >= 0, e >= 0)
    n_ok = sum(o.astype(np.int8) for o in ok)
    # Seen from the camera (x right, y up) every triangle below is counter-clockwise. A full
    # block gets two triangles, a block with three valid pixels the triangle of those three.
    cases = (
        ((c, e, a), (dc, de, da), (n_ok == 4) | ((n_ok == 3) & ~ok[1])),
        ((e, b, a), (de, db, da), (n_ok == 4) | ((n_ok == 3) & ~ok[2])),
        ((c, e, b), (dc, de, db), (n_ok == 3) & ~ok[0]),
        ((c, b, a), (dc, db, da), (n_ok == 3) & ~ok[3]),
    )
    faces = []
    for tri, dd, use in cases:
        lo = np.minimum(np.minimum(dd[0], dd[1]), dd[2])
        hi = np.maximum(np.maximum(dd[0], dd[1]), dd[2])
        with np.errstate(invalid="ignore"):
            use = use & ((hi - lo) <= max_jump * lo)
        faces.append(np.stack([t[use] for t in tri], axis=1))
    faces_arr = np.concatenate(faces, axis=0)
    if not math.isfinite(float(vertices.sum())):
        raise ValueError("depth mesh has non-finite vertices")
    return vertices, faces_arr, uvs
