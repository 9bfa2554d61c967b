"""Bpy-free core of the scene side (the rig itself is :mod:`pbrdf.sensor.rig`).

Modules:
    - ``spec``, ``spec_lights``: scene spec (objects, materials; lights, world; JSON).
    - ``procedural``: seeded procedural shapes and the mesh size convention.
    - ``assets``: mesh references, loading, cleaning, UVs, PLY output.
    - ``placement``: random poses in view.
    - ``scenegen``: random Objaverse-like scenes.
    - ``mitsuba_scene``: spec -> polarized Mitsuba scene per colour channel.
    - ``mitsuba_preview``: spec -> RGB preview scene of an exported Blender scene, and its XML.
    - ``passes``, ``render``, ``spectral``: polarized rendering, synthetic samples, RGB preview.
    - ``generate``: datasets.
    - ``map_names``, ``map_io``, ``frustum``: predicted PBR map files (matching, loading,
      validation) and the Blender camera frustum the add-on imports them with.
    - ``reconstruction``: the add-on's "Reconstruct Capture" job (``headless/infer.py`` in a
      subprocess: command line, progress, cancel, outputs).
"""
