"""Scene spec: the rig, objects with poses, their polarimetric materials, lights and the seed.

A :class:`SceneSpec` is what the renderer consumes and what a dataset sample's JSON sidecar
records: it round-trips through JSON exactly (``SceneSpec.from_dict(s.to_dict()) == s``).
Every material carries its Disney parameters (albedo, roughness, metallic), the ground truth of
the material maps, beside what the renderer uses (an analytic polarimetric BSDF or a measured
pBRDF table).

Convention: ``to_world`` matrices map object coordinates (metres after the transform) to the
world frame of :mod:`pbrdf.sensor.rig` (the default camera frame: x right, y up, camera
looking along -z). Relative file paths are relative to the current working directory.

Lights and the environment (:class:`LightSpec`, :class:`EnvironmentSpec`) come from Blender
scenes and keep Blender's units (see :class:`LightSpec`); the RGB preview render
(:func:`blender_addon.core.mitsuba_preview.preview_scene_dict`) uses them. The polarized capture
render ignores them: the real capture happens in a dark room lit by the display alone.

This module stays whole (about 630 lines) on purpose: the five spec classes are one JSON
document, share its key, name and colour validators, and :meth:`SceneSpec.validate` checks them
against each other (material and light names, files). Lights in a module of their own would
need those validators from here while this module needs the lights: an import cycle, or a third
module for some 40 lines of validators.
"""

from __future__ import annotations

import copy
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pbrdf.sensor.rig import (
    IDENTITY4,
    Rig,
    _as_float,
    _as_int,
    _as_matrix4,
    _as_vec,
    _check_rigid,
    _read_json,
    atomic_write_text,
)

from . import assets
from .generated_shapes import GENERATED_SHAPES
from .procedural import PROCEDURAL_SHAPES
from .unseen_shapes import UNSEEN_SHAPES

__all__ = [
    "AREA_SHAPES",
    "LIGHT_KINDS",
    "MATERIAL_KINDS",
    "EnvironmentSpec",
    "LightSpec",
    "MaterialSpec",
    "ObjectSpec",
    "SceneSpec",
]

#: Material kinds: ``pplastic`` (Mitsuba's polarized plastic), ``conductor`` (rough conductor with
#: a complex IOR per channel), ``measured`` (a pBRDF tensor file for ``measured_polarized``),
#: ``diffuse`` (Lambertian; depolarizing, e.g. a Blender Diffuse BSDF or a Principled BSDF
#: without specular).
MATERIAL_KINDS = ("pplastic", "conductor", "measured", "diffuse")

_KIND_FIELDS = {"pplastic": ("ior",), "conductor": ("eta", "k"), "measured": ("table",), "diffuse": ()}

#: Light kinds, as Blender's light types POINT, SPOT, AREA, SUN.
LIGHT_KINDS = ("point", "spot", "area", "sun")
#: Shapes of area lights: Blender's SQUARE/RECTANGLE are ``rectangle``, DISK/ELLIPSE ``ellipse``.
AREA_SHAPES = ("rectangle", "ellipse")

_LIGHT_FIELDS = {"point": (), "sun": (), "area": ("size", "shape", "normalize"), "spot": ("spot_angle", "spot_blend")}


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


