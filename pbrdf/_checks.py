"""Shape checks and small numeric helpers shared by the pbrdf modules (private)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["as_float_array", "as_unit_vectors", "check_last_dims", "double_angle", "safe_div"]


def as_float_array(x: ArrayLike) -> NDArray[np.floating]:
    """Convert to a float ndarray, keeping float32/float64 and promoting everything else to float64."""
    arr = np.asarray(x)
    if arr.dtype in (np.float32, np.float64):
        return arr
    return arr.astype(np.float64)


def as_unit_vectors(v: ArrayLike, name: str, *, tol: float = 1e-3) -> NDArray[np.float64]:
    """Convert to float64 ``(..., 3)`` and raise ValueError unless every vector has unit length.

    Args:
        v: directions, ``(..., 3)``.
        name: the argument's name, for the message.
        tol: allowed deviation of ``|v|`` from 1 (loose: float32 input is fine).

    Returns:
        ``v`` as a float64 array.

    Example:
        >>> as_unit_vectors([0.0, 0.6, 0.8], "wi")
        array([0. , 0.6, 0.8])
        >>> as_unit_vectors([0.0, 0.0, 2.0], "wo")
        Traceback (most recent call last):
        ...
        ValueError: wo must hold finite unit vectors (|v| = 1 within 0.001)
    """
    a = np.asarray(v, dtype=np.float64)
    if a.ndim < 1 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3); got {a.shape}")
    norm = np.linalg.norm(a, axis=-1)
    if np.any(~np.isfinite(norm)) or np.any(np.abs(norm - 1.0) > tol):
        raise ValueError(f"{name} must hold finite unit vectors (|v| = 1 within {tol:g})")
    return a


def check_last_dims(x: NDArray, dims: tuple[int, ...], name: str) -> None:
    """Raise ValueError unless ``x`` has shape ``(..., *dims)``.

    Example:
        >>> check_last_dims(np.zeros((2, 4)), (4,), "stokes")
        >>> check_last_dims(np.zeros((2, 3)), (4,), "stokes")
        Traceback (most recent call last):
        ...
        ValueError: stokes must have shape (..., 4); got (2, 3)
    """
    n = len(dims)
    if x.ndim < n or tuple(x.shape[-n:]) != tuple(dims):
        spec = ", ".join(str(d) for d in dims)
        raise ValueError(f"{name} must have shape (..., {spec}); got {tuple(x.shape)}")


def safe_div(num: NDArray, den: NDArray) -> NDArray:
    """``num / den`` where ``den > 0`` and 0 elsewhere (no warnings, no NaN/Inf)."""
    num, den = np.broadcast_arrays(num, den)
    out = np.zeros(num.shape, dtype=np.result_type(num, den))
    np.divide(num, den, out=out, where=den > 0)
    return out


def double_angle(theta: NDArray, name: str = "theta") -> NDArray:
    """``2 theta`` for a ``cos 2 theta``, ``sin 2 theta``, reduced mod ``2 pi`` where doubling would overflow.

    ``cos`` and ``sin`` are periodic, so the reduction changes nothing but the overflow of
    ``2 theta`` for ``|theta|`` near the largest float (which made them NaN); NaN and Inf are
    refused with a ValueError naming ``name``. One vectorised check on the hot path.

    Example:
        >>> bool(np.isfinite(np.cos(double_angle(np.array(1e308)))))
        True
    """
    with np.errstate(over="ignore"):
        t2 = 2 * theta
    if not np.isfinite(t2).all():
        if not np.isfinite(theta).all():
            raise ValueError(f"{name} must be finite (radians); got NaN or Inf")
        t2 = 2 * np.remainder(theta, np.pi)
    return t2
