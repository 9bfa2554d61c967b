"""Bpy-free core of the scene side.

Modules: ``rig`` (display + camera), ``spec`` (scene spec: objects, materials, lights, world;
JSON), ``assets`` (meshes, procedural shapes, placement, PLY), ``scenegen`` (random
Objaverse-like scenes), ``mitsuba_scene`` (spec -> polarized Mitsuba scene per colour channel,
and the RGB preview scene of any exported Blender scene with its XML writer), ``render``
(polarized rendering, synthetic samples, RGB preview) and ``generate`` (datasets).
"""
