"""The Blender versions the add-on and the Blender route of the headless scripts accept (no bpy).

:data:`MIN_BLENDER` is the one home of the minimum version. Blender reads two copies without
importing the add-on, so they stay literals: ``bl_info["blender"]`` in ``__init__.py`` (legacy
add-ons) and ``blender_version_min`` in ``blender_manifest.toml`` (extensions); a test checks
that the three agree. :func:`blender_refusal` is the one-line refusal that the add-on's
``register()`` raises and that ``blender -b -P headless/render.py`` (or ``relight.py``) prints
before exiting with a non-zero status.

This module imports nothing from Blender and nothing newer than Python 3.7 needs, so an old
Blender can still import it and say why it is refused.
"""

from __future__ import annotations

import sys

__all__ = ["MIN_BLENDER", "blender_refusal", "running_blender", "version_text"]

#: The oldest Blender the add-on and the headless scripts' Blender route run in (extensions, Python 3.11).
MIN_BLENDER = (4, 2, 0)


def version_text(version, *, short: bool = False) -> str:
    """A version tuple as text: ``(3, 4, 1)`` -> ``"3.4.1"``; ``short`` drops a trailing ``.0``.

    Example:
        >>> version_text((3, 4, 1)), version_text((4, 2, 0), short=True)
        ('3.4.1', '4.2')
    """
    parts = [int(v) for v in version]
    if short and len(parts) == 3 and parts[2] == 0:
        parts = parts[:2]
    return ".".join(str(v) for v in parts)


def blender_refusal(version) -> str | None:
    """The one-line refusal for a Blender older than :data:`MIN_BLENDER`; None when ``version`` is enough.

    Args:
        version: ``bpy.app.version``, e.g. ``(3, 4, 1)``.

    Example:
        >>> blender_refusal((3, 4, 1))
        'needs Blender 4.2 or later, this is 3.4.1'
        >>> blender_refusal((4, 2, 0)) is None and blender_refusal((5, 0, 1)) is None
        True
    """
    if tuple(int(v) for v in version) >= MIN_BLENDER:
        return None
    return f"needs Blender {version_text(MIN_BLENDER, short=True)} or later, this is {version_text(version)}"


def running_blender() -> tuple[int, ...] | None:
    """``bpy.app.version`` of the bpy this process has already imported; None without one (imports nothing)."""
    bpy = sys.modules.get("bpy")
    version = getattr(getattr(bpy, "app", None), "version", None)
    return None if version is None else tuple(version)
