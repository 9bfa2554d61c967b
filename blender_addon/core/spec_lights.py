"""Lights and the world background of a scene spec: :class:`LightSpec`, :class:`EnvironmentSpec`.

They come from Blender scenes and keep Blender's units (see :class:`LightSpec`); the RGB preview
render (:func:`blender_addon.core.mitsuba_preview.preview_scene_dict`) uses them. The polarized
capture render ignores them: the real capture happens in a dark room lit by the display alone.
A module of their own keeps :mod:`.spec` to what every render needs; :class:`~.spec.SceneSpec`
holds them and :mod:`.spec` re-exports them. The key and name validators of every spec class live
here, in the lower of the two modules, so that :mod:`.spec` imports them without a cycle.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from pbrdf.sensor.spec_fields import IDENTITY4, as_float, as_matrix4, as_vec, check_rigid

__all__ = ["AREA_SHAPES", "LIGHT_KINDS", "EnvironmentSpec", "LightSpec"]

#: Light kinds, as Blender's light types POINT, SPOT, AREA, SUN.
LIGHT_KINDS = ("point", "spot", "area", "sun")
#: Shapes of area lights: Blender's SQUARE/RECTANGLE are ``rectangle``, DISK/ELLIPSE ``ellipse``.
AREA_SHAPES = ("rectangle", "ellipse")

_LIGHT_FIELDS = {"point": (), "sun": (), "area": ("size", "shape", "normalize"), "spot": ("spot_angle", "spot_blend")}


# Shared with spec.py (every spec class checks its JSON keys and name the same way).
def _check_keys(d: Any, cls_name: str, required: tuple[str, ...], optional: tuple[str, ...]) -> None:
    if not isinstance(d, dict):
        raise ValueError(f"{cls_name} must be a JSON object (dict), got {type(d).__name__}")
    valid = required + optional
    unknown = set(d) - set(valid)
    if unknown:
        raise ValueError(f"unknown {cls_name} keys {sorted(unknown)}; valid: {list(valid)}")
    missing = [k for k in required if k not in d]
    if missing:
        raise ValueError(f"{cls_name} {d.get('name', '')!r} is missing required keys {missing}")


def _check_name(value: Any, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{what} name must be a non-empty string, got {value!r}")
    return value


def _as_rgb(value: Any, name: str) -> tuple[float, float, float]:
    rgb = as_vec(value, 3, name)
    if not all(c >= 0 for c in rgb):
        raise ValueError(f"{name} must be >= 0 per channel, got {rgb}")
    return rgb  # type: ignore[return-value]


@dataclass(frozen=True)
class LightSpec:
    """A light of a Blender scene, in Blender's (Cycles') units.

    The light's local frame is Blender's: spot, area and sun lights shine along their local -z
    axis; an area light spans ``size`` along local x and y. Conversions to Mitsuba
    (:func:`blender_addon.core.mitsuba_preview.light_dict`, checked against Cycles renders):

    - point: radiant intensity ``I = power / (4 pi)`` W/sr in every direction (Blender's light
      radius, which softens shadows, is dropped: rendered as a true point).
    - spot: the same intensity inside the cone (Blender defines a spot's power as that of the
      point light it is cut from), ``cutoff = spot_angle / 2``, soft edge over ``spot_blend``.
    - area: a one-sided Lambertian emitter of area ``A`` emits ``pi A L``, so its radiance is
      ``L = power / (pi A)`` when ``normalize`` (Blender's default: the power does not depend on
      the size) and ``L = power / pi`` otherwise (the power is per square metre). Blender's
      ``spread`` below 180 degrees is not represented.
    - sun: irradiance ``power`` W/m^2 on a surface facing the sun (its angular size is dropped).

    Attributes:
        name: unique among the scene's lights.
        kind: one of :data:`LIGHT_KINDS`.
        to_world: light-to-world rigid transform (4x4 nested tuples).
        color: linear RGB colour multiplier (>= 0).
        power: Blender's ``energy`` times ``2 ** exposure``: watts for point, spot and area
            lights, irradiance in W/m^2 for the sun. >= 0.
        size: area only: ``(width, height)`` in m along local x and y.
        shape: area only: one of :data:`AREA_SHAPES`.
        normalize: area only: Blender's ``normalize`` flag.
        spot_angle: spot only: full cone angle in radians, in (0, pi].
        spot_blend: spot only: soft edge fraction in [0, 1].
    """

    name: str
    kind: Literal["point", "spot", "area", "sun"]
    to_world: tuple[tuple[float, ...], ...] = IDENTITY4
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    power: float = 1.0
    size: tuple[float, float] | None = None
    shape: str | None = None
    normalize: bool | None = None
    spot_angle: float | None = None
    spot_blend: float | None = None

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        _check_name(self.name, "light")
        where = f"light {self.name!r}"
        if self.kind not in LIGHT_KINDS:
            raise ValueError(f"{where}: unknown kind {self.kind!r}; valid: {list(LIGHT_KINDS)}")
        m = as_matrix4(self.to_world, f"{where}: to_world")
        check_rigid(m, f"{where}: to_world")
        put("to_world", m)
        put("color", _as_rgb(self.color, f"{where}: color"))
        put("power", as_float(self.power, f"{where}: power"))
        if self.power < 0:
            raise ValueError(f"{where}: power must be >= 0, got {self.power}")
        own = _LIGHT_FIELDS[self.kind]
        for name in ("size", "shape", "normalize", "spot_angle", "spot_blend"):
            if name not in own and getattr(self, name) is not None:
                raise ValueError(f"{where}: field {name} is not used by kind {self.kind!r} (fields: {list(own)})")
        if self.kind == "area":
            size = (1.0, 1.0) if self.size is None else as_vec(self.size, 2, f"{where}: size")
            if not all(v > 0 for v in size):
                raise ValueError(f"{where}: size must be > 0, got {size}")
            put("size", size)
            put("shape", "rectangle" if self.shape is None else self.shape)
            if self.shape not in AREA_SHAPES:
                raise ValueError(f"{where}: unknown shape {self.shape!r}; valid: {list(AREA_SHAPES)}")
            put("normalize", True if self.normalize is None else self.normalize)
            if not isinstance(self.normalize, bool):
                raise ValueError(f"{where}: normalize must be true or false, got {self.normalize!r}")
        elif self.kind == "spot":
            angle = math.radians(45.0) if self.spot_angle is None else as_float(self.spot_angle, f"{where}: spot_angle")
            if not 0 < angle <= math.pi:
                raise ValueError(f"{where}: spot_angle must be in (0, pi] radians, got {angle}")
            blend = 0.15 if self.spot_blend is None else as_float(self.spot_blend, f"{where}: spot_blend")
            if not 0 <= blend <= 1:
                raise ValueError(f"{where}: spot_blend must be in [0, 1], got {blend}")
            put("spot_angle", angle)
            put("spot_blend", blend)

    @property
    def area(self) -> float:
        """Emitting area in m^2 of an area light (``pi w h / 4`` for an ellipse)."""
        if self.kind != "area":
            raise ValueError(f"light {self.name!r} is a {self.kind} light, not an area light")
        w, h = self.size
        return w * h * (math.pi / 4 if self.shape == "ellipse" else 1.0)

    def radiance(self) -> tuple[float, float, float]:
        """Area lights: emitted radiance per channel, ``power color / (pi A)`` (normalized) or ``power color / pi``."""
        denom = math.pi * (self.area if self.normalize else 1.0)
        return tuple(self.power * c / denom for c in self.color)  # type: ignore[return-value]

    def intensity(self) -> tuple[float, float, float]:
        """Point and spot lights: radiant intensity per channel in W/sr, ``power color / (4 pi)``."""
        if self.kind not in ("point", "spot"):
            raise ValueError(f"light {self.name!r}: intensity is defined for point and spot lights, not {self.kind}")
        return tuple(self.power * c / (4 * math.pi) for c in self.color)  # type: ignore[return-value]

    def to_dict(self) -> dict:
        """JSON-friendly dict holding only the fields of this kind."""
        d: dict[str, Any] = {
            "name": self.name,
            "kind": self.kind,
            "to_world": [list(row) for row in self.to_world],
            "color": list(self.color),
            "power": self.power,
        }
        for name in _LIGHT_FIELDS[self.kind]:
            value = getattr(self, name)
            d[name] = list(value) if isinstance(value, tuple) else value
        return d

    @classmethod
    def from_dict(cls, d: dict) -> LightSpec:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError."""
        _check_keys(
            d, "light", ("name", "kind"),
            ("to_world", "color", "power", "size", "shape", "normalize", "spot_angle", "spot_blend"),
        )  # fmt: skip
        return cls(**d)


