"""The capture rig: a polarized LCD that lights the objects and an RGB polarization camera.

Both are plain, frozen, validated specs without bpy; the Mitsuba exporter and the Blender add-on
consume them. A rig round-trips through JSON exactly, and a rig file may override any single
number of the defaults (a calibrated rig), e.g. ``{"camera": {"focal_length": 0.012}}``.

Convention (world frame):
    The world frame is the default camera frame: metres, right-handed, x right, y up, the camera
    at the origin looking along -z (OpenGL). Objects sit at negative z. The display sits just
    behind the camera (default centre ``(0, 0, 0.05)``) and faces -z, toward the objects.
    Example: a point at ``(0, 0.1, -0.5)`` is 0.5 m in front of the camera and appears above the
    image centre (row < H/2).

Convention (display-local frame):
    ``X`` to the right as seen from the FRONT (from the objects), ``Y`` up, ``Z`` the front
    normal pointing toward the objects, origin at the centre of the active area. Because the
    display faces the camera, display ``+X`` is world ``-x`` by default. On a curved display ``X``
    is the arc length along the surface.

Convention (pixels):
    Pixel coordinates ``(u, v)``: ``u`` to the right, ``v`` DOWN, row 0 at the top of the image,
    pixel ``(0, 0)`` covers ``[0, 1] x [0, 1]`` so its centre is ``(0.5, 0.5)``; the principal
    point is the sensor centre ``(W/2, H/2)``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.strict_json import read_json_object
from pbrdf.sensor import projection
from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.display_response import check_emission_exponent, check_tone_gamma, tone_response
from pbrdf.sensor.spec_fields import IDENTITY4, as_float, as_int, as_matrix4, as_vec, check_rigid

__all__ = ["BUILTIN_PATTERNS", "DisplaySpec", "CameraSpec", "Rig", "merge_overrides"]

#: Built-in display patterns: ``rgb_halves`` (red right half, green left half, blue upper half, as
#: seen from the front) and ``white`` (every channel on everywhere).
BUILTIN_PATTERNS = ("rgb_halves", "white")

#: Default size ``(H, W)`` of a built-in pattern image. The patterns are piecewise constant with
#: edges at the centre lines, so any even size is exact; 36 x 64 keeps the display's 16:9 aspect.
DEFAULT_PATTERN_SIZE = (36, 64)

#: A display-surface rectangle ``(x0, x1, y0, y1)`` in m.
Rectangle = tuple[float, float, float, float]


def merge_overrides(base: dict, override: Any, path: str) -> dict:
    """Return ``base`` with ``override`` applied key by key, recursing into nested dicts.

    Args:
        base: complete dictionary (e.g. ``Rig().to_dict()``); not modified.
        override: partial dictionary with a subset of ``base``'s keys at any depth.
        path: dotted name of ``base`` used in error messages (``"rig"``).

    Raises:
        ValueError: an override key that ``base`` lacks (the message lists the valid ones), or a
            non-dict where ``base`` has a dict.
    """
    if not isinstance(override, dict):
        raise ValueError(f"{path} must be a JSON object (dict), got {type(override).__name__}")
    out = dict(base)
    for key, value in override.items():
        if key not in base:
            raise ValueError(f"unknown key '{path}.{key}'; valid: {sorted(base)}")
        if isinstance(base[key], dict):
            out[key] = merge_overrides(base[key], value, f"{path}.{key}")
        else:
            out[key] = value
    return out


def _rot_x(a: float) -> NDArray[np.float64]:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> NDArray[np.float64]:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


# --------------------------------------------------------------------------- display


@dataclass(frozen=True)
class DisplaySpec:
    """The LCD: a polarized area light showing a fixed RGB pattern.

    Defaults: Samsung Odyssey Ark 55" (3840 x 2160, active area about 1209.6 x 680.4 mm, peak
    600 cd/m^2), flat, vertically polarized, centred 5 cm behind the camera and facing the objects.

    Attributes:
        width: active-area width in m (arc length when curved).
        height: active-area height in m.
        resolution: ``(W, H)`` in pixels (documentation of the panel; the pattern image has its own size).
        curvature_radius: ``None`` for a flat panel, else the radius in m of the cylinder the
            panel is bent on (1.0 = 1000R). The axis is the display's vertical (``Y``) axis and the
            panel is concave toward the viewer: its left and right edges come forward (``+Z``).
            Must be ``>= width / pi`` so the panel spans at most a half cylinder.
        center: centre of the active area in world coordinates, m.
        yaw: rotation of the display about world y in radians (right-handed); 0 faces -z.
        pitch: rotation of the display about world x in radians (right-handed), applied before yaw.
        pattern: a name from :data:`BUILTIN_PATTERNS` or a path to an image file (Pillow).
        polarization_angle: angle of the emitted linear polarization in radians, measured in the
            display plane from ``+X`` toward ``+Y`` as seen from the front; ``pi/2`` = vertical.
        degree_of_polarization: in [0, 1]; 1 = fully polarized.
        radiance: renderer radiance of a fully lit colour channel (linear units).
        luminance_cd_m2: the physical peak luminance the radiance stands for (documentation;
            the radiometric calibration lives in ``SensorParams.electrons_per_unit``).
        emission_exponent: ``p`` of the emission profile ``cos^p`` (0 = flat; :mod:`pbrdf.sensor.display_response`).
        tone_gamma: per channel (R, G, B), the emitted level of a commanded pattern value ``v`` is ``v ** gamma``.
    """

    width: float = 1.2096
    height: float = 0.6804
    resolution: tuple[int, int] = (3840, 2160)
    curvature_radius: float | None = None
    center: tuple[float, float, float] = (0.0, 0.0, 0.05)
    yaw: float = 0.0
    pitch: float = 0.0
    pattern: str = "rgb_halves"
    polarization_angle: float = math.pi / 2
    degree_of_polarization: float = 1.0
    radiance: float = 1.0
    luminance_cd_m2: float = 600.0
    emission_exponent: float = 0.0
    tone_gamma: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        for name in ("width", "height", "yaw", "pitch", "polarization_angle", "degree_of_polarization"):
            put(name, as_float(getattr(self, name), f"display.{name}"))
        for name in ("radiance", "luminance_cd_m2"):
            put(name, as_float(getattr(self, name), f"display.{name}"))
        put("center", as_vec(self.center, 3, "display.center"))
        put("emission_exponent", check_emission_exponent(self.emission_exponent))
        put("tone_gamma", check_tone_gamma(self.tone_gamma))
        res = self.resolution
        if isinstance(res, (str, bytes)) or not hasattr(res, "__len__") or len(res) != 2:
            raise ValueError(f"display.resolution must be (W, H) pixels, got {self.resolution!r}")
        put("resolution", tuple(as_int(v, f"display.resolution[{i}]") for i, v in enumerate(self.resolution)))
        for name in ("width", "height", "radiance", "luminance_cd_m2"):
            if not getattr(self, name) > 0:
                raise ValueError(f"display.{name} must be > 0, got {getattr(self, name)}")
        if min(self.resolution) < 1:
            raise ValueError(f"display.resolution must be positive, got {self.resolution}")
        if not 0.0 <= self.degree_of_polarization <= 1.0:
            raise ValueError(f"display.degree_of_polarization must be in [0, 1], got {self.degree_of_polarization}")
        if self.curvature_radius is not None:
            put("curvature_radius", as_float(self.curvature_radius, "display.curvature_radius"))
            if not self.curvature_radius >= self.width / math.pi:
                raise ValueError(
                    f"display.curvature_radius must be >= width / pi = {self.width / math.pi:.4f} m "
                    f"(at most a half cylinder), got {self.curvature_radius}"
                )
        if isinstance(self.pattern, os.PathLike):
            put("pattern", os.fspath(self.pattern))
        if not isinstance(self.pattern, str) or not self.pattern:
            raise ValueError(f"display.pattern must be a built-in name {BUILTIN_PATTERNS} or an image path")

    # ----------------------------------------------------------------------- geometry
    def world_trans_display(self) -> NDArray[np.float64]:
        """Rotation part of :meth:`display_to_world`, ``(3, 3)``: columns are X_d, Y_d, Z_d in world."""
        facing = np.diag([-1.0, 1.0, -1.0])  # front normal along world -z: X_d = -x, Z_d = -z
        return _rot_y(self.yaw) @ _rot_x(self.pitch) @ facing

    def display_to_world(self) -> NDArray[np.float64]:
        """Homogeneous transform ``(4, 4)`` from display-local coordinates to world.

        Example (defaults): ``X_d -> -x``, ``Y_d -> +y``, ``Z_d -> -z``, origin at ``center``.
        """
        m = np.eye(4)
        m[:3, :3] = self.world_trans_display()
        m[:3, 3] = self.center
        return m

    def surface_points_local(self, points_display_xy: ArrayLike) -> NDArray[np.float64]:
        """Display-local 3D points ``(..., 3)`` of surface coordinates ``(..., 2)`` = (X, Y) in m.

        Flat: ``(X, Y, 0)``. Curved with radius R: ``(R sin(X/R), Y, R (1 - cos(X/R)))``, i.e.
        ``X`` is the arc length and the edges come toward the viewer.
        """
        xy = np.asarray(points_display_xy, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"points_display_xy must have shape (..., 2), got {xy.shape}")
        x, y = xy[..., 0], xy[..., 1]
        if self.curvature_radius is None:
            return np.stack([x, y, np.zeros_like(x)], axis=-1)
        r = self.curvature_radius
        return np.stack([r * np.sin(x / r), y, r * (1.0 - np.cos(x / r))], axis=-1)

    def surface_normals_local(self, points_display_xy: ArrayLike) -> NDArray[np.float64]:
        """Unit front normals ``(..., 3)`` (toward the viewer) at surface coordinates ``(..., 2)``."""
        xy = np.asarray(points_display_xy, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"points_display_xy must have shape (..., 2), got {xy.shape}")
        x = xy[..., 0]
        if self.curvature_radius is None:
            t = np.zeros_like(x)
        else:
            t = x / self.curvature_radius
        return np.stack([-np.sin(t), np.zeros_like(x), np.cos(t)], axis=-1)

    def surface_points_world(self, points_display_xy: ArrayLike) -> NDArray[np.float64]:
        """World points ``(..., 3)`` of surface coordinates ``(..., 2)`` (see :meth:`surface_points_local`)."""
        p = self.surface_points_local(points_display_xy)
        return p @ self.world_trans_display().T + np.asarray(self.center)

    def surface_normals_world(self, points_display_xy: ArrayLike) -> NDArray[np.float64]:
        """World unit front normals ``(..., 3)`` at surface coordinates ``(..., 2)``."""
        return self.surface_normals_local(points_display_xy) @ self.world_trans_display().T

    def corners_world(self) -> NDArray[np.float64]:
        """Corners of the active area in world, ``(4, 3)``.

        Order: bottom-left, bottom-right, top-right, top-left as seen from the front, i.e.
        counter-clockwise about the front normal.
        """
        w, h = self.width / 2, self.height / 2
        return self.surface_points_world([[-w, -h], [w, -h], [w, h], [-w, h]])

    def normal_world(self) -> NDArray[np.float64]:
        """Front normal ``(3,)`` of the display centre in world (default ``(0, 0, -1)``)."""
        return self.world_trans_display()[:, 2].copy()

    def polarization_direction_world(self) -> NDArray[np.float64]:
        """Unit electric-field direction ``(3,)`` in world at the display centre.

        ``cos(a) X_d + sin(a) Y_d`` with ``a = polarization_angle``; default ``(0, 1, 0)`` (vertical).
        """
        a = self.polarization_angle
        rot = self.world_trans_display()
        return math.cos(a) * rot[:, 0] + math.sin(a) * rot[:, 1]

    # ----------------------------------------------------------------------- pattern
    def pattern_rectangle(self, rows: tuple[int, int], cols: tuple[int, int], shape: tuple[int, int]) -> Rectangle:
        """Display-surface ``(x0, x1, y0, y1)`` in m of pixels ``rows`` x ``cols`` (half-open) of an ``(H, W)`` pattern.

        The pattern is stretched over the active area, row 0 at the top and column 0 at the left
        edge seen from the front; ``X`` is the arc length on a curved display.

        >>> DisplaySpec().pattern_rectangle((0, 18), (32, 64), (36, 64))  # the upper-right quadrant
        (0.0, 0.6048, 0.0, 0.3402)
        """
        (r0, r1), (c0, c1), (h, w) = rows, cols, shape
        x0, x1 = (-self.width / 2 + self.width * c / w for c in (c0, c1))
        y1, y0 = (self.height / 2 - self.height * r / h for r in (r0, r1))  # row 0 is the top
        return x0, x1, y0, y1

    def lit_rectangle(self, channel: int, *, uniform: bool = False) -> Rectangle | None:
        """Display-surface ``(x0, x1, y0, y1)`` in m bounding the pattern pixels that light ``channel`` (0, 1, 2).

        Every pattern value > 0 is light (the display emits ``radiance`` times the value). None
        where the channel is dark everywhere or, with ``uniform``, not exactly 1 all over the
        rectangle (which a constant emitter on it would then misrepresent).

        >>> DisplaySpec().lit_rectangle(0), DisplaySpec().lit_rectangle(2)  # rgb_halves: red right, blue up
        ((0.0, 0.6048, -0.3402, 0.3402), (-0.6048, 0.6048, 0.0, 0.3402))
        """
        img = self.pattern_image()[..., channel]
        rows, cols = np.nonzero(img > 0)
        if rows.size == 0:
            return None
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        if uniform and not np.all(img[r0:r1, c0:c1] == 1.0):
            return None
        return self.pattern_rectangle((r0, r1), (c0, c1), img.shape)

    def pattern_image(self, height: int | None = None, width: int | None = None) -> NDArray[np.float32]:
        """The emitted pattern ``(H, W, 3)`` float32 in [0, 1]: the commanded levels through ``tone_gamma``.

        The commanded levels are exactly {0, 1} for built-ins (which the tone response keeps).

        Row 0 is the TOP of the display and column 0 its LEFT edge, both as seen from the front.
        The renderer stretches it over the active area and samples it with nearest filtering.

        ``rgb_halves``: red on the right half (+X), green on the left half, blue on the upper half
        (+Y); quadrants upper-left cyan, upper-right magenta, lower-left green, lower-right red.

        Args:
            height: rows; default 36 for built-ins, the file's size for images.
            width: columns; default 64 for built-ins, the file's size for images. A file is
                resized with nearest filtering when a size is given.

        Raises:
            FileNotFoundError: ``pattern`` is neither a built-in name nor an existing file.
            ValueError: the file cannot be read as an image.
        """
        return tone_response(self._commanded_pattern(height, width), self.tone_gamma)

    def _commanded_pattern(self, height: int | None, width: int | None) -> NDArray[np.float32]:
        if self.pattern in BUILTIN_PATTERNS:
            h = DEFAULT_PATTERN_SIZE[0] if height is None else as_int(height, "height")
            w = DEFAULT_PATTERN_SIZE[1] if width is None else as_int(width, "width")
            if h < 1 or w < 1:
                raise ValueError(f"pattern size must be positive, got {h}x{w}")
            img = np.zeros((h, w, 3), dtype=np.float32)
            if self.pattern == "white":
                img[:] = 1.0
                return img
            right = (np.arange(w) + 0.5) / w >= 0.5  # column centres on the right half (+X)
            top = (np.arange(h) + 0.5) / h < 0.5  # rows on the upper half (+Y); row 0 = top
            img[:, right, 0] = 1.0
            img[:, ~right, 1] = 1.0
            img[top, :, 2] = 1.0
            return img
        return self._load_pattern_file(height, width)

    def _load_pattern_file(self, height: int | None, width: int | None) -> NDArray[np.float32]:
        path = Path(self.pattern)
        if not path.is_file():
            raise FileNotFoundError(
                f"display.pattern {self.pattern!r} is neither a built-in pattern {BUILTIN_PATTERNS} "
                "nor an existing file"
            )
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(path) as im:
                im.load()
                if height is not None or width is not None:
                    size = (im.width if width is None else int(width), im.height if height is None else int(height))
                    im = im.resize(size, Image.Resampling.NEAREST)
                if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                    a = np.asarray(im, dtype=np.float64) / 65535.0
                    img = np.repeat(a[..., None], 3, axis=-1)
                elif im.mode == "F":
                    img = np.repeat(np.asarray(im, dtype=np.float64)[..., None], 3, axis=-1)
                else:
                    img = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
        except (UnidentifiedImageError, OSError) as e:
            raise ValueError(f"{path}: cannot read the display pattern image: {e}") from None
        return np.clip(img, 0.0, 1.0).astype(np.float32)

    def pattern_rgb_at(self, points_display_xy: ArrayLike) -> NDArray[np.float32]:
        """Pattern value ``(..., 3)`` at display-local surface coordinates ``(..., 2)`` = (X, Y) in m.

        Nearest sampling of :meth:`pattern_image` at its default size, exactly what the renderer
        shows; 0 outside the active area. A numpy reference for tests.
        """
        xy = np.asarray(points_display_xy, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"points_display_xy must have shape (..., 2), got {xy.shape}")
        img = self.pattern_image()
        h, w = img.shape[:2]
        fx = xy[..., 0] / self.width + 0.5  # 0 at the left edge, 1 at the right
        fy = 0.5 - xy[..., 1] / self.height  # 0 at the top edge, 1 at the bottom
        inside = (fx >= 0) & (fx <= 1) & (fy >= 0) & (fy <= 1)
        col = np.clip(np.floor(np.where(inside, fx, 0.0) * w).astype(np.intp), 0, w - 1)
        row = np.clip(np.floor(np.where(inside, fy, 0.0) * h).astype(np.intp), 0, h - 1)
        return np.where(inside[..., None], img[row, col], np.float32(0.0)).astype(np.float32)


# --------------------------------------------------------------------------- camera


@dataclass(frozen=True)
class CameraSpec:
    """The RGB polarization camera: pinhole geometry plus the optics/sensor model.

    Defaults: FLIR BFS-U3-51S5PC-C (Sony IMX250MYR, 2448 x 2048 px at 3.45 um = 8.4456 x 7.0656
    mm) with an 8 mm lens: horizontal FOV ``2 atan(8.4456 / 16) = 55.65`` deg.

    Attributes:
        sensor_width_px: sensor columns W.
        sensor_height_px: sensor rows H.
        pixel_pitch: pixel size in m.
        focal_length: lens focal length in m.
        to_world: camera-to-world rigid transform, 4x4 nested tuples; the camera frame is OpenGL
            (x right, y up, looking along -z). Default identity: the camera frame is the world.
        model: QWP angle and retardance, analyzer extinction ratios, exposure brackets, sensor
            noise (:class:`pbrdf.sensor.camera.CameraModel`).
    """

    sensor_width_px: int = 2448
    sensor_height_px: int = 2048
    pixel_pitch: float = 3.45e-6
    focal_length: float = 8e-3
    to_world: tuple[tuple[float, ...], ...] = IDENTITY4
    model: CameraModel = field(default_factory=CameraModel)

    def __post_init__(self) -> None:
        for name in ("sensor_width_px", "sensor_height_px"):
            value = as_int(getattr(self, name), f"camera.{name}")
            if value < 1:
                raise ValueError(f"camera.{name} must be >= 1, got {value}")
            object.__setattr__(self, name, value)
        for name in ("pixel_pitch", "focal_length"):
            value = as_float(getattr(self, name), f"camera.{name}")
            if not value > 0:
                raise ValueError(f"camera.{name} must be > 0, got {value}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "to_world", as_matrix4(self.to_world, "camera.to_world"))
        check_rigid(self.to_world, "camera.to_world")
        if not isinstance(self.model, CameraModel):
            raise ValueError(f"camera.model must be a pbrdf.sensor.camera.CameraModel, got {type(self.model).__name__}")

    @property
    def sensor_width_m(self) -> float:
        """Sensor width in m (8.4456 mm by default)."""
        return self.sensor_width_px * self.pixel_pitch

    @property
    def sensor_height_m(self) -> float:
        """Sensor height in m (7.0656 mm by default)."""
        return self.sensor_height_px * self.pixel_pitch

    @property
    def focal_length_px(self) -> float:
        """Focal length in pixels (2318.84 by default)."""
        return self.focal_length / self.pixel_pitch

    @property
    def fov_x(self) -> float:
        """Full horizontal field of view in radians, ``2 atan(w / 2f)`` (0.9714, about 55.65 deg)."""
        return 2.0 * math.atan(self.sensor_width_m / (2.0 * self.focal_length))

    @property
    def fov_y(self) -> float:
        """Full vertical field of view in radians, ``2 atan(h / 2f)`` (about 47.6 deg)."""
        return 2.0 * math.atan(self.sensor_height_m / (2.0 * self.focal_length))

    def intrinsics(self) -> NDArray[np.float64]:
        """Pinhole matrix K ``(3, 3)`` in pixels, principal point at the sensor centre ``(W/2, H/2)``.

        Convention: :mod:`pbrdf.sensor.projection` (OpenGL camera frame, pixel ``(0, 0)``'s centre
        at ``(0.5, 0.5)``).
        """
        return projection.pinhole_intrinsics(self.focal_length_px, self.sensor_width_px, self.sensor_height_px)

    def camera_to_world(self) -> NDArray[np.float64]:
        """Camera-to-world transform ``(4, 4)``."""
        return np.array(self.to_world, dtype=np.float64)

    def world_to_camera(self) -> NDArray[np.float64]:
        """World-to-camera transform ``(4, 4)`` (rigid inverse of :meth:`camera_to_world`)."""
        return projection.rigid_inverse(self.camera_to_world())

    def project(self, points_world: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Project world points to pixel coordinates.

        Args:
            points_world: ``(..., 3)`` in m.

        Returns:
            ``(uv, depth)``: ``uv (..., 2)`` pixel coordinates (u right, v down, row 0 at the top;
            NaN for points with ``depth <= 0``) and ``depth (...)`` the distance in m along the
            viewing direction (-z of the camera frame), positive in front of the camera.
        """
        p = np.asarray(points_world, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ValueError(f"points_world must have shape (..., 3), got {p.shape}")
        return projection.camera_to_pixel(projection.transform_points(self.world_to_camera(), p), self.intrinsics())

    def out_of_view_px(self, points_world: ArrayLike, margin_px: float = 0.0) -> float:
        """How far, in pixels, the points leave the sensor shrunk by ``margin_px`` on every side.

        Returns:
            The largest overshoot over all points and the four edges: ``<= 0`` when every point
            projects inside (its magnitude is the smallest clearance), ``inf`` when a point is not
            in front of the camera.
        """
        uv, depth = self.project(points_world)
        if uv.size == 0:
            return -math.inf
        if not np.all(depth > 0):
            return math.inf
        u, v = uv[..., 0], uv[..., 1]
        w, h = self.sensor_width_px, self.sensor_height_px
        over = np.stack([margin_px - u, u - (w - margin_px), margin_px - v, v - (h - margin_px)])
        return float(np.max(over))


# --------------------------------------------------------------------------- rig


@dataclass(frozen=True)
class Rig:
    """Display plus camera; everything a renderer or a decoder needs to know about the hardware."""

    display: DisplaySpec = field(default_factory=DisplaySpec)
    camera: CameraSpec = field(default_factory=CameraSpec)

    def __post_init__(self) -> None:
        if not isinstance(self.display, DisplaySpec):
            raise ValueError(f"rig.display must be a DisplaySpec, got {type(self.display).__name__}")
        if not isinstance(self.camera, CameraSpec):
            raise ValueError(f"rig.camera must be a CameraSpec, got {type(self.camera).__name__}")

    def in_view(self, points_world: ArrayLike, margin_px: float = 0.0) -> bool:
        """True when every point is in front of the camera and projects inside the sensor.

        Args:
            points_world: ``(..., 3)`` in m.
            margin_px: keep this many pixels away from every sensor edge.
        """
        return self.camera.out_of_view_px(points_world, margin_px) <= 0.0

    # ----------------------------------------------------------------------- JSON
    def to_dict(self) -> dict:
        """JSON-friendly nested dict; :meth:`from_dict` inverts it exactly."""
        d = {f.name: getattr(self.display, f.name) for f in dataclasses.fields(DisplaySpec)}
        d["resolution"] = list(self.display.resolution)
        d["center"] = list(self.display.center)
        d["tone_gamma"] = list(self.display.tone_gamma)
        c = self.camera
        cam = {
            "sensor_width_px": c.sensor_width_px,
            "sensor_height_px": c.sensor_height_px,
            "pixel_pitch": c.pixel_pitch,
            "focal_length": c.focal_length,
            "to_world": [list(row) for row in c.to_world],
            "model": json.loads(json.dumps(c.model.to_dict())),
        }
        return {"display": d, "camera": cam}

    @classmethod
    def from_dict(cls, d: dict, base: Rig | None = None) -> Rig:
        """Build a rig from a (possibly partial) dict.

        Every key present overrides the corresponding number of ``base`` (default: the default
        rig), recursively, so ``{"camera": {"focal_length": 0.012}}`` changes only the focal
        length and ``{"camera": {"model": {"sensor": {"gain": 0.4}}}}`` only the gain.

        Raises:
            ValueError: unknown keys (listing the valid ones) or invalid values (naming the field).
        """
        full = merge_overrides((base or cls()).to_dict(), d, "rig")
        disp = dict(full["display"])
        cam = dict(full["camera"])
        try:
            model = CameraModel.from_dict(cam.pop("model"))
        except (TypeError, ValueError) as e:
            raise ValueError(f"camera.model: {e}") from None
        return cls(display=DisplaySpec(**disp), camera=CameraSpec(model=model, **cam))

    def save(self, path: str | os.PathLike) -> None:
        """Write the rig as JSON, atomically (temporary file + ``os.replace``)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> Rig:
        """Read a rig JSON file (complete or partial, see :meth:`from_dict`).

        Raises:
            FileNotFoundError: no such file.
            ValueError: invalid JSON, unknown keys or invalid values; the message starts with the path.
        """
        data = read_json_object(path, what="rig file")
        try:
            return cls.from_dict(data)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
