"""The "Build Scene" button: ``pdir.build_scene`` runs :func:`.scene_builder.build_scene` with the panel's inputs.

The options mirror ``headless/render.py``: *Keep asset materials* is ``--asset-materials``
(glTF/OBJ files keep their own materials, one object per material) and *Texture fraction*
``--texture-fraction`` (the share of drawn materials given seeded procedural textures).
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from .properties import ASSET_MATERIALS_TIP, TEXTURE_FRACTION_TIP
from .scene_builder import build_scene

__all__ = ["CLASSES", "PDIR_OT_build_scene"]


class PDIR_OT_build_scene(bpy.types.Operator):
    """Import random assets from a folder at random poses in the camera's view, with pBRDF materials."""

    bl_idname = "pdir.build_scene"
    bl_label = "Build Scene"
    bl_options = {"REGISTER", "UNDO"}

    folder: StringProperty(
        name="Assets", description="Folder of GLB/GLTF/OBJ/PLY/FBX/STL assets", subtype="DIR_PATH", default=""
    )
    count: IntProperty(name="Objects", description="How many objects to place", default=3, min=1, max=100)
    seed: IntProperty(name="Seed", description="Random seed of the scene", default=0, min=0)
    library: StringProperty(
        name="pBRDF Library",
        description="Folder with materials.json (empty: random analytic materials)",
        subtype="DIR_PATH",
        default="",
    )
    replace: BoolProperty(name="Replace", description="Remove the objects of the previous build first", default=True)
    asset_materials: BoolProperty(name="Keep Asset Materials", description=ASSET_MATERIALS_TIP, default=False)
    texture_fraction: FloatProperty(
        name="Texture Fraction", description=TEXTURE_FRACTION_TIP, default=0.0, min=0.0, max=1.0, subtype="FACTOR"
    )

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Build the scene and report what was placed."""
        if not self.folder.strip():
            self.report({"ERROR"}, "Choose an asset folder")
            return {"CANCELLED"}
        library = bpy.path.abspath(self.library.strip()) if self.library.strip() else None
        skipped: dict[str, str] = {}
        notes: dict[str, list[str]] = {}
        try:
            objs = build_scene(
                context.scene,
                bpy.path.abspath(self.folder.strip()),
                self.count,
                self.seed,
                library,
                replace=self.replace,
                skipped=skipped,
                asset_materials=self.asset_materials,
                texture_fraction=self.texture_fraction,
                notes=notes,
            )
        except (ValueError, OSError, RuntimeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for reason in skipped.values():
            self.report({"WARNING"}, f"skipped {reason}")
        for file, lines in notes.items():
            self.report({"INFO"}, f"{file}: {'; '.join(lines)}")
        source = "pBRDF library" if library else "random analytic materials"
        self.report({"INFO"}, f"Placed {len(objs)} objects (seed {self.seed}, {source}; {len(skipped)} files skipped)")
        return {"FINISHED"}


CLASSES = (PDIR_OT_build_scene,)
