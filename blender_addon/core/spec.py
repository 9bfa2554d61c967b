"""Scene spec: the rig, objects with poses, their polarimetric materials, lights and the seed.

A :class:`SceneSpec` is what the renderer consumes and what a dataset sample's JSON sidecar
records: it round-trips through JSON exactly (``SceneSpec.from_dict(s.to_dict()) == s``).
Every material carries its Disney parameters (albedo, roughness, metallic), the ground truth of
the material maps, beside what the renderer uses (an analytic polarimetric BSDF or a measured
pBRDF table).

Convention: ``to_world`` matrices map object coordinates (metres after the transform) to the
world frame of :mod:`pbrdf.sensor.rig` (the default camera frame: x right, y up, camera
looking along -z). Relative file paths are relative to the current working directory.

Lights and the environment (:class:`~.spec_lights.LightSpec`, :class:`~.spec_lights.EnvironmentSpec`,
re-exported here) live in :mod:`.spec_lights`: they come from Blender scenes, keep Blender's units
and only the RGB preview render uses them.
"""

from __future__ import annotations

import copy
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.strict_json import read_json_object
from pbrdf.sensor.rig import Rig
from pbrdf.sensor.spec_fields import IDENTITY4, as_float, as_int, as_matrix4, as_vec

from . import assets
from .generated_shapes import GENERATED_SHAPES
from .procedural import PROCEDURAL_SHAPES
from .spec_lights import EnvironmentSpec, LightSpec, _check_keys, _check_name
from .textures import MaterialTextures
from .unseen_shapes import UNSEEN_SHAPES

__all__ = [
    "MATERIAL_KINDS",
    "EnvironmentSpec",  # from .spec_lights, beside the SceneSpec that holds them
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
        textures: what varies across the surface (:class:`~.textures.MaterialTextures`), or None
            for a uniform material. With textures, ``albedo``, ``roughness`` and ``metallic`` are
            the material's mean values (what a renderer without textures shows).

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
    textures: MaterialTextures | None = None

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        _check_name(self.name, "material")
        where = f"material {self.name!r}"
        if isinstance(self.table, os.PathLike):
            put("table", os.fspath(self.table))
        if self.kind not in MATERIAL_KINDS:
            raise ValueError(f"{where}: unknown kind {self.kind!r}; valid: {list(MATERIAL_KINDS)}")
        put("albedo", as_vec(self.albedo, 3, f"{where}: albedo"))
        if not all(0.0 <= a <= 1.0 for a in self.albedo):
            raise ValueError(f"{where}: albedo must be in [0, 1], got {self.albedo}")
        for name in ("roughness", "metallic"):
            value = as_float(getattr(self, name), f"{where}: {name}")
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{where}: {name} must be in [0, 1], got {value}")
            put(name, value)
        own = _KIND_FIELDS[self.kind]
        for name in ("ior", "eta", "k", "table"):
            if name not in own and getattr(self, name) is not None:
                raise ValueError(f"{where}: field {name} is not used by kind {self.kind!r} (fields: {list(own)})")
        if self.kind == "pplastic":
            put("ior", 1.5 if self.ior is None else as_float(self.ior, f"{where}: ior"))
            if not self.ior > 0:
                raise ValueError(f"{where}: ior must be > 0, got {self.ior}")
        elif self.kind == "conductor":
            for name in ("eta", "k"):
                if getattr(self, name) is None:
                    raise ValueError(f"{where}: kind 'conductor' requires {name} (per channel R, G, B)")
                put(name, as_vec(getattr(self, name), 3, f"{where}: {name}"))
            if not all(n > 0 for n in self.eta):
                raise ValueError(f"{where}: eta must be > 0, got {self.eta}")
            if not all(k >= 0 for k in self.k):
                raise ValueError(f"{where}: k must be >= 0, got {self.k}")
        elif self.kind == "measured" and (not isinstance(self.table, str) or not self.table):
            raise ValueError(f"{where}: kind 'measured' requires table (path of a pBRDF tensor file)")
        if self.textures is not None and not isinstance(self.textures, MaterialTextures):
            raise ValueError(f"{where}: textures must be MaterialTextures or None, got {type(self.textures).__name__}")
        if self.textures is not None and self.textures.tables and self.kind != "measured":
            raise ValueError(f"{where}: only kind 'measured' mixes tables (textures.tables)")

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
        if self.textures is not None:
            d["textures"] = self.textures.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> MaterialSpec:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError."""
        _check_keys(d, "material", ("name", "kind", "albedo", "roughness", "metallic"),
                    ("ior", "eta", "k", "table", "textures"))  # fmt: skip
        if "textures" in d:
            d = {**d, "textures": MaterialTextures.from_dict(d["textures"])}
        return cls(**d)


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the scene.

    Attributes:
        name: unique name.
        mesh: path of a PLY/OBJ/GLB/GLTF file (``<file>#material=<K>``: the part of material K)
            or ``builtin:<shape>[?key=value&...]`` (see :func:`blender_addon.core.assets.load_mesh`).
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
        m = as_matrix4(self.to_world, f"{where}: to_world")
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
        seed = as_int(self.seed, "scene seed")
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
            if not builtin and not Path(assets.mesh_file(obj.mesh)).is_file():
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
        data = read_json_object(path, what="scene file")
        try:
            return cls.from_dict(data)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