@dataclass(frozen=True)
class EnvironmentSpec:
    """The world background: a constant colour or an equirectangular image, times ``strength``.

    Attributes:
        color: linear RGB background (>= 0), used when there is no image (Blender's Background
            colour).
        strength: multiplier (Blender's Background strength), >= 0.
        image: path of an equirectangular image (EXR, HDR, PNG, ...) or None.
        to_world: rotation from the map's frame to the world. The map's frame is Blender's world
            frame: z up, the image centre looks along +x, the image's left half covers +y
            (Blender's Environment Texture with the default vector). Identity for a Blender scene
            exported without a rig or camera frame change.
    """

    color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    strength: float = 1.0
    image: str | None = None
    to_world: tuple[tuple[float, ...], ...] = IDENTITY4

    def __post_init__(self) -> None:
        object.__setattr__(self, "color", _as_rgb(self.color, "environment: color"))
        object.__setattr__(self, "strength", as_float(self.strength, "environment: strength"))
        if self.strength < 0:
            raise ValueError(f"environment: strength must be >= 0, got {self.strength}")
        if isinstance(self.image, os.PathLike):
            object.__setattr__(self, "image", os.fspath(self.image))
        if self.image is not None and (not isinstance(self.image, str) or not self.image):
            raise ValueError(f"environment: image must be a file path or None, got {self.image!r}")
        m = as_matrix4(self.to_world, "environment: to_world")
        check_rigid(m, "environment: to_world")
        if not np.allclose(np.asarray(m)[:3, 3], 0.0, atol=1e-9):
            raise ValueError("environment: to_world must be a pure rotation (no translation)")
        object.__setattr__(self, "to_world", m)

    def to_dict(self) -> dict:
        """JSON-friendly dict."""
        return {
            "color": list(self.color),
            "strength": self.strength,
            "image": self.image,
            "to_world": [list(row) for row in self.to_world],
        }

    @classmethod
    def from_dict(cls, d: dict) -> EnvironmentSpec:
        """Inverse of :meth:`to_dict`; unknown keys raise ValueError."""
        _check_keys(d, "environment", (), ("color", "strength", "image", "to_world"))
        return cls(**d)
