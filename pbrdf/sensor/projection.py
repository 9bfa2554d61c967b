"""Pinhole camera projection: the one home for intrinsics, projection, pixel rays and crops.

Convention:
    Camera frame is OpenGL's: x right, y up, the camera looks along -z, so a point in front of
    the camera has ``z < 0`` and depth ``d = -z`` (m). Pixel coordinates are ``(u, v)`` with u
    right and v down, row 0 at the top; pixel ``(i, j)`` covers ``[j, j + 1) x [i, i + 1)`` so its
    centre is ``(j + 0.5, i + 0.5)``. The matrix ``K`` is written as OpenCV's,
    ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, and acts on ``(x, -y, -z)``:

    .. math:: u = c_x + f_x \\, x / d, \\qquad v = c_y - f_y \\, y / d

    Example: with ``fx = fy = 100`` and ``(cx, cy) = (50, 40)`` the point ``(0.1, 0.2, -1)`` lands
    at ``(60, 20)``, above and right of the centre.

Used by the rig (:mod:`pbrdf.sensor.rig`), the renderer's crop window, the add-on's Blender
frustum and the network's re-renderer.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "pinhole_intrinsics",
    "rigid_inverse",
    "transform_points",
    "camera_to_pixel",
    "pixel_rays",
    "crop_intrinsics",
]


def pinhole_intrinsics(
    focal_px: float, width: float, height: float, *, cx: float | None = None, cy: float | None = None
) -> NDArray[np.float64]:
    """Pinhole matrix ``K (3, 3)`` with square pixels.

    Args:
        focal_px: focal length in pixels (focal length / pixel pitch).
        width: image width W in pixels.
        height: image height H in pixels.
        cx: principal point u; default ``W / 2`` (the image centre, since pixel centres sit at
            ``j + 0.5``).
        cy: principal point v; default ``H / 2``.

    Returns:
        ``(3, 3)`` float64.

    Example:
        >>> pinhole_intrinsics(100.0, 64, 48)
        array([[100.,   0.,  32.],
               [  0., 100.,  24.],
               [  0.,   0.,   1.]])
    """
    cx = width / 2 if cx is None else cx
    cy = height / 2 if cy is None else cy
    return np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def rigid_inverse(matrix: ArrayLike) -> NDArray[np.float64]:
    """Inverse ``(4, 4)`` of a rigid transform (rotation plus translation), exact up to rounding.

    Example:
        >>> m = np.eye(4); m[:3, 3] = [1.0, 2.0, 3.0]
        >>> rigid_inverse(m)[:3, 3]
        array([-1., -2., -3.])
    """
    m = np.asarray(matrix, dtype=np.float64)
    inv = np.eye(4)
    inv[:3, :3] = m[:3, :3].T
    inv[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return inv


def transform_points(matrix: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply an affine ``(4, 4)`` transform to points ``(..., 3)``."""
    m = np.asarray(matrix, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def camera_to_pixel(points_cam: ArrayLike, intrinsics: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Project camera-frame points to pixel coordinates.

    Args:
        points_cam: ``(..., 3)`` camera-frame points in m (OpenGL frame, see the module docs).
        intrinsics: ``K (3, 3)``.

    Returns:
        ``(uv, depth)``: ``uv (..., 2)`` continuous pixel coordinates (NaN where ``depth <= 0``)
        and ``depth (...)`` in m, positive in front of the camera.

    Raises:
        ValueError: if ``points_cam`` is not ``(..., 3)``.

    Example:
        >>> k = pinhole_intrinsics(100.0, 100, 80)
        >>> camera_to_pixel([0.1, 0.2, -1.0], k)[0]
        array([60., 20.])
    """
    p = np.asarray(points_cam, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise ValueError(f"points must have shape (..., 3), got {p.shape}")
    k = np.asarray(intrinsics, dtype=np.float64)
    depth = -p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(depth > 0, depth, np.nan)
        u = k[0, 2] + k[0, 0] * p[..., 0] / safe
        v = k[1, 2] - k[1, 1] * p[..., 1] / safe
    return np.stack([u, v], axis=-1), depth


def pixel_rays(intrinsics: ArrayLike, height: int, width: int) -> NDArray[np.float64]:
    """Camera-frame rays ``(H, W, 3)`` through the pixel centres, scaled to ``z = -1``.

    A point at depth ``d`` (m along the viewing axis) on pixel ``(i, j)`` is ``d * rays[i, j]``;
    :func:`camera_to_pixel` of it gives back ``(j + 0.5, i + 0.5)``.

    Example:
        >>> rays = pixel_rays(pinhole_intrinsics(1.0, 2, 2), 2, 2)
        >>> rays[0, 1]  # top-right pixel: right and up
        array([ 0.5,  0.5, -1. ])
    """
    k = np.asarray(intrinsics, dtype=np.float64)
    x = (np.arange(width) + 0.5 - k[0, 2]) / k[0, 0]
    y = -(np.arange(height) + 0.5 - k[1, 2]) / k[1, 1]
    gx, gy = np.meshgrid(x, y, indexing="xy")
    return np.stack([gx, gy, -np.ones_like(gx)], axis=-1)


def crop_intrinsics(
    intrinsics: ArrayLike, box: tuple[int, int, int, int], size: tuple[int, int] | None = None
) -> NDArray[np.float64]:
    """Pinhole matrix ``(3, 3)`` after cropping to ``box`` and resizing the crop to ``size``.

    Args:
        intrinsics: ``K (3, 3)`` of the full image.
        box: ``(y0, x0, y1, x1)`` crop in pixels of the full image.
        size: ``(H, W)`` of the resized crop; default the crop's own size. Bilinear resizing with
            ``align_corners=False`` maps pixel-edge coordinates linearly, so the pixel-centre
            convention is kept.

    Example:
        >>> k = pinhole_intrinsics(100.0, 100, 80)
        >>> crop_intrinsics(k, (10, 20, 50, 60), (80, 80))[0]
        array([200.,   0.,  60.])
    """
    k = np.array(intrinsics, dtype=np.float64)
    y0, x0, y1, x1 = box
    size = (y1 - y0, x1 - x0) if size is None else size
    sx, sy = size[1] / (x1 - x0), size[0] / (y1 - y0)
    k[0, 2] -= x0
    k[1, 2] -= y0
    k[0] *= sx
    k[1] *= sy
    return k
