"""Small, robust OpenEXR I/O on the OpenEXR 3.x ``OpenEXR.File`` API.

Images are dictionaries of named 2-D channels ``(H, W)`` (row 0 at the top). Channel names are
free-form strings, by convention dotted: ``"maps.R_unpol"``, ``"normal.X"``,
``"stokes.R.S0"``; :func:`stack_channels` and :func:`split_channels` convert between a
``prefix.name`` group and an ``(H, W, C)`` array.

* :func:`write_exr` stores float channels as 32-bit float (or 16-bit half on request) and
  integer/bool channels as 32-bit unsigned int, losslessly (zip by default). It refuses NaN/Inf
  unless asked, and writes atomically: a temporary sibling file (see :func:`temporary_path`) is
  renamed over the target only once complete, so the target is either the old file or the new
  one, never a partial one.
* :func:`read_exr` returns float channels as float32 and uint channels as uint32, from
  single-part and multi-part files (Blender 5 writes multilayer EXRs as multi-part files; the
  channels of all parts are merged).
* :func:`read_exr_header` returns the size, the channels and the custom attributes (strings,
  32-bit ints and float32-exact floats round-trip; store structured data as a JSON string).

Errors: a missing file raises :class:`FileNotFoundError`; a file that is not a complete EXR
(empty, truncated, corrupt, another format) raises ``ValueError("<path>: not a readable EXR file:
<reason>")`` on one line; a requested channel that the file lacks raises
:class:`MissingChannelError` (both a ``KeyError`` and a ``ValueError``) listing the available
ones. The OpenEXR core library may still print its own diagnostics of a corrupt file to stderr.

Notes on OpenEXR 3.5's Python API (checked with 3.5.3): ``File(header, channels)`` replaces the
arrays of the ``channels`` dict passed in by ``Channel`` objects and adds keys to ``header``
(both are copied here); ``write`` takes a ``str`` (a ``Path`` is taken for a stream); float
attributes are stored as 32-bit floats and ints outside int32 are silently stored as 0 (both
refused here); there is no partial read (the whole file is decoded and the requested channels
selected; zip compresses 16 scanlines of all channels together anyway); a file whose pixel data
cannot be decoded opens with zero parts after a warning printed to ``sys.stdout`` (captured
here and used as the reason).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
from numpy.typing import NDArray

from pbrdf.io.atomic import fsync_path, temporary_path
from pbrdf.io.errors import one_line

__all__ = [
    "COMPRESSIONS",
    "EXR_MAGIC",
    "MissingChannelError",
    "write_exr",
    "read_exr",
    "read_exr_header",
    "exr_channel_names",
    "stack_channels",
    "split_channels",
]

#: First four bytes of every OpenEXR file (magic number 20000630, little-endian).
EXR_MAGIC = b"\x76\x2f\x31\x01"

#: Lossless compressions accepted by :func:`write_exr` (name -> OpenEXR constant). The lossy ones
#: (pxr24, b44, b44a, dwaa, dwab, htj2k) are left out: written files must read back exactly.
COMPRESSIONS: dict[str, Any] = {
    name: getattr(OpenEXR, const)
    for name, const in (
        ("none", "NO_COMPRESSION"),
        ("rle", "RLE_COMPRESSION"),
        ("zips", "ZIPS_COMPRESSION"),
        ("zip", "ZIP_COMPRESSION"),
        ("piz", "PIZ_COMPRESSION"),
        ("zstd", "ZSTD_COMPRESSION"),  # OpenEXR >= 3.4
    )
    if hasattr(OpenEXR, const)
}

# Header attributes that the library manages; custom attributes may not use these names.
_STANDARD_ATTRIBUTES = frozenset(
    {
        "channels",
        "chunkCount",
        "compression",
        "dataWindow",
        "displayWindow",
        "lineOrder",
        "name",
        "pixelAspectRatio",
        "screenWindowCenter",
        "screenWindowWidth",
        "tiles",
        "type",
        "version",
        "view",
    }
)
_PIXEL_WARNING_RE = re.compile(r"reading pixel data for part (\d+)\s*-\s*(.*)$")
_INT32 = (-(2**31), 2**31 - 1)
_UINT32_MAX = 2**32 - 1
_MAX_NAME_BYTES = 255
# Temporary siblings: ".<target name>.tmp-<pid>-<8 hex digits>" (the pattern of pbrdf.data.capture's
# temporary folders, ".old-" being its set-aside folders).


class MissingChannelError(KeyError, ValueError):
    """A requested channel is not in the file (catchable as ``KeyError`` or ``ValueError``)."""

    def __str__(self) -> str:  # KeyError would print the message in quotes
        return str(self.args[0]) if self.args else ""


def _half_names(half: bool | Iterable[str], names: Sequence[str]) -> set[str]:
    if isinstance(half, bool):
        return set(names) if half else set()
    if isinstance(half, str):
        raise ValueError(f"half must be a bool or a set of channel names; got the string {half!r}")
    chosen = set(half)
    unknown = sorted(chosen - set(names))
    if unknown:
        raise ValueError(f"half names channels that are not written: {unknown}; channels: {sorted(names)}")
    return chosen


def _prepare_channel(name: Any, value: Any, as_half: bool, half_explicit: bool, allow_nonfinite: bool) -> NDArray:
    if not isinstance(name, str) or not name:
        raise ValueError(f"channel names must be non-empty strings; got {name!r}")
    if "\0" in name or len(name.encode("utf-8")) > _MAX_NAME_BYTES:
        raise ValueError(f"channel {name!r}: names must be at most {_MAX_NAME_BYTES} bytes without NUL")
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise ValueError(f"channel {name!r}: expected a 2-D (H, W) array; got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"channel {name!r}: empty image of shape {arr.shape}")
    kind = arr.dtype.kind
    if kind == "f":
        dtype = np.float16 if as_half else np.float32
        with np.errstate(over="ignore"):  # overflow is reported below, naming the channel
            out = np.ascontiguousarray(arr, dtype=dtype)
        if not allow_nonfinite:
            finite = np.isfinite(out)
            if not finite.all():
                r, c = (int(v) for v in np.argwhere(~finite)[0])
                count = int((~finite).sum())
                if np.isnan(arr).any():
                    what = "NaN"
                elif np.isinf(arr).any():
                    what = "Inf"
                else:
                    what = f"values beyond the {np.dtype(dtype).name} range (max {np.finfo(dtype).max:g})"
                raise ValueError(
                    f"channel {name!r}: {what} in {count} pixel(s), first at (row {r}, col {c}) "
                    "(pass allow_nonfinite=True to store it)"
                )
        return out
    if as_half and half_explicit:
        raise ValueError(f"channel {name!r}: half applies to float channels only; got dtype {arr.dtype}")
    if kind == "b":
        return np.ascontiguousarray(arr, dtype=np.uint32)
    if kind in "iu":
        lo, hi = int(arr.min()), int(arr.max())
        if lo < 0 or hi > _UINT32_MAX:
            raise ValueError(f"channel {name!r}: integer values [{lo}, {hi}] do not fit uint32")
        return np.ascontiguousarray(arr, dtype=np.uint32)
    raise ValueError(f"channel {name!r}: unsupported dtype {arr.dtype}; expected float, integer or bool")


def _check_attribute(key: Any, value: Any) -> Any:
    if not isinstance(key, str) or not key or "\0" in key:
        raise ValueError(f"header attribute names must be non-empty strings; got {key!r}")
    if key in _STANDARD_ATTRIBUTES:
        raise ValueError(f"header attribute {key!r} is managed by the writer; custom names may not use it")
    if isinstance(value, str):
        if "\0" in value:
            raise ValueError(f"header attribute {key!r}: strings may not contain NUL")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(
            f"header attribute {key!r}: unsupported type {type(value).__name__}; use str, int or float "
            "(store structured data as a JSON string)"
        )
    if isinstance(value, int | np.integer):
        if not _INT32[0] <= int(value) <= _INT32[1]:
            raise ValueError(f"header attribute {key!r}: int {value} outside int32 (store it as a string)")
        return int(value)
    f = float(value)
    if not math.isfinite(f) or float(np.float32(f)) != f:
        raise ValueError(
            f"header attribute {key!r}: float {value!r} is not exactly a finite float32 (EXR float "
            "attributes are 32-bit; store it as a string)"
        )
    return f


def write_exr(
    path: str | os.PathLike,
    channels: Mapping[str, NDArray],
    *,
    half: bool | Iterable[str] = False,
    compression: str = "zip",
    header: Mapping[str, Any] | None = None,
    allow_nonfinite: bool = False,
) -> Path:
    """Write named ``(H, W)`` channels to a single-part scanline EXR, atomically.

    Float inputs are stored as float32 (float64 is rounded), or float16 where ``half`` says so;
    bool and integer inputs as uint32. The file is written to :func:`temporary_path` next to
    the target, synced and renamed over it; on any error the temporary file is removed and an
    existing file at ``path`` is left untouched.

    Args:
        path: target file; its folder must exist.
        channels: channel name -> ``(H, W)`` array; all the same shape, at least 1x1.
        half: True to store every float channel as float16, or the set of channel names to.
        compression: one of :data:`COMPRESSIONS` (all lossless).
        header: custom attributes: str, int (int32) or float (float32-exact) values; names may
            not be the standard ones (``compression``, ``channels``, ...).
        allow_nonfinite: store NaN/Inf instead of raising.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        ValueError: bad channel name, shape, dtype or value (the message names the channel),
            unknown compression, bad attribute.
        FileNotFoundError: the target folder does not exist.
        OSError: the file cannot be written.
    """
    target = Path(path)
    if not isinstance(channels, Mapping) or not channels:
        raise ValueError(f"{target}: channels must be a non-empty dict of name -> (H, W) array")
    if compression not in COMPRESSIONS:
        raise ValueError(f"unknown compression {compression!r}; valid: {sorted(COMPRESSIONS)}")
    names = list(channels)
    halves = _half_names(half, names)
    explicit = not isinstance(half, bool)
    prepared: dict[str, NDArray] = {}
    shape = None
    first = None
    for name in names:
        arr = _prepare_channel(name, channels[name], name in halves, explicit, allow_nonfinite)
        if shape is None:
            shape, first = arr.shape, name
        elif arr.shape != shape:
            raise ValueError(f"channel {name!r}: shape {arr.shape} differs from {shape} of channel {first!r}")
        prepared[name] = arr
    attrs = {k: _check_attribute(k, v) for k, v in (header or {}).items()}

    parent = target.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"{target}: folder {parent} does not exist")
    if target.is_dir():
        raise IsADirectoryError(f"{target}: is a folder")
    hdr = {"compression": COMPRESSIONS[compression], "type": OpenEXR.scanlineimage, **attrs}
    tmp = temporary_path(target)
    try:
        exr = OpenEXR.File(dict(hdr), dict(prepared))  # the library mutates both dicts
        try:
            exr.write(str(tmp))
        except RuntimeError as e:
            raise OSError(f"{target}: cannot write EXR: {one_line(e)}") from e
        fsync_path(tmp)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    fsync_path(parent, directory=True)
    return target


def _not_readable(path: Path, reason: str) -> ValueError:
    return ValueError(f"{path}: not a readable EXR file: {one_line(reason)}")


def _check_file(path: Path) -> None:
    """Raise FileNotFoundError / ValueError unless ``path`` starts like an EXR file."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: EXR file not found")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, not an EXR file")
    with open(path, "rb") as f:
        head = f.read(8)
    if not head:
        raise _not_readable(path, "empty file")
    if head[:4] != EXR_MAGIC:
        hint = " (a PNG file)" if head.startswith(b"\x89PNG") else ""
        raise _not_readable(path, f"bad magic number {head[:4].hex(' ')}{hint}; an EXR starts with 76 2f 31 01")
    if len(head) < 8:
        raise _not_readable(path, f"truncated header ({len(head)} bytes)")
    if head[4] != 2:
        raise _not_readable(path, f"unsupported EXR version {head[4]} (expected 2)")


