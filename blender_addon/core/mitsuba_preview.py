"""Scene spec -> RGB (non-polarized) Mitsuba 3 scene: the preview of an exported Blender scene.

:func:`preview_scene_dict` builds a plain Mitsuba scene of any exported Blender scene: the rig
camera over its whole sensor, meshes as PLY/OBJ files, Principled-like BSDFs from the Disney
parameters, lights and world in Blender's units (:class:`~.spec.LightSpec`), optionally the
display as an unpolarized area light. Every part is a file reference or a plain value, so
:func:`write_xml` can write the dict as Mitsuba XML. The polarized capture scene is
:mod:`.mitsuba_scene`'s.

Convention (frames):
    Blender cameras look along -z with image right = +x, Mitsuba's along +z with image right =
    -x (:data:`GL_TO_MITSUBA_CAMERA`, a half turn about y); Blender's spot, area and sun lights
    shine along local -z, Mitsuba's along +z (``FLIP_Z``, a half turn about x); Mitsuba's envmap
    frame (y up, image centre along +z) maps to Blender's world frame (z up, image centre along
    +x) by :data:`ENVMAP_TO_BLENDER`. Example: the envmap's image centre direction ``(0, 0, 1)``
    becomes Blender's ``(1, 0, 0)``:

    >>> (ENVMAP_TO_BLENDER[:3, :3] @ [0.0, 0.0, 1.0]).tolist()
    [1.0, 0.0, 0.0]

Mitsuba is imported lazily: this module imports without it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .mitsuba_scene import MIN_ALPHA, curved_strip, scalar_transform

if TYPE_CHECKING:
    from pbrdf.sensor.rig import CameraSpec, DisplaySpec

    from .spec import EnvironmentSpec, LightSpec, MaterialSpec, ObjectSpec, SceneSpec

__all__ = [
    "ENVMAP_TO_BLENDER",
    "GL_TO_MITSUBA_CAMERA",
    "environment_dict",
    "light_dict",
    "preview_bsdf_dict",
    "preview_resolution",
    "preview_scene_dict",
    "preview_sensor_dict",
    "write_xml",
]


#: Mitsuba's perspective camera looks along +z with image right = -x; an OpenGL/Blender camera
#: looks along -z with image right = +x: the two frames differ by a half turn about y.
GL_TO_MITSUBA_CAMERA = np.diag([-1.0, 1.0, -1.0, 1.0])
#: Half turn about x: Blender's spot, area and sun lights shine along local -z, Mitsuba's along +z.
FLIP_Z = np.diag([1.0, -1.0, -1.0, 1.0])
#: Mitsuba's envmap frame (y up, image centre along +z) -> Blender's world frame (z up, image
#: centre along +x, left half of the image toward +y).
ENVMAP_TO_BLENDER = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def _rgb(values: Any) -> dict:
    return {"type": "rgb", "value": [float(v) for v in values]}


def preview_resolution(camera: CameraSpec, resolution: tuple[int, int] | int | None) -> tuple[int, int]:
    """Film size ``(W, H)`` of a preview: the sensor's, or ``resolution`` (an int = width, aspect kept)."""
    if resolution is None:
        return camera.sensor_width_px, camera.sensor_height_px
    if isinstance(resolution, (int, np.integer)):
        w = int(resolution)
        return w, max(1, round(w * camera.sensor_height_px / camera.sensor_width_px))
    w, h = (int(v) for v in resolution)
    if w < 1 or h < 1:
        raise ValueError(f"preview resolution must be positive, got {resolution}")
    return w, h


def preview_sensor_dict(
    camera: CameraSpec,
    resolution: tuple[int, int] | int | None = None,
    spp: int = 64,
    *,
    sampler: str = "independent",
    rfilter: str = "box",
) -> dict:
    """Perspective sensor of a camera spec over its whole sensor, RGBA film (alpha = coverage).

    The horizontal field of view is the camera's; pixels are square, so a ``resolution`` with
    another aspect than the sensor's changes the vertical field of view.
    """
    w, h = preview_resolution(camera, resolution)
    return {
        "type": "perspective",
        "fov": math.degrees(camera.fov_x),
        "fov_axis": "x",
        "to_world": scalar_transform(camera.camera_to_world() @ GL_TO_MITSUBA_CAMERA),
        "film": {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "rgba", "rfilter": {"type": rfilter}},
        "sampler": {"type": sampler, "sample_count": int(spp)},
    }


