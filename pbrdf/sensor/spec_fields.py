"""The field checks of the frozen specs: numbers, integers, vectors and 4x4 transforms from JSON or code.

The rig (:mod:`pbrdf.sensor.rig`) and the scene (``blender_addon.core.spec``,
``blender_addon.core.spec_lights``) validate every field in ``__post_init__`` through these, so
a bad rig or scene file says which number is wrong: each raises ``ValueError`` naming the field
(``name``, e.g. ``"display.center"``) and what came. Booleans are refused where a number is
expected (JSON ``true`` is not 1).

Example:
    >>> as_vec([0, 0.5, 1], 3, "display.center")
    (0.0, 0.5, 1.0)
    >>> as_float(float("nan"), "display.width")
    Traceback (most recent call last):
    ...
    ValueError: display.width must be finite, got nan
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["IDENTITY4", "as_float", "as_int", "as_matrix4", "as_vec", "check_rigid"]

#: The 4x4 identity as nested tuples: the default ``to_world`` of a camera, object, light or world.
IDENTITY4: tuple[tuple[float, ...], ...] = tuple(tuple(float(i == j) for j in range(4)) for i in range(4))


def as_float(value: Any, name: str) -> float:
    """``value`` as a finite float; ValueError naming ``name`` for a non-number, a bool, NaN or Inf."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return out


def as_int(value: Any, name: str) -> int:
    """``value`` as an int (an integral float such as ``3.0`` from JSON too); ValueError naming ``name`` else.

    Example:
        >>> as_int(3.0, "display.resolution[0]")
        3
    """
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)) and float(value).is_integer():
        return int(value)
    raise ValueError(f"{name} must be an integer, got {value!r}")


def as_vec(value: Any, n: int, name: str) -> tuple[float, ...]:
    """``value`` as a tuple of ``n`` finite floats; ValueError naming ``name`` (and the entry) else.

    Args:
        value: a sequence (list, tuple, array) of ``n`` numbers; a string is refused.
        n: the number of entries.
        name: the field, for the message (entries as ``name[i]``).

    Returns:
        ``(n,)`` tuple of float.
    """
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise ValueError(f"{name} must be a sequence of {n} numbers, got {value!r}")
    if len(value) != n:
        raise ValueError(f"{name} must have {n} entries, got {len(value)}: {value!r}")
    return tuple(as_float(v, f"{name}[{i}]") for i, v in enumerate(value))


def as_matrix4(value: Any, name: str) -> tuple[tuple[float, ...], ...]:
    """``value`` as a finite affine 4x4 matrix (last row ``0 0 0 1``), nested tuples; ValueError naming ``name`` else.

    Example:
        >>> as_matrix4(np.eye(4), "camera.to_world") == IDENTITY4
        True
    """
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a 4x4 matrix of numbers: {e}") from None
    if a.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or Inf")
    if not np.allclose(a[3], (0.0, 0.0, 0.0, 1.0), atol=1e-9):
        raise ValueError(f"{name} must be affine (last row 0 0 0 1), got last row {a[3].tolist()}")
    return tuple(tuple(float(v) for v in row) for row in a)


def check_rigid(m: tuple[tuple[float, ...], ...], name: str) -> None:
    """Raise ValueError naming ``name`` unless the affine ``m`` (4x4) is a rotation plus translation.

    A scale, shear or mirror (``R^T R != I`` within 1e-6, or ``det R < 0``) is refused.

    Example:
        >>> check_rigid(((2.0, 0, 0, 0), (0, 1.0, 0, 0), (0, 0, 1.0, 0), (0, 0, 0, 1.0)), "camera.to_world")
        Traceback (most recent call last):
        ...
        ValueError: camera.to_world must be a rigid transform (rotation + translation, no scale or mirror)
    """
    r = np.asarray(m)[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ValueError(f"{name} must be a rigid transform (rotation + translation, no scale or mirror)")
