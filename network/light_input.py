"""Lighting-aware input: the display's irradiance per colour region at the object's distance, per pixel.

One frame cannot tell a dark object near the display from a bright one far away; the rig can. For
a rig, the camera's intrinsics and ONE object distance ``d`` (m along the viewing axis, as a tape
measure gives it), every pixel's viewing ray meets the plane ``z = -d`` at a point ``p``, and the
display's irradiance vector of each colour region ``c`` there is Lambert's closed form
(:func:`pbrdf.sensor.irradiance.irradiance_vectors`, no horizon clipping):

.. math:: \\Phi_c(p) = \\tfrac{1}{L} \\int_{\\text{region } c} L_c(y)\\, \\hat l \\,
          \\frac{\\cos\\theta_y}{\\lVert y - p \\rVert^2}\\, dA_y

in units of the display radiance ``L`` (so ``n . Phi_c`` is the projected solid angle of region
``c``'s light; ``L_c(y)`` falls with the emission angle as the display's profile ``cos^p`` says,
:mod:`pbrdf.sensor.display_response`). :func:`light_channels` returns ``LIGHT_GAIN * Phi`` as 9 channels ``3 c + k``
(region ``c`` = R, G, B; component ``k`` = x, y, z of the OpenGL camera frame), the same gain as
the calibrated maps (:data:`network.data.CALIBRATED_GAIN`), so a calibrated map divided by its
region's ``n . channels`` is ``albedo / pi``-like for a Lambertian surface, independent of the
distance. The field is smooth over the image (the display is behind the camera, never in view),
so it is computed on a coarse grid of pixel positions and interpolated bilinearly
(:data:`LIGHT_GRID`; accuracy and time in docs/measurements/network.md, "Lighting-aware input").

Distances: :func:`check_distance` accepts :data:`DISTANCE_RANGE_M`; a rendered sample's distance is
the median of its ground-truth depth over the mask (:func:`sample_distance`), never per-pixel
depth; a capture's is ``distance_m`` (:mod:`pbrdf.data.capture`), else
:data:`pbrdf.data.capture_meta.DEFAULT_DISTANCE_M` with a warning (:func:`resolve_distance`).
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M
from pbrdf.sensor import projection
from pbrdf.sensor.irradiance import irradiance_vectors
from pbrdf.sensor.patches import constant_patches

__all__ = [
    "DISTANCE_RANGE_M",
    "LightGeometry",
    "crop_light",
    "sidecar_rig",
    "LIGHT_CHANNELS",
    "LIGHT_GAIN",
    "LIGHT_GRID",
    "check_distance",
    "light_channels",
    "light_tensor",
    "per_map_light",
    "resolve_distance",
    "sample_distance",
    "sample_light",
    "sidecar_light",
    "scene_light",
]

#: Channels of the light input: 3 colour regions x 3 camera-frame components.
LIGHT_CHANNELS = 9
#: Gain of the light channels: :data:`network.data.CALIBRATED_GAIN` (not imported: network.data imports this module).
LIGHT_GAIN = 3.5
#: Largest coarse grid (points per side) the field is computed on before bilinear interpolation.
LIGHT_GRID = 24
#: Plausible object distances in m. Below 0.2 m an object 5-10 cm across fills the view and sits
#: closer than the display is wide from the camera (the lens' close focus); beyond 3 m the display's
#: irradiance is under 4 % of that at 0.5 m and the object a few pixels wide: a value outside is
#: a typo (cm for m) or the wrong field.
DISTANCE_RANGE_M = (0.2, 3.0)


def check_distance(distance: Any, where: str = "distance_m") -> float:
    """``distance`` as a float in :data:`DISTANCE_RANGE_M`, else one ValueError line naming ``where``.

    Example:
        >>> check_distance(0.7)
        0.7
        >>> check_distance(70, "distance_m")
        Traceback (most recent call last):
        ...
        ValueError: distance_m must be a distance in metres within 0.2-3 m (the rig's plausible range); got 70
    """
    lo, hi = DISTANCE_RANGE_M
    try:
        value = float(distance)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(distance, bool) or not (math.isfinite(value) and lo <= value <= hi):
        raise ValueError(
            f"{where} must be a distance in metres within {lo:g}-{hi:g} m (the rig's plausible range); got {distance!r}"
        )
    return value


def resolve_distance(distance: float | None, where: str = "input") -> tuple[float, bool]:
    """The distance to use and whether it was measured: ``distance`` checked, else the default with a warning.

    Example:
        >>> resolve_distance(0.9)
        (0.9, True)
    """
    if distance is not None:
        return check_distance(distance, f"{where}: distance_m"), True
    warnings.warn(
        f"{where}: no object distance (capture.json distance_m, --distance): the light input assumes "
        f"{DEFAULT_DISTANCE_M} m, so albedo is relative to that guess",
        stacklevel=2,
    )
    return DEFAULT_DISTANCE_M, False


def sample_distance(depth: ArrayLike, mask: ArrayLike, where: str = "sample") -> float:
    """A rendered sample's one distance: the median of its ground-truth depth over the mask (m).

    Example:
        >>> sample_distance(np.array([[0.5, 0.6], [0.9, 0.0]]), np.array([[1, 1], [1, 0]]))
        0.6
    """
    d = np.asarray(depth, dtype=np.float64)[np.asarray(mask, dtype=bool)]
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        raise ValueError(f"{where}: depth has no positive value inside the mask (no object distance)")
    return float(np.median(d))


def _interp_matrix(n: int, g: int) -> NDArray[np.float64]:
    """``(n, g)`` linear interpolation from ``g`` samples at ``linspace(0.5, n - 0.5, g)`` to ``n`` pixel centres."""
    if g == n:
        return np.eye(n)
    pos = np.arange(n) * (g - 1) / max(n - 1, 1)  # pixel centre i + 0.5 in grid units
    i0 = np.clip(np.floor(pos).astype(np.intp), 0, g - 2)
    t = pos - i0
    m = np.zeros((n, g))
    m[np.arange(n), i0] = 1 - t
    m[np.arange(n), i0 + 1] += t
    return m


def light_channels(
    rig, intrinsics: ArrayLike, shape: tuple[int, int], distance_m: float, *, grid: int | None = LIGHT_GRID
) -> NDArray[np.float32]:
    """``(9, H, W)`` light input: ``LIGHT_GAIN`` times the display's irradiance vectors per region at depth ``d``.

    Args:
        rig: :class:`pbrdf.sensor.rig.Rig` (display geometry and pattern, camera pose).
        intrinsics: ``K (3, 3)`` of the image grid (a crop's: :func:`pbrdf.sensor.projection.crop_intrinsics`).
        shape: ``(H, W)``.
        distance_m: the object's distance along the viewing axis in m (:func:`check_distance`).
        grid: at most this many points per side are computed exactly, the rest interpolated
            bilinearly; None computes every pixel.

    Returns:
        float32 ``(9, H, W)``, channel ``3 c + k``: component ``k`` of region ``c``'s irradiance
        vector in units of the display radiance, times :data:`LIGHT_GAIN`; finite.

    Example:
        >>> from pbrdf.sensor.rig import Rig
        >>> rig = Rig()
        >>> k = projection.pinhole_intrinsics(200.0, 32, 32)
        >>> near, far = (light_channels(rig, k, (32, 32), d) for d in (0.5, 1.0))
        >>> bool((near[[2, 5]] > far[[2, 5]]).all())  # red and green light toward +z (the display) fall with distance
        True
    """
    h, w = shape
    d = check_distance(distance_m)
    gy, gx = (h, w) if grid is None else (min(h, max(2, grid)), min(w, max(2, grid)))
    k = np.asarray(intrinsics, dtype=np.float64)
    u = np.linspace(0.5, w - 0.5, gx) if gx < w else np.arange(w) + 0.5
    v = np.linspace(0.5, h - 0.5, gy) if gy < h else np.arange(h) + 0.5
    uu, vv = np.meshgrid(u, v, indexing="xy")
    rays = np.stack([(uu - k[0, 2]) / k[0, 0], -(vv - k[1, 2]) / k[1, 1], -np.ones_like(uu)], axis=-1)
    verts, radiance = _camera_patches(rig.display, rig.camera)
    phi = irradiance_vectors(verts, radiance, (d * rays).reshape(-1, 3), exponent=rig.display.emission_exponent)
    coarse = (LIGHT_GAIN * phi).reshape(gy, gx, LIGHT_CHANNELS).transpose(2, 0, 1)  # (9, gy, gx)
    out = _interp_matrix(h, gy) @ coarse @ _interp_matrix(w, gx).T  # separable bilinear, (9, H, W)
    return np.ascontiguousarray(out, dtype=np.float32)


@functools.lru_cache(maxsize=16)
def _camera_patches(display, camera) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The display's constant patches in the camera frame and their radiance / display radiance (frozen specs)."""
    patches = constant_patches(display)
    verts = projection.transform_points(camera.world_to_camera(), patches.vertices)
    return verts, patches.radiance / display.radiance


def light_tensor(rig, intrinsics: ArrayLike, shape: tuple[int, int], distance_m: float) -> torch.Tensor:
    """:func:`light_channels` as a float32 tensor ``(9, H, W)``."""
    return torch.from_numpy(light_channels(rig, intrinsics, shape, distance_m))


def per_map_light(light: torch.Tensor, colors: tuple[int, ...]) -> torch.Tensor:
    """``(B, 9, H, W)`` light channels -> ``(B, M, 3, H, W)``: each map's own region's vector (``colors[n]``).

    Example:
        >>> per_map_light(torch.arange(9.0).reshape(1, 9, 1, 1), (2, 0))[0, :, :, 0, 0].tolist()
        [[6.0, 7.0, 8.0], [0.0, 1.0, 2.0]]
    """
    b, _, h, w = light.shape
    index = torch.tensor([3 * c + k for c in colors for k in range(3)], device=light.device)
    return light.index_select(1, index).reshape(b, len(colors), 3, h, w)


@dataclass(frozen=True)
class LightGeometry:
    """What the light input of one capture needs: the rig, the maps' intrinsics and the object distance.

    Attributes:
        rig: :class:`pbrdf.sensor.rig.Rig`.
        intrinsics: ``K (3, 3)`` of the full maps' grid.
        distance_m: the object distance used, m (checked: :func:`check_distance`).
        measured: whether ``distance_m`` was given (capture.json, ``--distance``, a sample's depth) or
            the :data:`pbrdf.data.capture_meta.DEFAULT_DISTANCE_M` fallback.
        source: where the distance came from, for the output's sidecar (e.g. ``"capture.json"``).
    """

    rig: Any
    intrinsics: NDArray[np.float64]
    distance_m: float
    measured: bool = True
    source: str = "given"

    @classmethod
    def resolve(cls, rig, intrinsics: ArrayLike, distance: float | None, source: str, where: str) -> LightGeometry:
        """The geometry with ``distance`` checked, or the default distance with a warning when it is None."""
        d, measured = resolve_distance(distance, where)
        return cls(rig, np.asarray(intrinsics, dtype=np.float64), d, measured, source if measured else "default")

    def to_dict(self) -> dict[str, Any]:
        """JSON record of the distance used: ``{"distance_m", "measured", "source"}``."""
        return {"distance_m": self.distance_m, "measured": self.measured, "source": self.source}


def crop_light(geometry: LightGeometry, box: tuple[int, int, int, int], size: tuple[int, int]) -> torch.Tensor:
    """``(1, 9, *size)`` light input of the crop ``box`` ``(y0, x0, y1, x1)`` of the maps, resized to ``size``."""
    k = projection.crop_intrinsics(geometry.intrinsics, box, size)
    return light_tensor(geometry.rig, k, size, geometry.distance_m)[None]


def sidecar_rig(meta: Mapping[str, Any], where: str):
    """The rig of a sample's sidecar (or a capture's metadata): its ``"rig"``, else the default rig."""
    from pbrdf.sensor.rig import Rig  # noqa: PLC0415

    try:
        return Rig.from_dict(meta["rig"]) if "rig" in meta else Rig()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: invalid rig: {exc}") from None


def sample_light(meta: Mapping[str, Any], depth: ArrayLike, mask: ArrayLike, shape: tuple[int, int], where: str):
    """A rendered sample's light input ``(9, *shape)`` and its distance, from its sidecar, depth and mask.

    The rig and intrinsics are the sidecar's (:func:`pbrdf.data.sample.sample_intrinsics`, of the
    rendered grid, rescaled to ``shape``); the distance is :func:`sample_distance`.
    """
    dist = sample_distance(depth, mask, where)
    return sidecar_light(meta, np.asarray(mask).shape[:2], shape, dist, where), dist


def sidecar_light(meta: Mapping[str, Any], hw: tuple[int, int], shape: tuple[int, int], distance: float, where: str):
    """:func:`sample_light` at a known ``distance``: the sidecar's rig and intrinsics of the rendered ``hw`` grid."""
    from pbrdf.data.sample import sample_intrinsics  # noqa: PLC0415

    hw = (int(hw[0]), int(hw[1]))
    k = projection.crop_intrinsics(sample_intrinsics(meta, hw, where), (0, 0, *hw), shape)
    return light_tensor(sidecar_rig(meta, where), k, shape, distance)


def scene_light(model, inp, depth: ArrayLike | None, region: ArrayLike, scale: float = 1.0) -> LightGeometry | None:
    """The light geometry of an evaluated scene for a ``light_input`` model (None for a light-blind one).

    The distance is the scene's tape measure: the median of its true ``depth`` over ``region``
    (:func:`sample_distance`), else the capture's ``distance_m``, else the default (with a
    warning); times ``scale`` (``1 + e`` for a distance off by ``e``, :mod:`network.distance_sensitivity`).

    Args:
        model: the network (its ``config.light_input`` decides).
        inp: the scene's :class:`network.infer.InferenceInput` (rig, intrinsics, ``distance_m``).
        depth: ``(H, W)`` true depth in m, or None.
        region: ``(H, W)`` the object's pixels.
        scale: factor on the distance.
    """
    if not model.config.light_input:
        return None
    if depth is not None and np.any(np.asarray(depth)[np.asarray(region, dtype=bool)] > 0):
        distance, source = sample_distance(depth, region), "median true depth"
    else:
        distance, source = inp.distance_m, "capture.json"
    geo = LightGeometry.resolve(inp.rig, inp.intrinsics, distance, source, "scene")
    if scale == 1.0:
        return geo
    scaled = check_distance(geo.distance_m * scale, f"distance x {scale:g}")
    return LightGeometry(geo.rig, geo.intrinsics, scaled, geo.measured, f"{geo.source} x {scale:g}")
