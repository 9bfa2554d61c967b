"""Helpers shared by the modules of :mod:`pbrdf.data` (private).

Index checks, JSON text with numpy values, removal of a sample's files or folders
(:mod:`~pbrdf.data.sample`, :mod:`~pbrdf.data.dataset`), and the checked JSON numbers with short
values in their messages of the capture readers (:mod:`~pbrdf.data.capture`, :mod:`~pbrdf.data.capture_meta`).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["check_index", "dumps_json", "check_metadata", "remove_path", "short_repr", "json_number"]


def check_index(index: Any) -> int:
    """``index`` as an int; ValueError unless it is an integer >= 0 (booleans are refused).

    Example:
        >>> check_index(np.int64(3))
        3
    """
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or index < 0:
        raise ValueError(f"sample index must be an integer >= 0; got {index!r}")
    return int(index)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def dumps_json(data: Mapping[str, Any], what: str) -> str:
    """Indented JSON text of ``data`` (numpy scalars and arrays, paths converted), ending in a newline.

    Raises:
        ValueError: ``data`` holds something JSON cannot encode, or NaN/Inf; the message starts with ``what``.
    """
    try:
        return json.dumps(data, indent=2, allow_nan=False, default=_json_default) + "\n"
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} is not valid JSON ({e})") from e


def check_metadata(metadata: Any, reserved: Sequence[str], what: str) -> dict[str, Any]:
    """A copy of ``metadata`` as a dict; ValueError unless it is a dict with string keys, none of them ``reserved``."""
    if not isinstance(metadata, Mapping):
        raise ValueError(f"{what} must be a dict; got {type(metadata).__name__}")
    bad = [k for k in metadata if not isinstance(k, str)]
    if bad:
        raise ValueError(f"{what} keys must be strings; got {bad}")
    clash = sorted(set(metadata) & set(reserved))
    if clash:
        raise ValueError(f"{what} may not set the reserved key(s) {clash}")
    return dict(metadata)


def remove_path(path: Path) -> None:
    """Remove a file, a link or a folder tree; a missing path is fine."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


def short_repr(value: Any, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters (a JSON integer may have thousands of digits).

    Example:
        >>> short_repr("x" * 50, 10)
        "'xxxxxx..."
    """
    text = repr(value) if not isinstance(value, int) or value.bit_length() < 128 else f"{str(value)[:20]}..."
    return text if len(text) <= limit else text[: limit - 3] + "..."


def json_number(value: Any, name: str, where: str | os.PathLike) -> float:
    """A JSON number as float; ValueError naming ``where`` and ``name`` for a non-number or one too large."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where}: {name} must be a number; got {short_repr(value)}")
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{where}: {name} {short_repr(value)} is too large for a floating-point number") from None