@dataclass(frozen=True)
class MaterialSpec:
    """A polarimetric material and its Disney parameters (the ground truth of the material maps).

    Attributes:
        name: unique name that objects refer to.
        kind: one of :data:`MATERIAL_KINDS`.
        albedo: Disney base colour, linear RGB in [0, 1].
        roughness: Disney roughness r in [0, 1]; the GGX alpha is ``r**2``.
        metallic: Disney metallic in [0, 1].
        ior: ``pplastic`` only: real index of refraction of the coating (default 1.5).
        eta: ``conductor`` only: real part n of the complex IOR ``n - ik`` per channel (R, G, B).
        k: ``conductor`` only: extinction coefficient k >= 0 per channel (R, G, B).
        table: ``measured`` only: path of a Mitsuba pBRDF tensor file.

    Fields that do not belong to the kind must be None (``ior`` is filled in for ``pplastic``).
    """

    name: str
    kind: Literal["pplastic", "conductor", "measured"]
    albedo: tuple[float, float, float]
    roughness: float
    metallic: float
    ior: float | None = None
    eta: tuple[float, float, float] | None = None
    k: tuple[float, float, float] | None = None
    table: str | None = None

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        _check_name(self.name, "material")
        where = f"material {self.name!r}"
        if isinstance(self.table, os.PathLike):
            put("table", os.fspath(self.table))
        if self.kind not in MATERIAL_KINDS:
            raise ValueError(f"{where}: unknown kind {self.kind!r}; valid: {list(MATERIAL_KINDS)}")
        put("albedo", _as_vec(self.albedo, 3, f"{where}: albedo"))
        if not all(0.0 <= a <= 1.0 for a in self.albedo):
            raise ValueError(f"{where}: albedo must be in [0, 1], got {self.albedo}")
        for name in ("roughness", "metallic"):
            value = _as_float(getattr(self, name), f"{where}: {name}")
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{where}: {name} must be in [0, 1], got {value}")
            put(name, value)
        own = _KIND_FIELDS[self.kind]
        for name in ("ior", "eta", "k", "table"):
            if name not in own and getattr(self, name) is not None:
                raise ValueError(f"{where}: field {name} is not used by kind {self.kind!r} (fields: {list(own)})")
        if self.kind == "pplastic":
            put("ior", 1.5 if self.ior is None else _as_float(self.ior, f"{where}: ior"))
            if not self.ior > 0:
                raise ValueError(f"{where}: ior must be > 0, got {self.ior}")
        elif self.kind == "conductor":
            for name in ("eta", "k"):
                if getattr(self, name) is None:
                    raise ValueError(f"{where}: kind 'conductor' requires {name} (per channel R, G, B)")
                put(name, _as_vec(getattr(self, name), 3, f"{where}: {name}"))
            if not all(n > 0 for n in self.eta):
                raise ValueError(f"{where}: eta must be > 0, got {self.eta}")
            if not all(k >= 0 for k in self.k):
                raise ValueError(f"{where}: k must be >= 0, got {self.k}")
        elif self.kind == "measured" and (not isinstance(self.table, str) or not self.table):
            raise ValueError(f"{where}: kind 'measured' requires table (path of a pBRDF tensor file)")

    @classmethod
    def plastic(cls, name: str, albedo: tuple[float, float, float], roughness: float, ior: float = 1.5) -> MaterialSpec:
        """Dielectric-coated diffuse material (``pplastic``), metallic 0."""
        return cls(name=name, kind="pplastic", albedo=albedo, roughness=roughness, metallic=0.0, ior=ior)

    @classmethod
    def metal(
        cls,
        name: str,
        eta: tuple[float, float, float],
        k: tuple[float, float, float],
        roughness: float,
        albedo: tuple[float, float, float] | None = None,
    ) -> MaterialSpec:
        """Rough conductor with complex IOR ``eta - ik`` per channel, metallic 1.

        The albedo defaults to the normal-incidence Fresnel reflectance per channel,

        .. math:: R_0 = \\left|\\frac{\\tilde n - 1}{\\tilde n + 1}\\right|^2 = \\frac{(n-1)^2 + k^2}{(n+1)^2 + k^2}.

        Example: gold at (650, 550, 450) nm, n = (0.16, 0.43, 1.38), k = (3.5, 2.4, 1.9)
        (Johnson and Christy 1972, rounded) gives R0 of about (0.95, 0.78, 0.40).
        """
        if albedo is None:
            n = np.broadcast_to(np.asarray(eta, dtype=np.float64), (3,))
            kk = np.broadcast_to(np.asarray(k, dtype=np.float64), (3,))
            r0 = ((n - 1) ** 2 + kk**2) / ((n + 1) ** 2 + kk**2)
            albedo = tuple(float(v) for v in np.clip(r0, 0.0, 1.0))
        return cls(name=name, kind="conductor", albedo=albedo, roughness=roughness, metallic=1.0, eta=eta, k=k)

    @classmethod
    def diffuse(cls, name: str, albedo: tuple[float, float, float], roughness: float = 1.0) -> MaterialSpec:
        """Lambertian material (depolarizing), metallic 0; ``roughness`` is only the Disney ground truth."""
        return cls(name=name, kind="diffuse", albedo=albedo, roughness=roughness, metallic=0.0)

    @classmethod
    def measured(
        cls, name: str, table: str, albedo: tuple[float, float, float], roughness: float, metallic: float
    ) -> MaterialSpec:
        """Measured or generated pBRDF table with its fitted Disney parameters."""
        return cls(name=name, kind="measured", albedo=albedo, roughness=roughness, metallic=metallic, table=str(table))

    def to_dict(self) -> dict:
        """JSON-friendly dict holding only the fields of this kind."""
        d: dict[str, Any] = {
            "name": self.name,
            "kind": self.kind,
            "albedo": list(self.albedo),
            "roughness": self.roughness,
            "metallic": self.metallic,
        }
        for name in _KIND_FIELDS[self.kind]:
            value = getattr(self, name)
            d[name] = list(value) if isinstance(value, tuple) else value
        return d

    @classmethod
    def from_dict(cls, d: dict) -> MaterialSpec:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError."""
        _check_keys(d, "material", ("name", "kind", "albedo", "roughness", "metallic"), ("ior", "eta", "k", "table"))
        return cls(**d)


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the scene.

    Attributes:
        name: unique name.
        mesh: path of a PLY/OBJ/GLB/GLTF file or ``builtin:<shape>[?key=value&...]``
            (see :func:`blender_addon.core.assets.load_mesh`).
        to_world: object-to-world affine transform (4x4 nested tuples) with a positive
            determinant (no mirroring, which would turn the normals inside out).
        material: name of a :class:`MaterialSpec` of the scene.
    """

    name: str
    mesh: str
    to_world: tuple[tuple[float, ...], ...] = IDENTITY4
    material: str = ""

    def __post_init__(self) -> None:
        _check_name(self.name, "object")
        where = f"object {self.name!r}"
        if isinstance(self.mesh, os.PathLike):
            object.__setattr__(self, "mesh", os.fspath(self.mesh))
        if not isinstance(self.mesh, str) or not self.mesh:
            raise ValueError(f"{where}: mesh must be a file path or 'builtin:<shape>', got {self.mesh!r}")
        builtin = assets.parse_builtin(self.mesh)
        if builtin is not None and builtin[0] not in PROCEDURAL_SHAPES + GENERATED_SHAPES + UNSEEN_SHAPES:
            valid = list(PROCEDURAL_SHAPES + GENERATED_SHAPES + UNSEEN_SHAPES)
            raise ValueError(f"{where}: unknown builtin shape {builtin[0]!r}; valid: {valid}")
        m = _as_matrix4(self.to_world, f"{where}: to_world")
        if not np.linalg.det(np.asarray(m)[:3, :3]) > 0:
            raise ValueError(f"{where}: to_world must have a positive determinant (no mirroring or collapse)")
        object.__setattr__(self, "to_world", m)
        if not isinstance(self.material, str) or not self.material:
            raise ValueError(f"{where}: material must name a material of the scene, got {self.material!r}")

    def to_dict(self) -> dict:
        """JSON-friendly dict."""
        return {
            "name": self.name,
            "mesh": self.mesh,
            "to_world": [list(row) for row in self.to_world],
            "material": self.material,
        }

    @classmethod
    def from_dict(cls, d: dict) -> ObjectSpec:
        """Inverse of :meth:`to_dict` (``to_world`` defaults to the identity)."""
        _check_keys(d, "object", ("name", "mesh", "material"), ("to_world",))
        return cls(**d)