def preview_bsdf_dict(material: MaterialSpec) -> dict:
    """Principled-like RGB BSDF of a material, two-sided (Blender shades both sides of a face).

    ``diffuse`` -> ``diffuse``; ``pplastic`` -> ``roughplastic`` (GGX, alpha = r^2, its IOR);
    ``conductor`` -> ``roughconductor`` with its complex IOR; ``measured`` -> from its Disney
    parameters: metallic >= 0.5 gives a rough conductor reflecting the albedo
    (``material="none"``), otherwise a rough plastic with the albedo as diffuse colour.
    """
    alpha = max(material.roughness**2, MIN_ALPHA)
    kind = material.kind
    if kind == "measured":
        kind = "metal" if material.metallic >= 0.5 else "pplastic"
    if kind == "diffuse":
        inner = {"type": "diffuse", "reflectance": _rgb(material.albedo)}
    elif kind == "pplastic":
        inner = {
            "type": "roughplastic",
            "diffuse_reflectance": _rgb(material.albedo),
            "int_ior": float(material.ior or 1.5),
            "ext_ior": 1.0,
            "alpha": alpha,
            "distribution": "ggx",
        }
    elif kind == "conductor":
        inner = {"type": "roughconductor", "eta": _rgb(material.eta), "k": _rgb(material.k), "alpha": alpha,
                 "distribution": "ggx"}  # fmt: skip
    else:
        inner = {"type": "roughconductor", "material": "none", "specular_reflectance": _rgb(material.albedo),
                 "alpha": alpha, "distribution": "ggx"}  # fmt: skip
    return {"type": "twosided", "bsdf": inner}


def light_dict(light: LightSpec) -> dict:
    """Mitsuba emitter (or emitting shape) of a light spec; the unit conversions are in :class:`LightSpec`."""
    m = np.asarray(light.to_world, dtype=np.float64)
    if light.kind == "point":
        return {"type": "point", "to_world": scalar_transform(m), "intensity": _rgb(light.intensity())}
    if light.kind == "spot":
        cutoff = math.degrees(light.spot_angle / 2)
        return {
            "type": "spot",
            "to_world": scalar_transform(m @ FLIP_Z),
            "intensity": _rgb(light.intensity()),
            "cutoff_angle": cutoff,
            "beam_width": cutoff * (1.0 - light.spot_blend),
        }
    if light.kind == "sun":
        return {"type": "directional", "to_world": scalar_transform(m @ FLIP_Z),
                "irradiance": _rgb([light.power * c for c in light.color])}  # fmt: skip
    w, h = light.size
    scale = np.diag([w / 2, h / 2, 1.0, 1.0])  # Mitsuba's rectangle and disk span [-1, 1]^2
    return {
        "type": "rectangle" if light.shape == "rectangle" else "disk",
        "to_world": scalar_transform(m @ FLIP_Z @ scale),
        "emitter": {"type": "area", "radiance": _rgb(light.radiance())},
        "bsdf": {"type": "null"},  # Blender's lights do not reflect or block light
    }


def environment_dict(env: EnvironmentSpec) -> dict:
    """``constant`` emitter for a background colour, ``envmap`` for an equirectangular image."""
    if env.image is None:
        return {"type": "constant", "radiance": _rgb([env.strength * c for c in env.color])}
    return {
        "type": "envmap",
        "filename": str(Path(env.image).resolve()),
        "scale": float(env.strength),
        "to_world": scalar_transform(np.asarray(env.to_world) @ ENVMAP_TO_BLENDER),
    }


def _preview_display(display: DisplaySpec, files_dir: Path) -> dict:
    """The display as an unpolarized RGB area light showing its pattern (no sheet, radiance as set)."""
    import mitsuba as mi  # noqa: PLC0415

    pattern = np.ascontiguousarray(np.flipud(display.pattern_image()), dtype=np.float32) * display.radiance
    path = files_dir / "display_pattern.exr"
    mi.Bitmap(pattern).write(str(path))  # row 0 of the file is the bitmap's v = 0, the display's bottom
    emitter = {"type": "area", "radiance": {"type": "bitmap", "filename": str(path.resolve()), "raw": True,
                                            "filter_type": "nearest", "wrap_mode": "clamp"}}  # fmt: skip
    to_world = np.asarray(display.display_to_world())
    if display.curvature_radius is None:
        scale = np.diag([display.width / 2, display.height / 2, 1.0, 1.0])
        return {"type": "rectangle", "to_world": scalar_transform(to_world @ scale), "emitter": emitter}
    from .ply_io import write_ply_arrays  # noqa: PLC0415

    v, f, uv = curved_strip(display, 0.0)
    world = v @ to_world[:3, :3].T + to_world[:3, 3]
    strip = files_dir / "display.ply"
    write_ply_arrays(strip, world, f, uvs=uv)
    return {"type": "ply", "filename": str(strip.resolve()), "emitter": emitter}