def _warning_reason(printed: str) -> str:
    """Reason from the warning OpenEXR's binding prints when it cannot decode pixel data."""
    text = one_line(printed) if printed.strip() else ""
    m = _PIXEL_WARNING_RE.search(text)
    if m:
        return f"truncated or corrupt pixel data in part {m.group(1)} ({m.group(2)})"
    return text


def _open(path: Path, **kwargs: bool) -> OpenEXR.File:
    """Open with the library, turning its errors and stdout warnings into one ValueError."""
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            exr = OpenEXR.File(str(path), **kwargs)
    except (RuntimeError, ValueError) as e:
        raise _not_readable(path, _warning_reason(out.getvalue()) or one_line(e)) from e
    if out.getvalue().strip():
        raise _not_readable(path, _warning_reason(out.getvalue()))
    return exr


def _header_channels(exr: OpenEXR.File, path: Path) -> list[str]:
    """Channel names over all parts of a header-only File (its channels carry no pixel type)."""
    found: list[str] = []
    for i in range(len(exr.parts)):
        for ch in exr.header(i).get("channels", []):
            if ch.name in found:
                raise _not_readable(path, f"channel {ch.name!r} appears in more than one part")
            found.append(ch.name)
    return found


def exr_channel_names(path: str | os.PathLike) -> list[str]:
    """Channel names of an EXR file (all parts), reading only its header.

    Args:
        path: the EXR file.

    Returns:
        The names in file order (OpenEXR sorts them within a part).
    """
    p = Path(path)
    _check_file(p)
    return _header_channels(_open(p, header_only=True), p)


