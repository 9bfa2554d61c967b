"""One raw mosaic frame on disk: a 16-bit greyscale PNG, a 16-bit TIFF or a ``.npy`` array.

:func:`write_raw` stores an ``(H, W)`` uint16 frame losslessly; :func:`read_raw` reads one back
as an ndarray of any dtype (its content is checked by :mod:`pbrdf.data.capture`). Both kinds of
header are checked before any pixel is read: an image or ``.npy`` array that declares more
than :func:`max_raw_pixels` pixels is refused with one line naming the file, instead of an
allocation of many GiB (a ``MemoryError``) or a decompression bomb. A raw sensor has a few
million pixels; the limit is Pillow's image-bomb limit, the same for every file type.

Errors: :class:`FileNotFoundError` for a missing file, :class:`ValueError` (message starting with
the path) for content that is not one readable raw frame.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["RAW_FORMATS", "RAW_SUFFIXES", "max_raw_pixels", "open_image", "read_raw", "write_raw"]

#: File name suffixes of raw frames :func:`read_raw` understands.
RAW_SUFFIXES = (".png", ".tif", ".tiff", ".npy")
#: File formats :func:`write_raw` writes (the file name suffix is the format's name).
RAW_FORMATS = ("png", "tiff", "npy")
# Pillow modes of single-channel integer images (16-bit PNG/TIFF open as "I;16"; old Pillow
# versions and 32-bit TIFFs give "I").
_GRAY_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I", "L")
# dtype kinds a raw may have on disk (checked further by the capture: integer, or whole floats).
_NPY_KINDS = "iuf"


def max_raw_pixels() -> int:
    """The most pixels a raw file may declare: Pillow's image-bomb limit, ``2 * Image.MAX_IMAGE_PIXELS``.

    Example:
        >>> max_raw_pixels() > 2448 * 2048  # the default sensor fits with room to spare
        True
    """
    from PIL import Image

    return 2 * int(Image.MAX_IMAGE_PIXELS)


def write_raw(path: Path, raw: NDArray[np.uint16], file_format: str) -> None:
    """Write one ``(H, W)`` uint16 raw to ``path`` as PNG, TIFF or npy (exact, lossless).

    Args:
        path: the file (written directly: stage it in :func:`pbrdf.io.atomic.atomic_folder`).
        raw: ``(H, W)`` frame with values in ``[0, 65535]``.
        file_format: one of :data:`RAW_FORMATS`.
    """
    if file_format == "npy":
        np.save(path, np.ascontiguousarray(raw, dtype=np.uint16), allow_pickle=False)
        return
    from PIL import Image

    # A little-endian uint16 array becomes mode "I;16", which PNG stores as 16-bit grayscale and
    # TIFF as 16-bit minisblack; both read back bit-exactly. (Pillow 13 rejects an explicit
    # ``mode="I;16"`` in ``fromarray``; the mode follows from the dtype.)
    img = Image.fromarray(np.ascontiguousarray(raw, dtype="<u2"))
    if img.mode != "I;16":  # pragma: no cover - guards against a Pillow behaviour change
        raise OSError(f"{path}: Pillow made a {img.mode!r} image from uint16 data, expected 'I;16'")
    img.save(path, format="PNG" if file_format == "png" else "TIFF")


def read_raw(path: Path) -> NDArray:
    """Read one raw file as an ndarray (any dtype; its shape and values are checked by the caller).

    Raises:
        FileNotFoundError: no such file.
        ValueError: an unsupported suffix, a header declaring too many pixels or an unusable
            dtype, a multi-frame or colour image, or unreadable content (one line naming the file).
    """
    suffix = path.suffix.lower()
    if suffix not in RAW_SUFFIXES:
        raise ValueError(f"{path}: unsupported raw file type {suffix!r}; expected one of {list(RAW_SUFFIXES)}")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: raw file does not exist")
    if suffix == ".npy":
        return _read_npy(path)
    from PIL import UnidentifiedImageError

    try:
        with open_image(path, "raw") as img:
            n_frames = getattr(img, "n_frames", 1)
            if n_frames != 1:
                raise ValueError(f"{path}: image has {n_frames} frames; expected one raw mosaic per file")
            bands = len(img.getbands())
            if bands != 1:
                raise ValueError(
                    f"{path}: colour image (mode {img.mode!r}, {bands} channels); expected a "
                    "single-channel 16-bit raw mosaic"
                )
            if img.mode not in _GRAY_MODES:
                raise ValueError(
                    f"{path}: image mode {img.mode!r} is not an integer grayscale mode {list(_GRAY_MODES)}"
                )
            img.load()
            return np.array(img)
    except UnidentifiedImageError as e:
        raise ValueError(f"{path}: not a readable PNG/TIFF image") from e
    except (OSError, SyntaxError) as e:
        if isinstance(e, FileNotFoundError | PermissionError):
            raise
        raise ValueError(f"{path}: cannot read image ({e})") from e


def _read_npy(path: Path) -> NDArray:
    """A ``.npy`` raw, its header (dtype, shape) checked before the array is allocated."""
    fmt = np.lib.format
    try:
        with open(path, "rb") as f:
            version = fmt.read_magic(f)
            if version == (1, 0):
                shape, _, dtype = fmt.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, _, dtype = fmt.read_array_header_2_0(f)
            else:  # 3.0 only differs for structured dtypes with non-latin-1 field names: no raw
                raise ValueError(f"format version {version[0]}.{version[1]} is not 1.0 or 2.0")
    except (ValueError, EOFError, SyntaxError) as e:
        raise ValueError(f"{path}: not a readable .npy array ({' '.join(str(e).split())})") from None
    if dtype.hasobject:  # np.load would need pickle, which is refused
        raise ValueError(f"{path}: not a readable .npy array (an object array; pickled data is refused)")
    if dtype.kind not in _NPY_KINDS:
        raise ValueError(f"{path}: raw dtype must be an integer type (or float for .npy); got {dtype}")
    pixels = math.prod(shape)
    if pixels > max_raw_pixels():
        raise ValueError(
            f"{path}: .npy array too large to read: its header declares shape {shape} ({pixels} pixels, "
            f"more than the {max_raw_pixels()} a raw file may have)"
        )
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, EOFError) as e:
        raise ValueError(f"{path}: not a readable .npy array ({' '.join(str(e).split())})") from e


def open_image(path: Path, what: str):
    """``PIL.Image.open(path)``, refusing images that declare too many pixels (one-line ValueError).

    Pillow raises ``DecompressionBombError`` above :func:`max_raw_pixels` (about 179 M pixels)
    and warns above half that; the warning is not printed (a genuine image of that size loads, a
    header that only claims it fails on reading), the error names the file.

    Args:
        path: the image file.
        what: the image's role in the message (``"raw"``, ``"mask"``).
    """
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            return Image.open(path)
    except Image.DecompressionBombError as e:
        reason = " ".join(str(e).split())
        raise ValueError(f"{path}: {what} image too large to read ({reason})") from None
