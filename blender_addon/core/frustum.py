"""A Blender camera's frustum without bpy: pixel rays, projection and depth-map meshes.

:func:`blender_frustum` turns a Blender camera's lens, sensor, fit, shift and pixel aspect into a
:class:`Frustum`, whose camera maths is :mod:`pbrdf.sensor.projection`'s (the one home of the
pinhole model); :func:`camera_from_intrinsics` is its inverse: the Blender camera whose frustum
is a pinhole matrix ``K`` (:func:`read_camera_json` reads the ``<name>_camera.json`` that
``headless/infer.py`` writes beside the maps); :func:`depth_mesh` lifts a depth map into a
camera-frame triangle mesh.

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

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pbrdf.data.predictions import CameraRecord
from pbrdf.geometry.relief import relief_mesh
from pbrdf.sensor import projection

__all__ = [
    "BlenderCamera",
    "CaptureCamera",
    "Frustum",
    "blender_frustum",
    "camera_from_intrinsics",
    "depth_mesh",
    "read_camera_json",
]

#: Sensor width (mm) of the cameras :func:`camera_from_intrinsics` makes (Blender's default).
SENSOR_WIDTH = 36.0
#: Blender's limits: lens >= 1 mm, |shift| <= 10.
_MIN_LENS, _MAX_SHIFT = 1.0, 10.0


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
    pixel_aspect_x: float = 1.0,
    pixel_aspect_y: float = 1.0,
) -> Frustum:
    """The frustum of a Blender perspective camera rendering ``width x height`` pixels.

    Blender fits the sensor to one image axis: ``HORIZONTAL`` (sensor_width spans the width),
    ``VERTICAL`` (sensor_height spans the height), ``AUTO`` (sensor_width spans the axis that is
    larger after the pixel aspect). Lens shift is in units of the fitted axis. A pixel is
    ``pixel_aspect_y / pixel_aspect_x`` times as tall as wide (the scene's render settings), as in
    Blender's ``BKE_camera_params_compute_viewplane``.

    Args:
        width: image columns.
        height: image rows.
        lens: focal length in mm.
        sensor_width: mm.
        sensor_height: mm.
        sensor_fit: ``AUTO``, ``HORIZONTAL`` or ``VERTICAL``.
        shift_x: horizontal lens shift.
        shift_y: vertical lens shift.
        pixel_aspect_x: the render setting of that name.
        pixel_aspect_y: the render setting of that name.
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    if not (lens > 0 and sensor_width > 0 and sensor_height > 0):
        raise ValueError(f"lens and sensor must be positive, got lens {lens}, sensor {sensor_width} x {sensor_height}")
    if not (pixel_aspect_x > 0 and pixel_aspect_y > 0):
        raise ValueError(f"pixel aspect must be positive, got {pixel_aspect_x} x {pixel_aspect_y}")
    ycor = pixel_aspect_y / pixel_aspect_x  # pixel height / pixel width
    if sensor_fit == "AUTO":
        sensor_fit = "HORIZONTAL" if pixel_aspect_x * width >= pixel_aspect_y * height else "VERTICAL"
        sensor_height = sensor_width
    if sensor_fit == "HORIZONTAL":
        hw = 0.5 * sensor_width / lens
        hh = hw * ycor * height / width
        fitted = 2.0 * hw
    elif sensor_fit == "VERTICAL":
        hh = 0.5 * sensor_height / lens
        hw = hh * width / (ycor * height)
        fitted = 2.0 * hh
    else:
        raise ValueError(f"unknown sensor_fit {sensor_fit!r}; valid: AUTO, HORIZONTAL, VERTICAL")
    return Frustum(int(width), int(height), hw, hh, shift_x * fitted, shift_y * fitted)


@dataclass(frozen=True)
class BlenderCamera:
    """The Blender camera data of one pinhole camera, for square pixels (see :func:`camera_from_intrinsics`).

    Attributes:
        lens: focal length in mm (``Camera.lens``).
        sensor_width: mm (``Camera.sensor_width``).
        sensor_height: mm (``Camera.sensor_height``; the sensor's true height, unused by the fit).
        sensor_fit: ``Camera.sensor_fit``.
        shift_x: ``Camera.shift_x`` (units of the sensor width).
        shift_y: ``Camera.shift_y`` (units of the sensor width).
        fy_over_fx: ``K``'s ``fy / fx``; 1 when this camera is ``K`` exactly.
    """

    lens: float
    sensor_width: float
    sensor_height: float
    sensor_fit: str
    shift_x: float
    shift_y: float
    fy_over_fx: float = 1.0

    def frustum(self, width: int, height: int) -> Frustum:
        """:func:`blender_frustum` of this camera at ``width x height`` square pixels."""
        return blender_frustum(
            width,
            height,
            lens=self.lens,
            sensor_width=self.sensor_width,
            sensor_height=self.sensor_height,
            sensor_fit=self.sensor_fit,
            shift_x=self.shift_x,
            shift_y=self.shift_y,
        )


def camera_from_intrinsics(intrinsics: NDArray, width: int, height: int) -> BlenderCamera:
    """The Blender camera whose frustum at ``width x height`` square pixels is the pinhole matrix ``K``.

    ``K`` is :mod:`pbrdf.sensor.projection`'s (OpenCV pixels: u right, v down, pixel centres at
    integer + 0.5; ``v = cy - fy y / depth`` for Blender's y-up camera frame). With a 36 mm sensor
    fitted horizontally: ``lens = 36 fx / W``; the principal point becomes the lens shift, in
    units of the fitted sensor width: ``shift_x = (W / 2 - cx) / W``, ``shift_y = (cy - H / 2) / W``
    (v grows downward, Blender's y upward). Exact when ``fx == fy``: the :func:`blender_frustum`
    of the result has ``K`` as its intrinsics. Otherwise the camera uses ``fx`` for both axes
    (``fy_over_fx`` says by how much rows are off): Blender's other route, the render's pixel
    aspect, breaks multilayer EXR output with more than one pass (Blender 5.0 refuses to write
    it) and the polarized export (square pixels only).

    Example: a 64 x 48 image with ``f = 80`` px and the principal point 2 px right of the centre:

    >>> k = [[80.0, 0.0, 34.0], [0.0, 80.0, 24.0], [0.0, 0.0, 1.0]]
    >>> cam = camera_from_intrinsics(k, 64, 48)
    >>> cam.lens, cam.shift_x, cam.shift_y
    (45.0, -0.03125, 0.0)
    >>> bool(np.allclose(cam.frustum(64, 48).intrinsics(), k))
    True

    Raises:
        ValueError: one line starting ``intrinsics:`` (not a finite 3x3 pinhole matrix, skew,
            outside Blender's lens or shift range) or ``width``/``height``.
    """
    for field_name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{field_name}: must be a positive integer, got {v!r}")
    try:
        k = np.asarray(intrinsics, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"intrinsics: not a 3x3 matrix of numbers: {intrinsics!r}") from None
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise ValueError(f"intrinsics: must be a finite 3x3 matrix, got {k.tolist()}")
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    if not (fx > 0 and fy > 0):
        raise ValueError(f"intrinsics: focal lengths must be positive, got fx {fx}, fy {fy}")
    if k[1, 0] != 0 or not np.array_equal(k[2], [0.0, 0.0, 1.0]) or abs(k[0, 1]) > 1e-9 * fx:
        raise ValueError(f"intrinsics: not a pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: {k.tolist()}")
    lens = fx * SENSOR_WIDTH / width
    shift_x = (width / 2 - cx) / width
    shift_y = (cy - height / 2) / width
    if lens < _MIN_LENS or max(abs(shift_x), abs(shift_y)) > _MAX_SHIFT:
        raise ValueError(
            f"intrinsics: outside what a Blender camera can hold (lens {lens:.4g} mm >= {_MIN_LENS:g}, "
            f"shift {shift_x:.4g}, {shift_y:.4g} within +-{_MAX_SHIFT:g})"
        )
    return BlenderCamera(
        lens=float(lens),
        sensor_width=SENSOR_WIDTH,
        sensor_height=float(SENSOR_WIDTH * height / width),
        sensor_fit="HORIZONTAL",
        shift_x=float(shift_x),
        shift_y=float(shift_y),
        fy_over_fx=float(fy / fx),
    )


@dataclass(frozen=True)
class CaptureCamera:
    """A ``<name>_camera.json``: the maps' pinhole camera (:class:`pbrdf.data.predictions.CameraRecord`).

    Attributes:
        intrinsics: ``K (3, 3)`` of the maps' grid (:mod:`pbrdf.sensor.projection` convention).
        width: map columns W.
        height: map rows H.
        distance_m: the capture's object distance in metres, or None.
        blender: the matching Blender camera (:func:`camera_from_intrinsics`).
    """

    intrinsics: NDArray
    width: int
    height: int
    distance_m: float | None
    blender: BlenderCamera


def read_camera_json(path: str | os.PathLike) -> CaptureCamera:
    """Read and check a ``<name>_camera.json`` (:class:`pbrdf.data.predictions.CameraRecord`) and its Blender camera.

    Raises:
        FileNotFoundError: no such file.
        ValueError: one line naming the file and the bad field (or the JSON error).
    """
    record = CameraRecord.read(path)
    try:
        cam = camera_from_intrinsics(record.intrinsics, record.width, record.height)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    return CaptureCamera(record.intrinsics, record.width, record.height, record.distance_m, cam)


def depth_mesh(
    depth: NDArray, valid: NDArray, frustum: Frustum, *, max_jump: float = 0.05
) -> tuple[NDArray, NDArray, NDArray]:
    """A camera-frame triangle mesh with one vertex per valid pixel centre, displaced to its depth.

    :func:`pbrdf.geometry.relief.relief_mesh` in this frustum, with Blender's UVs: two triangles
    per 2x2 block of valid pixels (one where three are valid), none across depth jumps larger
    than ``max_jump`` (relative), so silhouettes do not become skirts.

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
    vertices, faces, pixels = relief_mesh(depth, valid, frustum.intrinsics(), max_jump=max_jump)
    uvs = np.stack([(pixels[:, 1] + 0.5) / w, 1.0 - (pixels[:, 0] + 0.5) / h], axis=1)
    return vertices, faces, uvs
