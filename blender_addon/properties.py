"""Panel settings of the rig and the scene builder, stored on the scene.

``scene.pdir_rig`` (:class:`PDIR_RigSettings`) mirrors the editable numbers of
:class:`~pbrdf.sensor.rig.Rig`; editing one applies that field to the scene's rig at once
(:func:`.rig_bpy.update_from_setting`). ``scene.pdir_builder`` (:class:`PDIR_SceneBuilderSettings`)
holds the scene builder's inputs. Lengths are metres, angles radians (Blender shows degrees).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    IntVectorProperty,
    PointerProperty,
    StringProperty,
)

from pbrdf.sensor.rig import CameraSpec, DisplaySpec

from . import rig_bpy

__all__ = ["CLASSES", "PDIR_RigSettings", "PDIR_SceneBuilderSettings", "register_extra", "unregister_extra"]

_DISPLAY = DisplaySpec()
#: Tooltips of the scene builder's texture options (the panel's and ``pdir.build_scene``'s).
ASSET_MATERIALS_TIP = (
    "glTF and OBJ+MTL assets keep their own materials and textures: one object per material, "
    "with its UVs (as headless/render.py --asset-materials); off: one object with a drawn material"
)
TEXTURE_FRACTION_TIP = (
    "Share of drawn materials (not an asset's own) that get seeded procedural textures: varying base "
    "colour and roughness, metal segments or wear, a normal map (as headless/render.py --texture-fraction)"
)
_CAMERA = CameraSpec()


def _updater(name: str) -> Callable[[bpy.types.PropertyGroup, bpy.types.Context], None]:
    def update(self: bpy.types.PropertyGroup, context: bpy.types.Context) -> None:
        rig_bpy.update_from_setting(self.id_data, name)

    return update


class PDIR_RigSettings(bpy.types.PropertyGroup):
    """Display and camera of the rig; edits apply to the scene's rig immediately."""

    display_width: FloatProperty(
        name="Width",
        description="Width of the display's active area (arc length when curved)",
        default=_DISPLAY.width,
        min=0.01,
        soft_max=3.0,
        unit="LENGTH",
        precision=4,
        update=_updater("display_width"),
    )
    display_height: FloatProperty(
        name="Height",
        description="Height of the display's active area",
        default=_DISPLAY.height,
        min=0.01,
        soft_max=3.0,
        unit="LENGTH",
        precision=4,
        update=_updater("display_height"),
    )
    display_center: FloatVectorProperty(
        name="Center",
        description="Centre of the display in the rig frame (x right, y up, the camera looks along -z)",
        default=_DISPLAY.center,
        size=3,
        subtype="TRANSLATION",
        unit="LENGTH",
        precision=4,
        update=_updater("display_center"),
    )
    display_yaw: FloatProperty(
        name="Yaw",
        description="Rotation of the display about the rig's up axis (0 = facing the objects)",
        default=_DISPLAY.yaw,
        subtype="ANGLE",
        update=_updater("display_yaw"),
    )
    display_pitch: FloatProperty(
        name="Pitch",
        description="Rotation of the display about the rig's x axis, applied before the yaw",
        default=_DISPLAY.pitch,
        subtype="ANGLE",
        update=_updater("display_pitch"),
    )
    display_curved: BoolProperty(
        name="Curved",
        description="Bend the display on a vertical cylinder, concave toward the objects",
        default=_DISPLAY.curvature_radius is not None,
        update=_updater("display_curved"),
    )
    display_curvature_radius: FloatProperty(
        name="Radius",
        description="Curvature radius of a curved display (1 m = 1000R); at least width / pi",
        default=1.0,
        min=0.05,
        soft_max=10.0,
        unit="LENGTH",
        precision=3,
        update=_updater("display_curvature_radius"),
    )
    display_pattern: EnumProperty(
        name="Pattern",
        description="What the display shows",
        items=(
            ("rgb_halves", "RGB halves", "Red right half, green left half, blue upper half (seen from the objects)"),
            ("white", "White", "Every channel on everywhere"),
            ("FILE", "Image file", "An image file stretched over the active area"),
        ),
        default=_DISPLAY.pattern,
        update=_updater("display_pattern"),
    )
    display_pattern_file: StringProperty(
        name="Image",
        description="Pattern image (row 0 = top of the display, seen from the front)",
        subtype="FILE_PATH",
        default="",
        update=_updater("display_pattern_file"),
    )
    display_brightness: FloatProperty(
        name="Brightness",
        description="Radiance of a fully lit colour channel (renderer units; the Emission strength)",
        default=_DISPLAY.radiance,
        min=1e-6,
        soft_max=100.0,
        update=_updater("display_brightness"),
    )
    display_polarization_angle: FloatProperty(
        name="Polarization",
        description="Angle of the emitted linear polarization from the display's x axis (90 deg = vertical)",
        default=_DISPLAY.polarization_angle,
        subtype="ANGLE",
        min=-math.pi,
        max=math.pi,
        update=_updater("display_polarization_angle"),
    )
    camera_focal_length: FloatProperty(
        name="Focal Length (mm)",
        description="Focal length of the lens in millimetres",
        default=_CAMERA.focal_length * 1e3,
        min=0.1,
        soft_max=200.0,
        precision=3,
        update=_updater("camera_focal_length"),
    )
    camera_resolution: IntVectorProperty(
        name="Resolution",
        description="Sensor pixels (width, height); the pixel pitch is kept, so the sensor size follows",
        default=(_CAMERA.sensor_width_px, _CAMERA.sensor_height_px),
        size=2,
        min=1,
        soft_max=16384,
        update=_updater("camera_resolution"),
    )
    camera_pixel_pitch: FloatProperty(
        name="Pixel Pitch (um)",
        description="Sensor pixel size in micrometres (3.45 for the Sony IMX250MYR)",
        default=_CAMERA.pixel_pitch * 1e6,
        min=0.01,
        soft_max=50.0,
        precision=3,
        update=_updater("camera_pixel_pitch"),
    )
    error: StringProperty(
        name="Error",
        description="Why the last edit could not be applied to the rig",
        default="",
    )


