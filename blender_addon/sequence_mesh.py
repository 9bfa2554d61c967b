"""Per-frame relief geometry of an imported sequence: shape keys on one mesh, else one object per frame.

:func:`blender_addon.pbr_import.import_pbr_maps` builds each frame's relief mesh from its depth map
(:func:`blender_addon.core.frustum.depth_mesh`, the single-capture builder) and hands them here.

* **Same topology** (:func:`same_topology`: every frame has the same vertices' pixels and the same
  triangles, i.e. the same mask and the same depth jumps): one mesh, frame 1's relief as its
  basis and one shape key per later frame f, keyed to 1 at frame f and to 0 at f - 1 and f + 1
  with CONSTANT interpolation (:func:`key_shapes`), so scene frame f shows frame f's relief
  exactly and no frame blends into the next. One object, one mesh's topology in memory.
* **Otherwise** (an object that moves changes its mask): one object per frame sharing the
  material, shown only at its own frame by ``hide_render`` / ``hide_viewport`` keyframes
  (:func:`key_visibility`; booleans step between keys).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from bpy_extras.anim_utils import action_get_channelbag_for_slot

__all__ = ["Relief", "key_shapes", "key_visibility", "same_topology"]


@dataclass(frozen=True)
class Relief:
    """One frame's relief mesh (:func:`blender_addon.core.frustum.depth_mesh`).

    Attributes:
        vertices: ``(N, 3)`` camera-frame positions, one per pixel of the mesh's support.
        faces: ``(F, 3)`` vertex indices.
        uvs: ``(N, 2)`` the vertices' pixel centres as UVs (they identify the pixels).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray


def same_topology(reliefs: Sequence[Relief]) -> bool:
    """Whether every relief has frame 1's vertices (same pixels, same order) and triangles."""
    first = reliefs[0]
    return all(
        r.vertices.shape == first.vertices.shape
        and np.array_equal(r.faces, first.faces)
        and np.array_equal(r.uvs, first.uvs)
        for r in reliefs[1:]
    )


def _neighbour_frames(f: int, n: int) -> list[int]:
    """Frames ``f - 1, f, f + 1`` inside ``1..n``: the keys that pin frame f's state on and its neighbours' off."""
    return [t for t in (f - 1, f, f + 1) if 1 <= t <= n]


def _constant(animation_data) -> None:
    """CONSTANT interpolation on every keyframe of the action assigned to ``animation_data``."""
    bag = action_get_channelbag_for_slot(animation_data.action, animation_data.action_slot)
    for curve in bag.fcurves:
        for point in curve.keyframe_points:
            point.interpolation = "CONSTANT"


def key_shapes(obj, reliefs: Sequence[Relief]) -> None:
    """Give ``obj`` (frame 1's mesh) one shape key per later frame, keyed on at its frame only (module docstring).

    Args:
        obj: the mesh object built from ``reliefs[0]``.
        reliefs: every frame's relief, frame 1 first, all of one topology (:func:`same_topology`).
    """
    n = len(reliefs)
    obj.shape_key_add(name="Basis", from_mix=False)
    for f, relief in enumerate(reliefs[1:], start=2):
        key = obj.shape_key_add(name=f"frame_{f:04d}", from_mix=False)
        key.data.foreach_set("co", np.asarray(relief.vertices, np.float32).ravel())
        for t in _neighbour_frames(f, n):
            key.value = 1.0 if t == f else 0.0
            key.keyframe_insert("value", frame=t)
    if n > 1:
        _constant(obj.data.shape_keys.animation_data)


def key_visibility(objects: Sequence) -> None:
    """Show ``objects[f - 1]`` at scene frame f only (render and viewport), keyed with CONSTANT steps."""
    n = len(objects)
    for f, obj in enumerate(objects, start=1):
        for t in _neighbour_frames(f, n):
            obj.hide_render = obj.hide_viewport = t != f
            obj.keyframe_insert("hide_render", frame=t)
            obj.keyframe_insert("hide_viewport", frame=t)
        if n > 1:
            _constant(obj.animation_data)