def read_exr(path: str | os.PathLike, channels: Sequence[str] | None = None) -> dict[str, NDArray]:
    """Read the channels of an EXR file (single- or multi-part).

    Args:
        path: the EXR file.
        channels: names to return (in this order); None for all, in file order. The library
            decodes the whole file either way.

    Returns:
        Channel name -> ``(H, W)`` array (row 0 at the top): float32 for half and float
        channels, uint32 for uint channels.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a complete, readable EXR file (one line naming the file).
        MissingChannelError: a requested channel is absent (lists the available ones).
    """
    p = Path(path)
    _check_file(p)
    head = _open(p, header_only=True)
    available = _header_channels(head, p)
    if channels is not None:
        if isinstance(channels, str):
            raise ValueError(f"channels must be a list of names; got the string {channels!r}")
        missing = [c for c in channels if c not in available]
        if missing:
            raise MissingChannelError(f"{p}: no channel(s) {missing}; available: {list(available)}")
        if not channels:
            return {}
    exr = _open(p, separate_channels=True)
    if len(exr.parts) != len(head.parts):
        raise _not_readable(p, f"decoded {len(exr.parts)} of {len(head.parts)} parts")
    pixels: dict[str, NDArray] = {}
    for i in range(len(exr.parts)):
        for name, ch in exr.channels(i).items():
            pixels[name] = ch.pixels
    wanted = list(available) if channels is None else list(channels)
    result: dict[str, NDArray] = {}
    for name in wanted:
        arr = pixels.get(name)
        if arr is None or not isinstance(arr, np.ndarray) or arr.ndim != 2:
            raise _not_readable(p, f"no pixel data for channel {name!r}")
        result[name] = arr if arr.dtype in (np.float32, np.uint32) else arr.astype(np.float32)
    return result


