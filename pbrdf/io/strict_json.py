"""Strict JSON out: what every results file of the project is written with.

Python's :mod:`json` writes ``NaN`` and ``Infinity`` by default, which strict parsers (browsers'
``JSON.parse``, ``jq``, most other languages) reject. :func:`to_strict` turns non-finite floats
into ``null`` and numpy values into Python ones; :func:`dumps_strict` then refuses anything JSON
cannot represent.

Example:
    >>> dumps_strict({"psnr": float("inf"), "mae": np.float32(1.5), "ids": np.arange(2)}, indent=None)
    '{"psnr": null, "mae": 1.5, "ids": [0, 1]}'
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["to_strict", "dumps_strict", "loads_strict"]


def to_strict(obj: Any) -> Any:
    """A copy of ``obj`` with non-finite floats as None, numpy scalars/arrays as Python values, paths as str."""
    if isinstance(obj, dict):
        return {str(k): to_strict(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_strict(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_strict(obj.tolist())
    if isinstance(obj, np.generic):
        return to_strict(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def dumps_strict(obj: Any, *, indent: int | None = 2) -> str:
    """Serialise ``obj`` (after :func:`to_strict`) as strict JSON; raises ValueError if impossible."""
    return json.dumps(to_strict(obj), indent=indent, allow_nan=False)


def _refuse(name: str) -> Any:
    raise ValueError(f"not strict JSON: {name}")


def loads_strict(text: str) -> Any:
    """Parse JSON, refusing ``NaN``, ``Infinity`` and ``-Infinity`` (which :func:`json.loads` accepts)."""
    return json.loads(text, parse_constant=_refuse)
