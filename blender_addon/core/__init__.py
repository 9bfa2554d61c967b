"""Bpy-free core of the scene side: rig, scene spec, Mitsuba export (not yet implemented)."""
