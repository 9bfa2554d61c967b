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

__all__ = ["to_strict", "dumps_strict", "loads_strict", "read_json_object"]


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


def read_json_object(path: str | Path, fmt: str | None = None, *, what: str = "JSON file") -> dict[str, Any]:
    """A JSON object (whose ``format`` is ``fmt``, when given); one-line ValueError naming the file otherwise.

    The one reader of the project's JSON files. Malformed text, text that is not UTF-8, nesting
    too deep for the parser (RecursionError) and integers of more than 4300 digits are all
    reported as invalid JSON.

    Args:
        path: the file.
        fmt: the value its ``"format"`` key must have, or None (any).
        what: the file's kind in the message when it is missing (``"rig file"``).

    Returns:
        The parsed object.

    Raises:
        FileNotFoundError: no such file (``"<path>: <what> not found"``).
        ValueError: not a JSON object (of format ``fmt``); the message starts with the path.
        OSError: other read errors.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: {what} not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise ValueError(f"{path}: invalid JSON (nested too deeply)") from None
    except ValueError as e:  # UnicodeDecodeError, JSONDecodeError, too many digits
        raise ValueError(f"{path}: invalid JSON ({' '.join(str(e).split())})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object; got {type(data).__name__}")
    if fmt is not None and data.get("format") != fmt:
        found = repr(data.get("format"))
        found = found if len(found) <= 40 else found[:37] + "..."
        raise ValueError(f"{path}: unsupported format {found}; expected {fmt!r}")
    return data
