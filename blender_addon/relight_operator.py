"""Relighting presets for imported assets and the relit render.

* :func:`add_point_light_orbit`: a point light keyframed on a circle around the target, one
  keyframe per frame (every integer frame lies exactly on the circle).
* :func:`add_environment`: a world lit by Blender 5.0's procedural Sky Texture
  (``MULTIPLE_SCATTERING`` by default, without its sun disc unless asked) or an HDR/EXR
  environment file.
* :func:`render_relit`: Cycles on CPU or GPU (falls back to CPU with a warning when no GPU
  backend has a device), one file per frame, each written atomically.

Convention (orbit):
    The circle's axis is the target's local +z in world coordinates; for an imported plane that
    is its normal, pointing toward the capture camera. The centre is the target's origin moved
    ``height`` metres along the axis; angle 0 is along the target's local +x, angles grow
    counter-clockwise seen from the axis' tip. Frame ``frame_start + k`` holds angle
    ``2 pi k / frames``.

Radiometry (Cycles): a point light of power ``P`` W has intensity ``I = P / (4 pi)`` W/sr, so a
Lambertian surface of albedo ``a`` at distance ``r`` and incidence ``theta`` has radiance
``a / pi * I cos(theta) / r^2`` (checked by the tests against renders).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterable
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty
from mathutils import Vector

from pbrdf.io.atomic import temporary_path

from .ui import SidebarPanel

__all__ = [
    "CLASSES",
    "RelightWarning",
    "DENOISE_PREFILTER",
    "ORBIT_LIGHT_NAME",
    "ENVIRONMENT_WORLD_NAME",
    "add_point_light_orbit",
    "orbit_positions",
    "add_environment",
    "select_device",
    "render_relit",
]

ORBIT_LIGHT_NAME = "PDIR Orbit Light"
ENVIRONMENT_WORLD_NAME = "PDIR Environment"
#: Output formats of :func:`render_relit`: Blender file format -> suffix.
RELIT_FORMATS = {"PNG": ".png", "OPEN_EXR": ".exr"}
#: Cycles' importance map of the procedural sky without its sun disc (a smooth sky needs no finer map;
#: the automatic 1024 map is rebuilt for every render and costs seconds there, docs/measurements/relight.md).
SKY_MAP_RESOLUTION = 256
#: Cycles' denoising prefilter of the relit frames: ``"FAST"`` denoises the colour, albedo and normal
#: passes together in one OpenImageDenoise filter; the default ``"ACCURATE"`` runs three, most of a small
#: frame's render time, and the frames still reach 35 dB against a 1024-sample reference without them
#: (docs/measurements/relight.md).
DENOISE_PREFILTER = "FAST"
#: Cycles GPU backends, tried in this order.
GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")


class RelightWarning(UserWarning):
    """A relight step that succeeded differently from what was asked (GPU -> CPU)."""


# --------------------------------------------------------------------------- point light orbit


def orbit_positions(target, *, radius: float, height: float, frames: int) -> list[Vector]:
    """World positions of the orbit (see the module's Convention), one per frame."""
    m = target.matrix_world
    axis = (m.to_3x3() @ Vector((0.0, 0.0, 1.0))).normalized()
    x = m.to_3x3() @ Vector((1.0, 0.0, 0.0))
    u = (x - axis * x.dot(axis)).normalized()
    v = axis.cross(u)
    centre = m.translation + axis * height
    step = 2.0 * math.pi / frames
    return [centre + radius * (math.cos(k * step) * u + math.sin(k * step) * v) for k in range(frames)]


def add_point_light_orbit(
    scene, target, *, radius: float, height: float, frames: int, energy: float, light_radius: float = 0.0
):
    """A point light keyframed on a circle around ``target``; the scene's frame range is set to the orbit.

    An existing orbit light (object :data:`ORBIT_LIGHT_NAME`) is replaced.

    Args:
        scene: the scene.
        target: the object to circle (its origin and local +z define the circle).
        radius: circle radius in metres (> 0).
        height: offset of the circle's centre along the target's +z, metres.
        frames: number of frames (>= 1), one keyframe each.
        energy: light power in W (>= 0).
        light_radius: the light's sphere radius in metres (0 = a true point light).

    Returns:
        The light object.
    """
    if not radius > 0:
        raise ValueError(f"radius must be > 0 metres, got {radius}")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    if not energy >= 0 or not math.isfinite(energy):
        raise ValueError(f"energy must be >= 0 W, got {energy}")
    if target is None:
        raise ValueError("no target object to orbit (select the imported asset)")
    bpy.context.view_layer.update()  # a freshly parented target has a stale matrix_world
    old = bpy.data.objects.get(ORBIT_LIGHT_NAME)
    if old is not None:
        data = old.data
        bpy.data.objects.remove(old)
        if data is not None and data.users == 0:
            bpy.data.lights.remove(data)
    light = bpy.data.lights.new(ORBIT_LIGHT_NAME, "POINT")
    light.energy = energy
    light.shadow_soft_size = light_radius
    obj = bpy.data.objects.new(ORBIT_LIGHT_NAME, light)
    scene.collection.objects.link(obj)
    start = scene.frame_start
    for k, pos in enumerate(orbit_positions(target, radius=radius, height=height, frames=frames)):
        obj.location = pos
        obj.keyframe_insert("location", frame=start + k)
    scene.frame_end = start + frames - 1
    scene.frame_set(scene.frame_current)
    return obj


# --------------------------------------------------------------------------- environment


def add_environment(
    scene,
    *,
    hdr_path: str | os.PathLike | None = None,
    strength: float = 1.0,
    sun_elevation: float = math.radians(15.0),
    sun_rotation: float = 0.0,
    sun: bool = False,
):
    """Light the scene with a procedural sky (no ``hdr_path``) or an HDR/EXR environment map.

    The world :data:`ENVIRONMENT_WORLD_NAME` is (re)built and assigned to the scene.

    Args:
        scene: the scene.
        hdr_path: equirectangular ``.hdr``/``.exr`` file; None for Blender's Sky Texture
            (``MULTIPLE_SCATTERING``, physically scaled: expect bright renders at strength 1).
        strength: Background strength (>= 0).
        sun_elevation: sky sun elevation in radians.
        sun_rotation: sky sun rotation about world z in radians.
        sun: draw the sky's sun disc. Off by default: the physically scaled sun outshines its
            sky about tenfold, so at any strength that exposes the sky, the sunlit side of an
            asset clips to flat white behind a hard terminator while the rest, lit by the sky
            alone, is starved of light samples (noisy); see docs/measurements/blender_addon.md.

    Returns:
        The world.
    """
    if not strength >= 0 or not math.isfinite(strength):
        raise ValueError(f"strength must be >= 0, got {strength}")
    image = None
    if hdr_path is not None and str(hdr_path).strip():
        path = Path(bpy.path.abspath(str(hdr_path)))
        if not path.is_file():
            raise FileNotFoundError(f"{path}: environment file not found")
        try:
            image = bpy.data.images.load(str(path), check_existing=True)
        except RuntimeError as e:
            raise ValueError(f"{path}: cannot load the environment image: {e}") from None
    world = bpy.data.worlds.get(ENVIRONMENT_WORLD_NAME) or bpy.data.worlds.new(ENVIRONMENT_WORLD_NAME)
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputWorld")
    out.location = (300, 0)
    bg = nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = strength
    links.new(bg.outputs["Background"], out.inputs["Surface"])
    if image is not None:
        tex = nodes.new("ShaderNodeTexEnvironment")
        tex.image = image
    else:
        tex = nodes.new("ShaderNodeTexSky")
        kinds = {item.identifier for item in tex.bl_rna.properties["sky_type"].enum_items}
        tex.sky_type = "MULTIPLE_SCATTERING" if "MULTIPLE_SCATTERING" in kinds else "NISHITA"  # 5.0 / 4.2-4.5
        tex.sun_disc = sun
        tex.sun_elevation = sun_elevation
        tex.sun_rotation = sun_rotation
        if not sun:  # the same image, cheaper to sample; a sun disc is small and keeps the automatic map
            world.cycles.sampling_method = "MANUAL"
            world.cycles.sample_map_resolution = SKY_MAP_RESOLUTION
    tex.location = (-300, 0)
    links.new(tex.outputs["Color"], bg.inputs["Color"])
    scene.world = world
    return world


# --------------------------------------------------------------------------- rendering


def select_device(scene, device: str = "CPU") -> str:
    """Set Cycles' device; ``"GPU"`` enables every device of the first backend that has one.

    Returns:
        The device used: ``"GPU"`` or ``"CPU"`` (with a :class:`RelightWarning` when a GPU was
        asked for and none was found).
    """
    if device not in ("CPU", "GPU"):
        raise ValueError(f"device must be 'CPU' or 'GPU', got {device!r}")
    scene.render.engine = "CYCLES"
    if device == "GPU":
        prefs = bpy.context.preferences.addons["cycles"].preferences
        for backend in GPU_BACKENDS:
            try:
                prefs.compute_device_type = backend
                prefs.refresh_devices()
                gpus = [d for d in prefs.devices if d.type == backend]
            except (TypeError, ValueError, AttributeError, RuntimeError):
                continue
            if gpus:
                for d in prefs.devices:
                    d.use = d.type == backend
                scene.cycles.device = "GPU"
                return "GPU"
        prefs.compute_device_type = "NONE"
        warnings.warn(
            "no GPU device found for Cycles (tried " + ", ".join(GPU_BACKENDS) + "); rendering on the CPU",
            RelightWarning,
            stacklevel=2,
        )
    scene.cycles.device = "CPU"
    return "CPU"


def render_relit(
    scene,
    out_dir: str | os.PathLike,
    *,
    device: str = "CPU",
    samples: int = 16,
    frames: Iterable[int] | None = None,
    file_format: str = "PNG",
    prefix: str = "relit_",
    denoise: bool = False,
) -> list[Path]:
    """Render frames with Cycles into ``out_dir/<prefix><frame:04d>.png|.exr``.

    Each frame is rendered, saved with the scene's output settings (``Image.save_render``) to a
    temporary sibling and renamed over the target: a crash never leaves a half-written frame, and
    the temporary name never reaches the log (``render(write_still=True)`` prints
    ``Saved: '<path>'``; ``save_render`` prints nothing). The scene's output format and frame are
    restored afterwards.

    Args:
        scene: the scene (its camera renders).
        out_dir: output folder (created).
        device: ``"CPU"`` or ``"GPU"`` (falls back to the CPU with a :class:`RelightWarning`).
        samples: Cycles samples per pixel (>= 1).
        frames: frame numbers; None = the scene's frame range.
        file_format: ``"PNG"`` (view transform applied, 8 bit) or ``"OPEN_EXR"`` (linear 32-bit float RGBA).
        prefix: file name prefix.
        denoise: use Cycles' denoiser (prefilter :data:`DENOISE_PREFILTER`).

    Returns:
        The written files, in frame order.
    """
    if file_format not in RELIT_FORMATS:
        raise ValueError(f"file_format must be one of {sorted(RELIT_FORMATS)}, got {file_format!r}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    if scene.camera is None:
        raise ValueError(f"scene {scene.name!r} has no camera to render from")
    frames = list(range(scene.frame_start, scene.frame_end + 1) if frames is None else frames)
    if not frames:
        raise ValueError("no frames to render")
    out = Path(bpy.path.abspath(str(out_dir)))
    out.mkdir(parents=True, exist_ok=True)
    select_device(scene, device)
    scene.cycles.samples = samples
    scene.cycles.use_denoising = denoise
    if denoise:
        scene.cycles.denoising_prefilter = DENOISE_PREFILTER
    r = scene.render
    fmt = r.image_settings
    has_media = hasattr(fmt, "media_type")  # Blender 5.0; 4.2-4.5 have file formats only
    saved = (fmt.media_type if has_media else None, fmt.file_format, fmt.color_depth, scene.frame_current)
    suffix = RELIT_FORMATS[file_format]
    written: list[Path] = []
    try:
        if has_media:
            fmt.media_type = "IMAGE"
        fmt.file_format = file_format
        fmt.color_mode = "RGBA"
        fmt.color_depth = "32" if file_format == "OPEN_EXR" else "8"
        for frame in frames:
            scene.frame_set(int(frame))
            target = out / f"{prefix}{int(frame):04d}{suffix}"
            tmp = temporary_path(target)  # save_render writes the scene's format under any name
            try:
                bpy.ops.render.render(scene=scene.name)
                _render_result().save_render(filepath=str(tmp), scene=scene)
                if not tmp.is_file():
                    raise OSError(f"{target}: Blender did not write the frame")
                os.replace(tmp, target)
            finally:
                tmp.unlink(missing_ok=True)
            written.append(target)
    finally:
        if has_media:
            fmt.media_type = saved[0]
        fmt.file_format, fmt.color_depth = saved[1], saved[2]
        scene.frame_set(saved[3])
    return written


def _render_result():
    """The "Render Result" image (found by type: its name is translated in localized Blender builds)."""
    image = next((img for img in bpy.data.images if img.type == "RENDER_RESULT"), None)
    if image is None:
        raise RuntimeError("Blender rendered no image (no Render Result)")
    return image


# --------------------------------------------------------------------------- settings, operators, panel


class PDIR_RelightSettings(bpy.types.PropertyGroup):
    """Relighting settings of a scene (``scene.pdir_relight``)."""

    radius: FloatProperty(
        name="Orbit Radius", description="Radius of the light's circle", default=1.0, min=1e-4, unit="LENGTH"
    )
    height: FloatProperty(
        name="Height",
        description="Offset of the circle's centre along the asset's normal (toward the camera)",
        default=0.5,
        unit="LENGTH",
    )
    frames: IntProperty(name="Frames", description="Frames of the orbit, one keyframe each", default=24, min=1)
    energy: FloatProperty(name="Power", description="Point light power", default=100.0, min=0.0, unit="POWER")
    hdr_path: StringProperty(
        name="HDR", description="Equirectangular HDR/EXR environment (empty: procedural sky)", subtype="FILE_PATH"
    )
    strength: FloatProperty(name="Strength", description="Environment strength", default=1.0, min=0.0)
    out_dir: StringProperty(
        name="Output", description="Folder for the relit frames", default="//relit/", subtype="DIR_PATH"
    )
    device: EnumProperty(
        name="Device",
        description="Cycles device (GPU falls back to the CPU with a warning)",
        items=(("CPU", "CPU", "Render on the CPU"), ("GPU", "GPU", "Render on a GPU")),
        default="CPU",
    )
    samples: IntProperty(name="Samples", description="Cycles samples per pixel", default=16, min=1)
    file_format: EnumProperty(
        name="Format",
        description="Output image format",
        items=(("PNG", "PNG", "8-bit PNG, view transform applied"), ("OPEN_EXR", "EXR", "Linear 32-bit EXR")),
        default="PNG",
    )
    current_only: BoolProperty(name="Current Frame Only", description="Render only the current frame", default=False)


def _settings(context) -> PDIR_RelightSettings:
    return context.scene.pdir_relight


class PDIR_OT_add_light_orbit(bpy.types.Operator):
    """Add a point light circling the active object, one keyframe per frame."""

    bl_idname = "pdir.add_light_orbit"
    bl_label = "Add Orbiting Light"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        """Add the orbit around the active object with the scene's relight settings."""
        s = _settings(context)
        try:
            light = add_point_light_orbit(
                context.scene,
                context.active_object,
                radius=s.radius,
                height=s.height,
                frames=s.frames,
                energy=s.energy,
            )
        except ValueError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"{light.name}: {s.frames} frames around {context.active_object.name!r}")
        return {"FINISHED"}


class PDIR_OT_add_environment(bpy.types.Operator):
    """Light the scene with the procedural sky or the chosen HDR file."""

    bl_idname = "pdir.add_environment"
    bl_label = "Add Environment"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        """Build the environment world from the scene's relight settings."""
        s = _settings(context)
        try:
            world = add_environment(context.scene, hdr_path=s.hdr_path or None, strength=s.strength)
        except (ValueError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        what = Path(s.hdr_path).name if s.hdr_path else "procedural sky"
        self.report({"INFO"}, f"{world.name}: {what}, strength {s.strength:g}")
        return {"FINISHED"}


class PDIR_OT_render_relit(bpy.types.Operator):
    """Render the relit frames with Cycles into the output folder."""

    bl_idname = "pdir.render_relit"
    bl_label = "Render Relit"
    bl_options = {"REGISTER"}

    def execute(self, context):
        """Render the frame range (or the current frame) and report the files."""
        s = _settings(context)
        scene = context.scene
        frames = [scene.frame_current] if s.current_only else None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RelightWarning)
            try:
                files = render_relit(
                    scene, s.out_dir, device=s.device, samples=s.samples, frames=frames, file_format=s.file_format
                )
            except (ValueError, OSError, RuntimeError) as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
        for w in caught:
            if issubclass(w.category, RelightWarning):
                self.report({"WARNING"}, str(w.message))
        self.report({"INFO"}, f"rendered {len(files)} frame(s) to {files[0].parent}")
        return {"FINISHED"}


class PDIR_PT_import_relight(SidebarPanel, bpy.types.Panel):
    """Import predicted PBR maps and relight them."""

    bl_label = "Import & Relight"
    bl_idname = "PDIR_PT_import_relight"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 3

    def draw(self, context):
        """Import button, light and environment presets, render settings."""
        layout = self.layout
        s = _settings(context)
        layout.operator("pdir.import_pbr", icon="IMPORT")
        box = layout.box()
        box.label(text="Orbiting point light", icon="LIGHT_POINT")
        col = box.column(align=True)
        for prop in ("radius", "height", "frames", "energy"):
            col.prop(s, prop)
        box.operator("pdir.add_light_orbit", icon="LIGHT_POINT")
        box = layout.box()
        box.label(text="Environment", icon="WORLD")
        box.prop(s, "hdr_path")
        box.prop(s, "strength")
        box.operator("pdir.add_environment", icon="WORLD")
        box = layout.box()
        box.label(text="Render", icon="RENDER_ANIMATION")
        col = box.column(align=True)
        for prop in ("out_dir", "device", "samples", "file_format", "current_only"):
            col.prop(s, prop)
        box.operator("pdir.render_relit", icon="RENDER_ANIMATION")


CLASSES = (
    PDIR_RelightSettings,
    PDIR_OT_add_light_orbit,
    PDIR_OT_add_environment,
    PDIR_OT_render_relit,
    PDIR_PT_import_relight,
)


def register_extra() -> None:
    """Attach the settings to every scene."""
    bpy.types.Scene.pdir_relight = PointerProperty(type=PDIR_RelightSettings)


def unregister_extra() -> None:
    """Remove the scene settings."""
    del bpy.types.Scene.pdir_relight
