"""Mitsuba ``tensor_file`` codec: named arrays in one binary file, read with memory maps.

The format of Mitsuba 3's ``TensorFile`` (``src/core/tensor.cpp``) and of its Python module
``mitsuba.tensor_io``, in which the KAIST pBRDF (``.pbsdf``) and hpBRDF (``.hpbrdf``) tables are
stored. This module knows nothing about pBRDFs: :mod:`pbrdf.brdf.table` maps a table's fields to
and from it.

Layout, little-endian:

* ``b"tensor_file\\0"``, ``uint8`` major version 1, ``uint8`` minor version 0, ``uint32`` field
  count;
* per field: ``uint16`` name length, the name (UTF-8), ``uint16`` ndim, ``uint8`` dtype code
  (1..11: uint8, int8, uint16, int16, uint32, int32, uint64, int64, float16, float32, float64),
  ``uint64`` data offset, ``ndim x uint64`` shape;
* the data of each field in C order, at an 8-byte aligned offset (zero padding before it).

Large fields are memory-mapped on read and written in chunks, so a table of many gigabytes
never needs a second copy in memory.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.io.atomic import atomic_open

__all__ = ["write_tensor_file", "read_tensor_file"]

_MAGIC = b"tensor_file\x00"
_VERSION = (1, 0)
_ALIGN = 8
_CODE_OF_KIND = {
    ("u", 1): 1,
    ("i", 1): 2,
    ("u", 2): 3,
    ("i", 2): 4,
    ("u", 4): 5,
    ("i", 4): 6,
    ("u", 8): 7,
    ("i", 8): 8,
    ("f", 2): 9,
    ("f", 4): 10,
    ("f", 8): 11,
}
_DTYPE_OF_CODE = {code: np.dtype(f"<{kind}{size}") for (kind, size), code in _CODE_OF_KIND.items()}
# Fields at least this large are memory-mapped by read_tensor_file(mmap=True); smaller ones are loaded.
_MMAP_MIN_BYTES = 1 << 20
# Bytes converted and written per step.
_CHUNK_BYTES = 64 << 20


def _align(pos: int) -> int:
    return (pos + _ALIGN - 1) // _ALIGN * _ALIGN


def _prepare_field(name: Any, value: ArrayLike) -> tuple[bytes, NDArray, int]:
    if not isinstance(name, str) or not name:
        raise ValueError(f"tensor file field names must be non-empty strings; got {name!r}")
    label = name.encode("utf-8")
    if len(label) > 0xFFFF:
        raise ValueError(f"field {name[:40]!r}...: name longer than 65535 bytes")
    # No copy: a memmap stays on disk until it is written in chunks. A 0-d array is stored as (1,),
    # like mitsuba.tensor_io.write (np.ascontiguousarray); Mitsuba's Python reader cannot read ndim 0.
    arr = np.atleast_1d(np.asarray(value))
    code = _CODE_OF_KIND.get((arr.dtype.kind, arr.dtype.itemsize))
    if code is None:
        valid = ", ".join(str(d) for d in _DTYPE_OF_CODE.values())
        raise ValueError(f"field {name!r}: unsupported dtype {arr.dtype}; valid: {valid}")
    if arr.ndim > 0xFFFF:
        raise ValueError(f"field {name!r}: too many dimensions ({arr.ndim})")
    return label, arr, code


def _write_array(f: Any, arr: NDArray, chunk_fn: Callable[[NDArray], NDArray] | None) -> None:
    """Write ``arr`` in C order, little-endian, at most about ``_CHUNK_BYTES`` at a time."""
    le = arr.dtype.newbyteorder("<")
    if arr.ndim == 0 or arr.nbytes <= _CHUNK_BYTES:
        out = arr if chunk_fn is None else chunk_fn(arr)
        f.write(np.ascontiguousarray(out, dtype=le).tobytes())
        return
    row_bytes = arr.nbytes // arr.shape[0]
    if row_bytes > _CHUNK_BYTES and arr.ndim > 1:
        for row in arr:
            _write_array(f, row, chunk_fn)
        return
    step = max(1, _CHUNK_BYTES // max(row_bytes, 1))
    for start in range(0, arr.shape[0], step):
        _write_array(f, arr[start : start + step], chunk_fn)


def write_tensor_file(
    path: str | os.PathLike,
    fields: Mapping[str, ArrayLike],
    *,
    chunk_fns: Mapping[str, Callable[[NDArray], NDArray]] | None = None,
) -> Path:
    """Write named arrays to a Mitsuba ``tensor_file`` (version 1.0), atomically.

    The bytes equal those of ``mitsuba.tensor_io.write(path, **fields)``: the header
    (magic ``"tensor_file\\0"``, version 1.0, field count, then per field its name, ndim, dtype
    code, 64-bit offset and 64-bit shape), followed by the data of each field in C order at an
    8-byte aligned offset. Large arrays (including memory maps) are written in chunks of about
    64 MB, so a multi-gigabyte hpBRDF table needs no second copy in memory. The file is written
    to a temporary sibling, fsynced and renamed over ``path``; parent folders are created.

    Args:
        path: target file.
        fields: name -> array, in file order. Supported dtypes: uint8/16/32/64, int8/16/32/64,
            float16/32/64 (booleans and objects are not).
        chunk_fns: optional name -> function applied to each chunk of that field before it is
            written (same shape and dtype out), e.g. to zero the NaN bins of a memory-mapped
            table without loading it.

    Returns:
        The path written.

    Raises:
        ValueError: an empty or non-string name, or an unsupported dtype (the message names the field).
        OSError: the file cannot be written.

    Example:
        >>> import tempfile
        >>> p = Path(tempfile.mkdtemp()) / "x.tensor"
        >>> _ = write_tensor_file(p, {"wvls": np.array([450, 550], dtype=np.uint16)})
        >>> read_tensor_file(p)["wvls"]
        array([450, 550], dtype=uint16)
    """
    target = Path(path)
    if not isinstance(fields, Mapping):
        raise ValueError(f"{target}: fields must be a dict of name -> array; got {type(fields).__name__}")
    prepared = [_prepare_field(name, value) for name, value in fields.items()]
    chunk_fns = chunk_fns or {}

    header = bytearray(_MAGIC)
    header += struct.pack("<BBI", *_VERSION, len(prepared))
    header_size = len(header) + sum(2 + len(label) + 2 + 1 + 8 + 8 * arr.ndim for label, arr, _ in prepared)
    offsets = []
    pos = header_size
    for _, arr, _ in prepared:
        pos = _align(pos)
        offsets.append(pos)
        pos += arr.nbytes  # Python ints: no overflow for tables of many GB
    for (label, arr, code), offset in zip(prepared, offsets, strict=True):
        header += struct.pack("<H", len(label)) + label
        header += struct.pack("<HBQ", arr.ndim, code, offset)
        header += struct.pack(f"<{arr.ndim}Q", *arr.shape)

    if target.is_dir():
        raise IsADirectoryError(f"{target}: is a folder")
    with atomic_open(target) as f:
        f.write(header)
        pos = len(header)
        for (label, arr, _), offset in zip(prepared, offsets, strict=True):
            if arr.nbytes == 0:
                continue  # no padding either: Mitsuba's writer seeks, so a trailing empty field adds no bytes
            f.write(b"\x00" * (offset - pos))
            _write_array(f, arr, chunk_fns.get(label.decode("utf-8")))
            pos = offset + arr.nbytes
    return target


def _bad(path: Path, reason: str) -> ValueError:
    return ValueError(f"{path}: not a valid tensor file: {reason}")


def read_tensor_file(path: str | os.PathLike, *, mmap: bool = True) -> dict[str, NDArray]:
    """Read all fields of a Mitsuba ``tensor_file``.

    Args:
        path: file written by :func:`write_tensor_file`, ``mitsuba.tensor_io.write`` or Mitsuba's
            C++ ``TensorFile`` tools (KAIST ``.pbsdf``, hpBRDF ``.hpbrdf``).
        mmap: memory-map fields of 1 MiB or more as read-only :class:`numpy.memmap` instead of
            loading them (a multi-gigabyte hpBRDF ``M`` then costs no memory until it is used).
            Smaller fields are always loaded.

    Returns:
        name -> array in file order, with the stored dtype (native byte order where loaded).

    Raises:
        FileNotFoundError: no such file.
        ValueError: bad magic string, unsupported version, unknown dtype code, duplicate field
            name, or a truncated file (the header or a field's data ends past the end of the file).
    """
    p = Path(path)
    if p.is_dir():
        raise IsADirectoryError(f"{p}: is a folder, not a tensor file")
    size = p.stat().st_size
    with open(p, "rb") as f:

        def take(n: int, what: str) -> bytes:
            data = f.read(n)
            if len(data) != n:
                raise _bad(p, f"truncated header ({size} bytes; it ends inside {what})")
            return data

        magic = f.read(len(_MAGIC))
        if magic != _MAGIC:
            if len(magic) < len(_MAGIC) and _MAGIC.startswith(magic):
                raise _bad(p, f"truncated header ({size} bytes)")
            raise _bad(p, f"bad magic {magic!r} (expected {_MAGIC!r})")
        major, minor = struct.unpack("<BB", take(2, "the version"))
        if (major, minor) != _VERSION:
            raise _bad(p, f"unsupported version {major}.{minor} (expected 1.0)")
        (n_fields,) = struct.unpack("<I", take(4, "the field count"))
        specs: dict[str, tuple[np.dtype, int, tuple[int, ...]]] = {}
        for k in range(n_fields):
            what = f"field {k} of {n_fields}"
            (name_len,) = struct.unpack("<H", take(2, what))
            try:
                name = take(name_len, what).decode("utf-8")
            except UnicodeDecodeError as e:
                raise _bad(p, f"{what}: name is not UTF-8 ({e.reason})") from None
            ndim, code, offset = struct.unpack("<HBQ", take(11, f"field {name!r}"))
            shape = struct.unpack(f"<{ndim}Q", take(8 * ndim, f"the shape of field {name!r}"))
            if code not in _DTYPE_OF_CODE:
                raise _bad(p, f"field {name!r} has unknown dtype code {code} (valid: 1..11)")
            if name in specs:
                raise _bad(p, f"duplicate field {name!r}")
            specs[name] = (_DTYPE_OF_CODE[code], offset, tuple(int(s) for s in shape))

        out: dict[str, NDArray] = {}
        for name, (dtype, offset, shape) in specs.items():
            count = math.prod(shape)
            nbytes = count * dtype.itemsize
            if nbytes and offset + nbytes > size:
                raise _bad(
                    p, f"truncated: field {name!r} {shape} needs bytes {offset}..{offset + nbytes}, file has {size}"
                )
            if count == 0:
                out[name] = np.empty(shape, dtype=dtype.newbyteorder("="))
            elif mmap and nbytes >= _MMAP_MIN_BYTES:
                out[name] = np.memmap(p, dtype=dtype, mode="r", offset=offset, shape=shape)
            else:
                f.seek(offset)
                arr = np.fromfile(f, dtype=dtype, count=count).reshape(shape)  # one copy, however large
                out[name] = arr if arr.dtype.isnative else arr.astype(dtype.newbyteorder("="))
    return out
