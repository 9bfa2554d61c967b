"""Sidebar tab "Polarimetric" in the 3D view: the main panel and the rig and scene-builder sub-panels.

Other modules add their sub-panels with ``bl_parent_id = "PDIR_PT_main"`` and ``bl_order``
2 (export/render), 3 (reconstruct capture, then import/relight: registration order) and 4 (bake).
"""

from __future__ import annotations

import math

import bpy

from . import rig_bpy

__all__ = ["CLASSES", "PDIR_PT_main", "PDIR_PT_rig", "PDIR_PT_scene_builder"]

_CATEGORY = "Polarimetric"


class SidebarPanel:
    """Mixin: a panel in the 3D view's sidebar tab; sub-panels add ``bl_parent_id = "PDIR_PT_main"``."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = _CATEGORY


class PDIR_PT_main(SidebarPanel, bpy.types.Panel):
    """Polarimetric inverse rendering: rig, synthetic scenes, Mitsuba export and re-import."""

    bl_idname = "PDIR_PT_main"
    bl_label = "Polarimetric Inverse Rendering"

    def draw(self, context: bpy.types.Context) -> None:
        """Status lines: modules left out for a missing package, the rig and its field of view."""
        from . import UNAVAILABLE  # noqa: PLC0415 - the package's registration state

        for name, why in UNAVAILABLE.items():
            self.layout.label(text=f"{name}: {why}", icon="ERROR")
        root = rig_bpy.find_rig_root(context.scene)
        if root is None:
            self.layout.label(text="No rig in the scene yet", icon="INFO")
            return
        try:
            rig = rig_bpy.rig_from_blender(root)
        except ValueError as e:
            self.layout.label(text=str(e), icon="ERROR")
            return
        cam = rig.camera
        self.layout.label(
            text=f"{root.name}: {cam.sensor_width_px}x{cam.sensor_height_px} px, "
            f"FOV {math.degrees(cam.fov_x):.1f} x {math.degrees(cam.fov_y):.1f} deg",
            icon="OUTLINER_OB_CAMERA",
        )


class PDIR_PT_rig(SidebarPanel, bpy.types.Panel):
    """The polarized display and the polarization camera."""

    bl_idname = "PDIR_PT_rig"
    bl_label = "Display-Camera Rig"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 0

    def draw(self, context: bpy.types.Context) -> None:
        """Rig settings (applied live) and rig JSON in/out."""
        layout = self.layout
        s = context.scene.pdir_rig
        has_rig = rig_bpy.find_rig_root(context.scene) is not None
        layout.operator("pdir.add_rig", text="Update Rig" if has_rig else "Add Display-Camera Rig", icon="CAMERA_DATA")
        if s.error:
            box = layout.box()
            box.alert = True
            box.label(text=s.error, icon="ERROR")
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column(heading="Display")
        col.prop(s, "display_width")
        col.prop(s, "display_height")
        col.prop(s, "display_center")
        col.prop(s, "display_yaw")
        col.prop(s, "display_pitch")
        row = col.row(heading="Curved")
        row.prop(s, "display_curved", text="")
        sub = row.row()
        sub.active = s.display_curved
        sub.prop(s, "display_curvature_radius", text="")
        col.prop(s, "display_pattern")
        if s.display_pattern == "FILE":
            col.prop(s, "display_pattern_file")
        col.prop(s, "display_brightness")
        col.prop(s, "display_polarization_angle")
        col = layout.column(heading="Camera")
        col.prop(s, "camera_focal_length")
        col.prop(s, "camera_resolution")
        col.prop(s, "camera_pixel_pitch")
        row = layout.row(align=True)
        row.operator("pdir.rig_from_json", text="Load JSON", icon="FILEBROWSER")
        sub = row.row(align=True)
        sub.enabled = has_rig
        sub.operator("pdir.rig_to_json", text="Export JSON", icon="EXPORT")


class PDIR_PT_scene_builder(SidebarPanel, bpy.types.Panel):
    """Objaverse-like scenes: random assets at random poses in view with pBRDF materials."""

    bl_idname = "PDIR_PT_scene_builder"
    bl_label = "Scene Builder"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 1

    def draw(self, context: bpy.types.Context) -> None:
        """Builder inputs and the build button."""
        layout = self.layout
        s = context.scene.pdir_builder
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "folder")
        layout.prop(s, "library")
        layout.prop(s, "count")
        layout.prop(s, "seed")
        layout.prop(s, "asset_materials")
        layout.prop(s, "texture_fraction")
        row = layout.row()
        row.enabled = bool(s.folder.strip())
        op = row.operator("pdir.build_scene", icon="SCENE_DATA")
        op.folder, op.count, op.seed, op.library = s.folder, s.count, s.seed, s.library
        op.asset_materials, op.texture_fraction = s.asset_materials, s.texture_fraction


CLASSES = (PDIR_PT_main, PDIR_PT_rig, PDIR_PT_scene_builder)
