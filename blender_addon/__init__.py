"""blender_addon: the scene side. ``core`` is bpy-free; the add-on proper will live beside it."""