def read_exr_header(path: str | os.PathLike) -> dict[str, Any]:
    """Size, channels, compression and custom attributes of an EXR file (header only).

    Args:
        path: the EXR file.

    Returns:
        ``{"width": W, "height": H, "channels": [names, all parts], "compression": "zip",
        "parts": number of parts, "attributes": {custom attributes}}``; size, compression and
        attributes are those of the first part. (The pixel types are not reported: OpenEXR 3.5
        knows them only after decoding the pixels.)

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a readable EXR file.
    """
    p = Path(path)
    _check_file(p)
    exr = _open(p, header_only=True)
    if not exr.parts:
        raise _not_readable(p, "no parts")
    hdr = exr.header(0)
    (x0, y0), (x1, y1) = (tuple(int(v) for v in corner) for corner in hdr["dataWindow"])
    comp = hdr.get("compression")
    comp_name = getattr(comp, "name", str(comp)).removesuffix("_COMPRESSION").lower()
    return {
        "width": x1 - x0 + 1,
        "height": y1 - y0 + 1,
        "channels": _header_channels(exr, p),
        "compression": "none" if comp_name == "no" else comp_name,
        "parts": len(exr.parts),
        "attributes": {k: v for k, v in hdr.items() if k not in _STANDARD_ATTRIBUTES},
    }


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def stack_channels(channels: Mapping[str, NDArray], prefix: str, names: Sequence[str]) -> NDArray:
    """Stack the channels ``prefix.name`` for ``name`` in ``names`` along a last axis.

    Args:
        channels: channel name -> ``(H, W)`` array (e.g. from :func:`read_exr`).
        prefix: group name, e.g. ``"normal"``; empty to use ``names`` as they are.
        names: component names in output order, e.g. ``("X", "Y", "Z")``.

    Returns:
        ``(H, W, C)`` array with ``C = len(names)``.

    Raises:
        MissingChannelError: a channel is absent.

    Example:
        >>> ch = {"n.X": np.zeros((2, 3)), "n.Y": np.ones((2, 3))}
        >>> stack_channels(ch, "n", ["X", "Y"]).shape
        (2, 3, 2)
    """
    full = [_join(prefix, n) for n in names]
    missing = [f for f in full if f not in channels]
    if missing:
        raise MissingChannelError(f"no channel(s) {missing}; available: {list(channels)}")
    if not full:
        raise ValueError("names must not be empty")
    return np.stack([np.asarray(channels[f]) for f in full], axis=-1)


def split_channels(prefix: str, array: NDArray, names: Sequence[str]) -> dict[str, NDArray]:
    """Split an ``(H, W, C)`` array into channels ``prefix.name`` (inverse of :func:`stack_channels`).

    Args:
        prefix: group name; empty to use ``names`` as they are.
        array: ``(H, W, C)`` array.
        names: ``C`` component names.

    Returns:
        Channel name -> ``(H, W)`` view of ``array``.

    Raises:
        ValueError: ``array`` is not ``(H, W, len(names))``.
    """
    arr = np.asarray(array)
    if arr.ndim != 3 or arr.shape[-1] != len(names):
        raise ValueError(
            f"{prefix or 'array'} must have shape (H, W, {len(names)}) for channels {list(names)}; got {arr.shape}"
        )
    return {_join(prefix, n): arr[..., k] for k, n in enumerate(names)}
