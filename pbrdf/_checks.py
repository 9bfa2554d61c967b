"""Shape checks and small numeric helpers shared by the pbrdf modules (private)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["as_float_array", "check_last_dims", "safe_div"]


def as_float_array(x: ArrayLike) -> NDArray[np.floating]:
    """Convert to a float ndarray, keeping float32/float64 and promoting everything else to float64."""
    arr = np.asarray(x)
    if arr.dtype in (np.float32, np.float64):
        return arr
    return arr.astype(np.float64)


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