def _as_rgb(value: Any, name: str) -> tuple[float, float, float]:
    rgb = _as_vec(value, 3, name)
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
        m = _as_matrix4(self.to_world, f"{where}: to_world")
        _check_rigid(m, f"{where}: to_world")
        put("to_world", m)
        put("color", _as_rgb(self.color, f"{where}: color"))
        put("power", _as_float(self.power, f"{where}: power"))
        if self.power < 0:
            raise ValueError(f"{where}: power must be >= 0, got {self.power}")
        own = _LIGHT_FIELDS[self.kind]
        for name in ("size", "shape", "normalize", "spot_angle", "spot_blend"):
            if name not in own and getattr(self, name) is not None:
                raise ValueError(f"{where}: field {name} is not used by kind {self.kind!r} (fields: {list(own)})")
        if self.kind == "area":
            size = (1.0, 1.0) if self.size is None else _as_vec(self.size, 2, f"{where}: size")
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
            angle = (
                math.radians(45.0) if self.spot_angle is None else _as_float(self.spot_angle, f"{where}: spot_angle")
            )
            if not 0 < angle <= math.pi:
                raise ValueError(f"{where}: spot_angle must be in (0, pi] radians, got {angle}")
            blend = 0.15 if self.spot_blend is None else _as_float(self.spot_blend, f"{where}: spot_blend")
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
        object.__setattr__(self, "strength", _as_float(self.strength, "environment: strength"))
        if self.strength < 0:
            raise ValueError(f"environment: strength must be >= 0, got {self.strength}")
        if isinstance(self.image, os.PathLike):
            object.__setattr__(self, "image", os.fspath(self.image))
        if self.image is not None and (not isinstance(self.image, str) or not self.image):
            raise ValueError(f"environment: image must be a file path or None, got {self.image!r}")
        m = _as_matrix4(self.to_world, "environment: to_world")
        _check_rigid(m, "environment: to_world")
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


