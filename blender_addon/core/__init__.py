"""Bpy-free core of the scene side.

Modules: ``rig`` (display + camera), ``spec`` (scene spec, JSON), ``assets`` (meshes, procedural
shapes, placement), ``scenegen`` (random Objaverse-like scenes), ``mitsuba_scene`` (spec ->
Mitsuba scene per colour channel) and ``render`` (polarized rendering and synthetic samples).
"""