def _preview_mesh(obj: ObjectSpec, files_dir: Path) -> dict:
    """A shape referring to the object's mesh file; other sources are converted to PLY first."""
    suffix = Path(obj.mesh).suffix.lower()
    if suffix in (".ply", ".obj") and not obj.mesh.startswith("builtin:"):
        path = Path(obj.mesh)
        if not path.is_file():
            raise FileNotFoundError(f"object {obj.name!r}: mesh file not found: {obj.mesh}")
        return {
            "type": suffix[1:],
            "filename": str(path.resolve()),
            "to_world": scalar_transform(np.asarray(obj.to_world)),
        }
    from .assets import load_mesh, write_ply  # noqa: PLC0415

    path = files_dir / "meshes" / f"{_safe_name(obj.name)}.ply"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_ply(load_mesh(obj.mesh), path)
    return {"type": "ply", "filename": str(path.resolve()), "to_world": scalar_transform(np.asarray(obj.to_world))}


def _safe_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def preview_scene_dict(
    spec: SceneSpec,
    files_dir: str | Path,
    *,
    resolution: tuple[int, int] | int | None = None,
    spp: int = 64,
    max_depth: int = 8,
    display: bool = True,
    sampler: str = "independent",
) -> dict:
    """An RGB (non-polarized) Mitsuba scene dict of a scene spec: the preview of a Blender scene.

    Camera: the rig camera over its whole sensor (:func:`preview_sensor_dict`). Objects: their
    mesh files (PLY and OBJ referenced in place; builtin shapes, GLB and GLTF written as PLY
    into ``files_dir/meshes``) with :func:`preview_bsdf_dict`. Lights: :func:`light_dict`;
    world: :func:`environment_dict`; with ``display`` also the rig's display as an unpolarized
    area light showing its pattern. Needs mitsuba with an RGB variant set (transforms are
    Mitsuba objects); every other part is a plain value or a file, so :func:`write_xml` can
    write it.

    Args:
        spec: the scene (objects, materials, lights, environment, rig).
        files_dir: folder for the files the scene refers to (created).
        resolution: film size ``(W, H)``, a width (aspect of the sensor), or None (sensor size).
        spp: samples per pixel.
        max_depth: path length limit of the ``path`` integrator.
        display: include the rig's display as a light.
        sampler: Mitsuba sampler plugin.
    """
    files_dir = Path(files_dir)
    files_dir.mkdir(parents=True, exist_ok=True)
    materials = {m.name: m for m in spec.materials}
    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth)},
        "sensor": preview_sensor_dict(spec.rig.camera, resolution, spp, sampler=sampler),
    }
    if display:
        scene["display"] = _preview_display(spec.rig.display, files_dir)
    if spec.environment is not None:
        scene["environment"] = environment_dict(spec.environment)
    for light in spec.lights:
        scene[f"light_{_safe_name(light.name)}"] = light_dict(light)
    for i, obj in enumerate(spec.objects):
        if obj.material not in materials:
            raise ValueError(f"object {obj.name!r} references unknown material {obj.material!r}")
        shape = _preview_mesh(obj, files_dir)
        shape["bsdf"] = preview_bsdf_dict(materials[obj.material])
        scene[f"object_{i}"] = shape
    return scene


def write_xml(scene: dict, path: str | Path, *, variant: str | None = None) -> Path:
    """Write a Mitsuba scene dict as a Mitsuba 3 XML file, atomically.

    Uses Mitsuba 3.9's own writer (``mi.parser.parse_dict`` then ``mi.parser.write_string``;
    the old ``mitsuba.python.xml`` writer is gone since 3.7). The dict may hold only plain values,
    nested plugin dicts and transforms (no Mitsuba objects built in memory, such as meshes from
    arrays): :func:`preview_scene_dict` satisfies this. ``mi.load_file(path)`` loads the result.

    Args:
        scene: the scene dict.
        path: output ``.xml`` path.
        variant: Mitsuba variant the parser checks plugins against (default: the current one).
    """
    import mitsuba as mi  # noqa: PLC0415

    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    variant = variant or mi.variant()
    if variant is None:
        raise ValueError("write_xml: no Mitsuba variant is set; call mi.set_variant first or pass variant")
    state = mi.parser.parse_dict(mi.parser.ParserConfig(variant), scene)
    path = Path(path)
    atomic_write_text(path, mi.parser.write_string(state))
    return path