@dataclass(frozen=True)
class SceneSpec:
    """Rig, objects, materials and seed of one synthetic capture.

    Attributes:
        rig: display and camera.
        objects: the objects (names unique).
        materials: the materials objects refer to (names unique).
        seed: non-negative integer seeding everything random about rendering this scene.
        metadata: free JSON-serialisable information (asset ids, generator versions, ...).
        lights: lights of a Blender scene (names unique); only the preview render uses them.
        environment: world background of a Blender scene, or None (black); preview only.
    """

    rig: Rig = field(default_factory=Rig)
    objects: tuple[ObjectSpec, ...] = ()
    materials: tuple[MaterialSpec, ...] = ()
    seed: int = 0
    metadata: dict = field(default_factory=dict)
    lights: tuple[LightSpec, ...] = ()
    environment: EnvironmentSpec | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.rig, Rig):
            raise ValueError(f"scene rig must be a Rig, got {type(self.rig).__name__}")
        if self.environment is not None and not isinstance(self.environment, EnvironmentSpec):
            raise ValueError(
                f"scene environment must be an EnvironmentSpec or None, got {type(self.environment).__name__}"
            )
        for name, cls in (("objects", ObjectSpec), ("materials", MaterialSpec), ("lights", LightSpec)):
            items = getattr(self, name)
            if isinstance(items, (str, bytes, dict)) or not hasattr(items, "__iter__"):
                raise ValueError(f"scene {name} must be a sequence of {cls.__name__}, got {type(items).__name__}")
            items = tuple(items)
            for item in items:
                if not isinstance(item, cls):
                    raise ValueError(f"scene {name} must hold {cls.__name__} items, got {type(item).__name__}")
            object.__setattr__(self, name, items)
        seed = _as_int(self.seed, "scene seed")
        if seed < 0:
            raise ValueError(f"scene seed must be >= 0, got {seed}")
        object.__setattr__(self, "seed", seed)
        if not isinstance(self.metadata, dict):
            raise ValueError(f"scene metadata must be a dict, got {type(self.metadata).__name__}")
        try:
            # Normalised through JSON so that a round trip is exact (tuples become lists).
            metadata = json.loads(json.dumps(self.metadata, allow_nan=False))
        except (TypeError, ValueError) as e:
            raise ValueError(f"scene metadata must be JSON-serialisable: {e}") from None
        object.__setattr__(self, "metadata", metadata)

    __hash__ = None  # type: ignore[assignment]  # metadata is a dict

    def material(self, name: str) -> MaterialSpec:
        """The material called ``name``; KeyError listing the known names otherwise."""
        for m in self.materials:
            if m.name == name:
                return m
        raise KeyError(f"unknown material {name!r}; known: {[m.name for m in self.materials]}")

    # ----------------------------------------------------------------------- validation
    def validate(self, check_files: bool = True) -> None:
        """Check the scene is renderable; raise on the first problem with a one-line message.

        Checks: duplicate object or material names, objects referring to unknown materials, and
        every object fully inside the camera view (all its mesh vertices project inside the
        sensor, in front of the camera). With ``check_files``: mesh files, pBRDF tables and the
        display pattern image exist, and file meshes load; builtin meshes are always checked.

        Raises:
            ValueError: a naming, reference or view problem (object and pixel overshoot named).
            FileNotFoundError: a missing mesh, table or pattern file (``check_files`` only).
        """
        for what, items in (("object", self.objects), ("material", self.materials), ("light", self.lights)):
            seen: set[str] = set()
            for item in items:
                if item.name in seen:
                    raise ValueError(f"duplicate {what} name {item.name!r}")
                seen.add(item.name)
        known = [m.name for m in self.materials]
        for obj in self.objects:
            if obj.material not in known:
                raise ValueError(f"object {obj.name!r} references unknown material {obj.material!r}; known: {known}")
        if check_files:
            for m in self.materials:
                if m.kind == "measured" and not Path(m.table).is_file():
                    raise FileNotFoundError(f"material {m.name!r}: pBRDF table not found: {m.table}")
            env = self.environment
            if env is not None and env.image is not None and not Path(env.image).is_file():
                raise FileNotFoundError(f"environment image not found: {env.image}")
            self.rig.display.pattern_image()  # raises FileNotFoundError for a missing pattern file
        cam = self.rig.camera
        for obj in self.objects:
            builtin = assets.parse_builtin(obj.mesh) is not None
            if not builtin and not check_files:
                continue
            if not builtin and not Path(obj.mesh).is_file():
                raise FileNotFoundError(f"object {obj.name!r}: mesh file not found: {obj.mesh}")
            try:
                mesh = assets.load_mesh(obj.mesh)
            except ValueError as e:
                raise ValueError(f"object {obj.name!r}: {e}") from None
            m = np.asarray(obj.to_world)
            points = np.asarray(mesh.vertices) @ m[:3, :3].T + m[:3, 3]
            over = cam.out_of_view_px(points)
            if over > 0:
                if np.isinf(over):
                    depth = cam.project(points)[1]
                    raise ValueError(
                        f"object {obj.name!r} is not in front of the camera (nearest depth {depth.min():.3f} m)"
                    )
                uv = cam.project(points)[0]
                raise ValueError(
                    f"object {obj.name!r} leaves the camera view by {over:.1f} px (projects to u in "
                    f"[{uv[:, 0].min():.1f}, {uv[:, 0].max():.1f}], v in [{uv[:, 1].min():.1f}, {uv[:, 1].max():.1f}]; "
                    f"sensor {cam.sensor_width_px}x{cam.sensor_height_px})"
                )

    # ----------------------------------------------------------------------- JSON
    def to_dict(self) -> dict:
        """JSON-friendly nested dict; :meth:`from_dict` inverts it exactly.

        ``lights`` and ``environment`` appear only when the scene has them, so scenes without
        them serialise as before.
        """
        d = {
            "rig": self.rig.to_dict(),
            "objects": [o.to_dict() for o in self.objects],
            "materials": [m.to_dict() for m in self.materials],
            "seed": self.seed,
            "metadata": copy.deepcopy(self.metadata),
        }
        if self.lights:
            d["lights"] = [light.to_dict() for light in self.lights]
        if self.environment is not None:
            d["environment"] = self.environment.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> SceneSpec:
        """Build from a dict; the ``rig`` may be partial (overrides of the default rig).

        Raises:
            ValueError: unknown or missing keys, invalid values; the message names the field.
        """
        _check_keys(d, "scene", (), ("rig", "objects", "materials", "seed", "metadata", "lights", "environment"))
        for key in ("objects", "materials", "lights"):
            if key in d and not isinstance(d[key], list):
                raise ValueError(f"scene {key} must be a list, got {type(d[key]).__name__}")
        return cls(
            rig=Rig.from_dict(d.get("rig", {})),
            objects=tuple(ObjectSpec.from_dict(o) for o in d.get("objects", [])),
            materials=tuple(MaterialSpec.from_dict(m) for m in d.get("materials", [])),
            seed=d.get("seed", 0),
            metadata=d.get("metadata", {}),
            lights=tuple(LightSpec.from_dict(light) for light in d.get("lights", [])),
            environment=None if d.get("environment") is None else EnvironmentSpec.from_dict(d["environment"]),
        )

    def save(self, path: str | os.PathLike) -> None:
        """Write the scene as JSON, atomically (temporary file + ``os.replace``)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> SceneSpec:
        """Read a scene JSON file.

        Raises:
            FileNotFoundError: no such file.
            ValueError: invalid JSON or content; the message starts with the path.
        """
        data = _read_json(path, "scene")
        try:
            return cls.from_dict(data)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
