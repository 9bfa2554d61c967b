"""Polarimetric Inverse Rendering: the Blender extension, and its bpy-free ``core``.

The add-on adds a sidebar tab "Polarimetric" to the 3D view: the display-camera rig, the
Objaverse-like scene builder, export/render to Mitsuba, import/relight of predicted maps and
baking. Everything bpy lives in the modules beside this file; ``core/`` stays bpy-free.

Packaging:
    - Extension (Blender 4.2 and later, including 5.0): ``blender_manifest.toml`` sits beside this
      file; Blender installs the zip built by ``make addon`` (``tools/build_addon.py``; its files
      lie in one top-level folder ``polarimetric_inverse_rendering/``) as
      ``bl_ext.<repository>.polarimetric_inverse_rendering``. Every import inside the add-on is
      relative and module names come from ``__package__``, so the package works under any name.
    - Legacy add-on (Blender 4.2+): the same zip installs with Preferences > Add-ons > Install
      legacy Add-on (it unpacks into ``scripts/addons/polarimetric_inverse_rendering/``), or unpack
      it there by hand (any folder name); ``bl_info`` below describes it (an extension install
      ignores ``bl_info``). The repository's folder alone lacks ``_vendor/pbrdf`` (see below).
    - Minimum version: :data:`compat.MIN_BLENDER` (``bl_info["blender"]`` and the manifest's
      ``blender_version_min`` repeat it). On an older Blender :func:`register` refuses with one
      line ("needs Blender 4.2 or later, this is 3.4.1") and registers nothing.
    - ``pbrdf`` (the project's bottom layer, imported by ``core``) is not part of this folder in
      the repository. The zip vendors it as ``_vendor/pbrdf``; importing this package prepends
      ``_vendor`` to ``sys.path`` when ``pbrdf`` is not importable otherwise (a source checkout
      uses the repository's own ``pbrdf``). Only numpy is needed by the parts the add-on imports.
    - Optional dependencies that Blender's Python lacks: mitsuba and drjit (Mitsuba rendering;
      :func:`prefs.mitsuba_available` says how to get them, or an external Python can be set in
      the add-on preferences), trimesh, xatlas, OpenEXR, scipy. Code paths that need one fail with
      a message naming it; registering the add-on never needs them (a module that imports one at
      module level is left out with a message in the main panel, the rest still registers).

Registration:
    This file never imports bpy at module level, so ``import blender_addon.core`` works under
    plain Python. :func:`register` imports the modules of :data:`MODULES`, registers
    each one's ``CLASSES`` in order and calls its ``register_extra()``; :func:`unregister` undoes
    it in reverse. Both may be called repeatedly (register, unregister, register, ...).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

bl_info = {
    "name": "Polarimetric Inverse Rendering",
    "author": "snapshot-pdir developers",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > Polarimetric",
    "description": "Display-camera rig, synthetic scenes and polarized rendering",
    "category": "3D View",
}

#: Add-on modules in registration order. ``ui`` (the main panel) comes before the modules whose
#: sub-panels name it as ``bl_parent_id``.
MODULES = (
    "properties",
    "prefs",
    "ui",
    "rig_bpy",
    "scene_builder",
    "build_scene_operator",
    "render_operator",
    "pbr_import",
    "reconstruct_operator",
    "gltf_export_operator",
    "relight_operator",
    "bake",
)

#: Folder of vendored pure-Python packages inside the built zip (``pbrdf``).
VENDOR_DIR = Path(__file__).resolve().parent / "_vendor"

# (module, classes registered so far, whether register_extra ran), in registration order.
_registered: list[tuple[ModuleType, list[type], list[bool]]] = []
#: Modules left out at the last :func:`register` because a third-party package is missing: name -> why.
UNAVAILABLE: dict[str, str] = {}


def ensure_vendor_path() -> bool:
    """Make ``pbrdf`` importable: prepend :data:`VENDOR_DIR` to ``sys.path`` if needed.

    Returns:
        True when ``pbrdf`` is importable afterwards.
    """
    if importlib.util.find_spec("pbrdf") is not None:
        return True
    if VENDOR_DIR.is_dir() and str(VENDOR_DIR) not in sys.path:
        sys.path.insert(0, str(VENDOR_DIR))
        importlib.invalidate_caches()
    return importlib.util.find_spec("pbrdf") is not None


ensure_vendor_path()


def _modules() -> list[ModuleType]:
    """Import the modules of :data:`MODULES` (relative to this package).

    A module that needs a third-party package Blender's Python lacks is left out (recorded in
    :data:`UNAVAILABLE` and shown in the main panel), so the rest of the add-on still works.
    """
    UNAVAILABLE.clear()
    out = []
    for name in MODULES:
        try:
            out.append(importlib.import_module(f".{name}", __package__))
        except ModuleNotFoundError as e:
            missing = (e.name or "").split(".")[0]
            if not missing or missing in (__package__.split(".")[0], "bpy"):
                raise
            UNAVAILABLE[name] = f"needs the Python package '{missing}' ({sys.executable} -m pip install {missing})"
            print(f"{__package__}: module {name!r} left out: {UNAVAILABLE[name]}", file=sys.stderr)
    return out


def register() -> None:
    """Register every module's classes and extras (idempotent: re-registers cleanly).

    Raises:
        RuntimeError: Blender older than :data:`compat.MIN_BLENDER` (one line that Blender shows,
            e.g. "needs Blender 4.2 or later, this is 3.4.1"); nothing is registered then.
    """
    import bpy  # noqa: PLC0415 - the package itself must import without bpy

    from .compat import blender_refusal, running_blender  # noqa: PLC0415

    problem = blender_refusal(running_blender())
    if problem:
        raise RuntimeError(f"{bl_info['name']} {problem}")
    if _registered:
        unregister()
    if not ensure_vendor_path():
        raise ImportError(f"{__package__}: the 'pbrdf' package is missing (expected in {VENDOR_DIR})")
    try:
        for mod in _modules():
            done: list[type] = []
            extra_done: list[bool] = []
            _registered.append((mod, done, extra_done))
            for cls in getattr(mod, "CLASSES", ()):
                bpy.utils.register_class(cls)
                done.append(cls)
            extra = getattr(mod, "register_extra", None)
            if extra is not None:
                extra()
                extra_done.append(True)
    except Exception:
        unregister()
        raise


def unregister() -> None:
    """Undo :func:`register` in reverse order; a no-op when nothing is registered."""
    import bpy  # noqa: PLC0415

    while _registered:
        mod, classes, extra_done = _registered.pop()
        extra = getattr(mod, "unregister_extra", None)
        if extra is not None and extra_done:
            extra()
        for cls in reversed(classes):
            bpy.utils.unregister_class(cls)