class PDIR_SceneBuilderSettings(bpy.types.PropertyGroup):
    """Inputs of the Objaverse-like scene builder."""

    folder: StringProperty(
        name="Assets",
        description="Folder of GLB/GLTF/OBJ/PLY/FBX/STL assets (searched recursively)",
        subtype="DIR_PATH",
        default="",
    )
    count: IntProperty(
        name="Objects",
        description="How many objects to place (assets drawn with replacement)",
        default=3,
        min=1,
        max=100,
        soft_max=20,
    )
    seed: IntProperty(
        name="Seed",
        description="Random seed: the same seed and inputs give the same scene",
        default=0,
        min=0,
    )
    library: StringProperty(
        name="pBRDF Library",
        description=(
            "Optional folder with materials.json listing pBRDF tables and their Disney parameters; "
            "empty: random analytic materials (plastic and metals)"
        ),
        subtype="DIR_PATH",
        default="",
    )
    asset_materials: BoolProperty(
        name="Keep Asset Materials",
        description=ASSET_MATERIALS_TIP,
        default=False,
    )
    texture_fraction: FloatProperty(
        name="Texture Fraction",
        description=TEXTURE_FRACTION_TIP,
        default=0.0,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
    )


CLASSES = (PDIR_RigSettings, PDIR_SceneBuilderSettings)


def register_extra() -> None:
    """Attach the settings to every scene."""
    bpy.types.Scene.pdir_rig = PointerProperty(type=PDIR_RigSettings, name="Rig")
    bpy.types.Scene.pdir_builder = PointerProperty(type=PDIR_SceneBuilderSettings, name="Scene Builder")


def unregister_extra() -> None:
    """Detach the settings."""
    for name in ("pdir_rig", "pdir_builder"):
        if hasattr(bpy.types.Scene, name):
            delattr(bpy.types.Scene, name)
