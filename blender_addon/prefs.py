"""Add-on preferences and the availability of the optional Mitsuba renderer.

Blender's bundled Python has numpy but not mitsuba/drjit. Rendering with Mitsuba works either in
Blender's own Python (after ``<blender python> -m pip install mitsuba``) or through an external
Python that has mitsuba (the project's ``.venv/bin/python``), set in the add-on preferences and
run as a subprocess by :mod:`.render_operator`. The same Python runs the network for "Reconstruct
Capture" (:mod:`.reconstruct_operator`).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import bpy
from bpy.props import StringProperty

__all__ = [
    "CLASSES",
    "PDIR_AddonPreferences",
    "addon_preferences",
    "external_python",
    "importable",
    "mitsuba_available",
]


class PDIR_AddonPreferences(bpy.types.AddonPreferences):
    """Preferences of the Polarimetric Inverse Rendering add-on."""

    bl_idname = __package__

    python_path: StringProperty(
        name="Python with Mitsuba",
        description=(
            "Optional: a Python interpreter that has mitsuba and drjit installed (e.g. the project's "
            ".venv/bin/python); used for Mitsuba renders when Blender's own Python lacks them, and "
            "for Reconstruct Capture (the network, torch)"
        ),
        subtype="FILE_PATH",
        default="",
    )

    def draw(self, context: bpy.types.Context) -> None:
        """Draw the preferences and the current Mitsuba status."""
        layout = self.layout
        layout.prop(self, "python_path")
        ok, message = mitsuba_available(context)
        layout.label(text=message, icon="CHECKMARK" if ok else "ERROR")


CLASSES = (PDIR_AddonPreferences,)


def addon_preferences(context: bpy.types.Context | None = None) -> PDIR_AddonPreferences | None:
    """The add-on's preferences, or None when the add-on is registered without being enabled.

    (Tests and scripts that call ``register()`` directly do not enable the add-on in the
    preferences, so there are no stored preferences then.)
    """
    context = context or bpy.context
    addon = context.preferences.addons.get(__package__)
    return None if addon is None else addon.preferences


def external_python(context: bpy.types.Context | None = None) -> Path | None:
    """The external Python set in the preferences, if it is set and is an existing file."""
    prefs = addon_preferences(context)
    if prefs is None or not prefs.python_path.strip():
        return None
    path = Path(bpy.path.abspath(prefs.python_path.strip()))
    return path if path.is_file() else None


def importable(*names: str) -> bool:
    """Whether every named top-level package can be imported in this Python (without importing it).

    Example:
        >>> importable("json", "math"), importable("json", "no_such_package_pdir")
        (True, False)
    """
    return all(importlib.util.find_spec(n) is not None for n in names)


def mitsuba_available(context: bpy.types.Context | None = None) -> tuple[bool, str]:
    """Whether Mitsuba rendering can run, and a one-line message saying how (or how to get it).

    Returns:
        ``(True, ...)`` when mitsuba and drjit are importable in Blender's Python, or an external
        Python is set in the preferences; ``(False, how-to)`` otherwise.
    """
    missing = [name for name in ("mitsuba", "drjit") if not importable(name)]
    if not missing:
        return True, "Mitsuba: available in Blender's Python"
    python = external_python(context)
    if python is not None:
        return True, f"Mitsuba: using the external Python {python}"
    prefs = addon_preferences(context)
    if prefs is not None and prefs.python_path.strip():
        return False, f"Mitsuba: the Python set in the add-on preferences does not exist: {prefs.python_path.strip()}"
    return False, (
        f"Mitsuba not installed ({', '.join(missing)} missing): run '{sys.executable} -m pip install mitsuba' "
        "or set a Python with mitsuba in the add-on preferences"
    )
