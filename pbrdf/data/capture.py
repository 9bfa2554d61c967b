"""Real (or synthetic) captures on disk: one raw mosaic per exposure plus ``capture.json``.

A capture folder holds

* one single-channel raw IMX250MYR mosaic per exposure, ``(H, W)`` with H and W multiples of 4,
  as a 16-bit grayscale PNG, a 16-bit TIFF or a ``.npy`` array (black level included, values in
  ``[0, white_level]``), and
* ``capture.json``, for example::

    {
      "format": "pdir-capture/1",
      "exposures_s": [0.01, 0.02, 0.1, 0.2],
      "raw_files": ["raw_0010.0ms.png", "raw_0020.0ms.png", "raw_0100.0ms.png", "raw_0200.0ms.png"],
      "black_level": 16.0,
      "white_level": 4095,
      "bits": 12,
      "pattern_offset": [0, 0],
      "camera_model": {"qwp_angle": 0.0, "qwp_retardance": [1.5708, 1.5708, 1.5708], ...},
      "object": "any further keys are kept as metadata"
    }

``exposures_s`` and ``raw_files`` are required and correspond one to one (any order; they are
sorted by exposure on load). ``black_level``, ``white_level``, ``bits`` and ``pattern_offset``
are optional and, where present, override the same quantities inside ``camera_model`` (the
:meth:`pbrdf.sensor.camera.CameraModel.to_dict` of the calibrated rig, itself optional: defaults are
used for what it does not give). ``white_level`` must be ``2**bits - 1``: the decoder assumes
LSB-aligned data, so MSB-aligned 16-bit exports (e.g. 12-bit data times 16) must be shifted
right before saving. 8-bit data (an 8-bit PNG/TIFF, mode ``"L"``, or a uint8 ``.npy``; e.g. a
photo) is refused unless ``bits`` is 8. Every other top-level key is returned as
:attr:`Capture.metadata`.

An optional ``mask.png`` (:data:`MASK_FILE`) in the folder marks the object: an 8- or 16-bit
greyscale PNG (a bilevel one also works), nonzero on the object, the size of the decoded grid
(``(H/2, W/2)`` for the default ``"half"`` grid, ``(H, W)`` for ``"full"``) or of the raw frames
``(H, W)``; a raw-size mask is reduced to the half grid by 2x2 blocks (a block is object when at
least two of its four pixels are). It replaces the automatic object mask of
:mod:`pbrdf.sensor.foreground` (:attr:`DecodedCapture.foreground`); without it the object mask
is found from the capture alone.

Errors: :class:`FileNotFoundError` (missing folder, ``capture.json`` or raw file) and other
:class:`OSError` for I/O, :class:`ValueError` for bad content; every message names the file.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.io.atomic import fsync_path, temporary_path
from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.decode import Decoded, decode
from pbrdf.sensor.foreground import capture_foreground

__all__ = [
    "CAPTURE_FORMAT",
    "CAPTURE_JSON",
    "MASK_FILE",
    "RAW_SUFFIXES",
    "Capture",
    "DecodedCapture",
    "save_capture",
    "load_capture",
    "validate_capture",
    "decode_capture",
    "load_mask",
    "object_mask",
]

#: Value of the ``"format"`` key of ``capture.json``; bumped on incompatible changes.
CAPTURE_FORMAT = "pdir-capture/1"
#: Name of the sidecar inside a capture folder.
CAPTURE_JSON = "capture.json"
#: Optional object mask inside a capture folder (overrides the automatic foreground mask).
MASK_FILE = "mask.png"
#: File name suffixes of raw mosaics understood by :func:`load_capture`.
RAW_SUFFIXES = (".png", ".tif", ".tiff", ".npy")
#: Keys of ``capture.json`` written by :func:`save_capture`; ``extra`` may not use them.
_RESERVED_KEYS = (
    "format",
    "exposures_s",
    "raw_files",
    "black_level",
    "white_level",
    "bits",
    "pattern_offset",
    "camera_model",
)
_FILE_FORMATS = {"png": "png", "tiff": "tiff", "npy": "npy"}
# Pillow modes of single-channel integer images (16-bit PNG/TIFF open as "I;16"; old Pillow
# versions and 32-bit TIFFs give "I").
_GRAY_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I", "L")
# Pillow modes accepted for mask.png: bilevel, 8-bit and 16-bit greyscale.
_MASK_MODES = ("1", "L", "I;16", "I;16L", "I;16B", "I;16N", "I")


@dataclass
class Capture:
    """An HDR bracket of raw mosaics and the camera model it was taken with.

    Attributes:
        raws: ``(E, H, W)`` uint16 raw frames (black level included), sorted by exposure time.
        model: camera model; ``model.exposures`` are the ``E`` exposure times in seconds
            (ascending), ``model.sensor`` holds black level and bit depth.
        folder: the folder it was loaded from (None for an in-memory capture).
        metadata: the keys of ``capture.json`` that are not part of the format (object name,
            date, rig notes, ...).
        raw_files: file names of the raws inside ``folder``, in the order of ``raws``.
    """

    raws: NDArray[np.uint16]
    model: CameraModel
    folder: Path | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    raw_files: tuple[str, ...] = ()


def _raw_file_name(exposure: float, suffix: str) -> str:
    return f"raw_{exposure * 1e3:06.1f}ms.{suffix}"


def _write_raw(path: Path, raw: NDArray[np.uint16], file_format: str) -> None:
    """Write one ``(H, W)`` uint16 raw to ``path`` as PNG, TIFF or npy (exact, lossless)."""
    if file_format == "npy":
        with open(path, "wb") as f:
            np.save(f, np.ascontiguousarray(raw, dtype=np.uint16), allow_pickle=False)
            f.flush()
            os.fsync(f.fileno())
        return
    from PIL import Image

    # A little-endian uint16 array becomes mode "I;16", which PNG stores as 16-bit grayscale and
    # TIFF as 16-bit minisblack; both read back bit-exactly. (Pillow 13 rejects an explicit
    # ``mode="I;16"`` in ``fromarray``; the mode follows from the dtype.)
    img = Image.fromarray(np.ascontiguousarray(raw, dtype="<u2"))
    if img.mode != "I;16":  # pragma: no cover - guards against a Pillow behaviour change
        raise OSError(f"{path}: Pillow made a {img.mode!r} image from uint16 data, expected 'I;16'")
    with open(path, "wb") as f:
        img.save(f, format="PNG" if file_format == "png" else "TIFF")
        f.flush()
        os.fsync(f.fileno())


def _check_frame(raw: NDArray, where: str, white_level: int) -> NDArray[np.uint16]:
    """Check one raw frame and return it as uint16; ``where`` names it in error messages."""
    if raw.ndim != 2:
        hint = " (a colour image? expected a single-channel raw mosaic)" if raw.ndim == 3 else ""
        raise ValueError(f"{where}: raw must be a 2-D (H, W) mosaic; got shape {raw.shape}{hint}")
    h, w = raw.shape
    if h % 4 or w % 4 or h < 8 or w < 8:
        raise ValueError(f"{where}: raw size must be a multiple of 4 (the mosaic period) and at least 8x8; got {h}x{w}")
    kind = raw.dtype.kind
    if kind == "f":
        if np.isnan(raw).any():
            raise ValueError(f"{where}: NaN in raw")
        if not np.isfinite(raw).all():
            raise ValueError(f"{where}: Inf in raw")
        if np.any(raw != np.round(raw)):
            raise ValueError(f"{where}: float raw must hold whole DN values (it is stored as uint16)")
    elif kind not in "iu":
        raise ValueError(f"{where}: raw dtype must be an integer type (or float for .npy); got {raw.dtype}")
    if raw.size:
        lo, hi = raw.min(), raw.max()
        if lo < 0 or hi > np.iinfo(np.uint16).max:
            raise ValueError(f"{where}: raw values [{lo}, {hi}] do not fit uint16 [0, 65535]")
        if hi > white_level:
            raise ValueError(f"{where}: raw value {hi} above white_level {white_level}")
    return raw.astype(np.uint16, copy=False)


def validate_capture(capture: Capture) -> None:
    """Check that a capture is consistent and decodable; raise ValueError otherwise.

    Checks: ``raws`` is ``(E, H, W)`` with one frame per exposure of ``capture.model``, of an
    integer dtype (or whole-number float) fitting uint16, H and W multiples of 4 and >= 8, no
    value above the white level, black level below the white level, and frames in the order
    of the exposure times (a clearly exposed frame is not followed by one under half as bright
    at a longer exposure).

    Args:
        capture: the capture to check.

    Raises:
        ValueError: with a one-line message saying what is wrong.
    """
    where = str(capture.folder) if capture.folder is not None else "capture"
    raws = np.asarray(capture.raws)
    model = capture.model
    if raws.ndim != 3:
        raise ValueError(f"{where}: raws must have shape (E, H, W); got {raws.shape}")
    if raws.shape[0] != len(model.exposures):
        raise ValueError(
            f"{where}: {raws.shape[0]} raw frames for {len(model.exposures)} exposure times {model.exposures}"
        )
    _check_levels(model.sensor.black_level, model.sensor.white_level, where)
    for k in range(raws.shape[0]):
        _check_frame(raws[k], f"{where} (raw {k})", model.sensor.white_level)
    _check_order(raws, model, [f"raw {k}" for k in range(raws.shape[0])], where)


def _check_levels(black_level: float, white_level: int, where: str) -> None:
    if not black_level < white_level:
        raise ValueError(f"{where}: black_level {black_level} must be below white_level {white_level}")


def save_capture(
    folder: str | os.PathLike,
    raws: ArrayLike,
    model: CameraModel,
    *,
    file_format: str = "png",
    extra: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a capture folder atomically: raws (one file per exposure) plus ``capture.json``.

    Everything is written into a temporary sibling folder that is renamed into place at the end,
    so an interrupted run leaves either no folder or a complete one (never a half-written
    capture). With ``overwrite=True`` an existing folder is first renamed aside and deleted after
    the new one is in place.

    Args:
        folder: target folder; its parent must exist. It may exist only if empty (or with
            ``overwrite=True``).
        raws: ``(E, H, W)`` raw frames, one per exposure of ``model.exposures``, integer values
            in ``[0, model.sensor.white_level]``. Frames are sorted by exposure time on writing.
        model: the camera model (exposures, sensor levels, calibration).
        file_format: ``"png"`` (16-bit grayscale), ``"tiff"`` (16-bit) or ``"npy"``.
        extra: further JSON-serialisable keys for ``capture.json`` (returned as
            :attr:`Capture.metadata` by :func:`load_capture`); may not use the format's keys.
        overwrite: replace an existing non-empty folder.

    Returns:
        The path of the written folder.

    Raises:
        ValueError: invalid raws, model, file format or ``extra``.
        FileExistsError: ``folder`` exists, is not empty and ``overwrite`` is False.
        OSError: the folder cannot be written.
    """
    target = Path(folder)
    if file_format not in _FILE_FORMATS:
        raise ValueError(f"file_format must be one of {sorted(_FILE_FORMATS)}; got {file_format!r}")
    extra = dict(extra or {})
    clash = sorted(set(extra) & set(_RESERVED_KEYS))
    if clash:
        raise ValueError(f"extra may not set the capture format keys {clash}")
    r = np.asarray(raws)
    order = np.argsort(np.asarray(model.exposures, dtype=np.float64), kind="stable")
    if r.ndim == 3 and r.shape[0] == len(order):
        r = r[order]
    model = model.replace(exposures=tuple(model.exposures[i] for i in order))
    capture = Capture(raws=r, model=model, folder=None)
    validate_capture(capture)
    r = r.astype(np.uint16, copy=False)

    names = [_raw_file_name(t, file_format) for t in model.exposures]
    if len(set(names)) != len(names):  # repeated or nearly equal exposure times
        names = [f"raw_{k:02d}_{n[4:]}" for k, n in enumerate(names)]
    meta = {
        "format": CAPTURE_FORMAT,
        "exposures_s": list(model.exposures),
        "raw_files": names,
        "black_level": model.sensor.black_level,
        "white_level": model.sensor.white_level,
        "bits": model.sensor.bits,
        "pattern_offset": list(model.pattern_offset),
        "camera_model": model.to_dict(),
        **extra,
    }
    try:
        text = json.dumps(meta, indent=2, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{target}: capture metadata is not valid JSON ({e})") from e

    if target.is_symlink() or (target.exists() and not target.is_dir()):
        raise FileExistsError(f"{target}: exists and is not a folder")
    if target.exists() and any(target.iterdir()) and not overwrite:
        raise FileExistsError(f"{target}: folder exists and is not empty (pass overwrite=True to replace it)")
    parent = target.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"{parent}: parent folder of the capture does not exist")

    tmp = _make_sibling(target, "tmp")
    try:
        for name, raw in zip(names, r, strict=True):
            _write_raw(tmp / name, raw, file_format)
        with open(tmp / CAPTURE_JSON, "w", encoding="utf-8") as f:
            f.write(text + "\n")
            f.flush()
            os.fsync(f.fileno())
        fsync_path(tmp, directory=True)
        _move_into_place(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    fsync_path(parent, directory=True)
    return target


def _make_sibling(target: Path, tag: str) -> Path:
    """Create a new, uniquely named hidden folder next to ``target`` (usual permissions)."""
    for _ in range(100):
        path = temporary_path(target, tag)
        try:
            path.mkdir()
        except FileExistsError:  # pragma: no cover - 32 random bits collided
            continue
        return path
    raise FileExistsError(f"{target.parent}: cannot create a temporary folder")  # pragma: no cover


def _move_into_place(tmp: Path, target: Path) -> None:
    """Rename the finished ``tmp`` folder to ``target``, replacing an existing one."""
    if not target.exists():
        os.replace(tmp, target)
        return
    if not any(target.iterdir()):
        target.rmdir()
        os.replace(tmp, target)
        return
    old = _make_sibling(target, "old")
    old.rmdir()
    os.replace(target, old)
    try:
        os.replace(tmp, target)
    except BaseException:
        os.replace(old, target)  # put the previous capture back
        raise
    shutil.rmtree(old, ignore_errors=True)


def _read_raw(path: Path) -> NDArray:
    """Read one raw file as an ndarray (any dtype; checked by the caller)."""
    suffix = path.suffix.lower()
    if suffix not in RAW_SUFFIXES:
        raise ValueError(f"{path}: unsupported raw file type {suffix!r}; expected one of {list(RAW_SUFFIXES)}")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: raw file listed in {CAPTURE_JSON} does not exist")
    if suffix == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except (ValueError, EOFError) as e:
            raise ValueError(f"{path}: not a readable .npy array ({e})") from e
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
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


def _check_bit_depth(raw: NDArray, path: Path, bits: int) -> None:
    """Refuse 8-bit data (an 8-bit photo saved as a raw) for a sensor of more than 8 bits."""
    if raw.dtype.kind in "iu" and raw.dtype.itemsize == 1 and bits > 8:
        found = f"a {raw.dtype} array" if path.suffix.lower() == ".npy" else "an 8-bit greyscale image (mode 'L')"
        raise ValueError(
            f"{path}: raw is 8-bit ({found}) but the capture is {bits}-bit; expected the {bits}-bit raw "
            "mosaic as a 16-bit greyscale PNG/TIFF or a uint16 .npy"
        )


def _number(value: Any, name: str, where: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where}: {name} must be a number; got {value!r}")
    return float(value)


def _integer(value: Any, name: str, where: Path) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ValueError(f"{where}: {name} must be an integer; got {value!r}")
    return value


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: capture sidecar not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not UTF-8 text ({e})") from e
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: invalid JSON ({e})") from e
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level; got {type(meta).__name__}")
    return meta


def _model_from_meta(meta: dict[str, Any], exposures: tuple[float, ...], where: Path) -> CameraModel:
    """Camera model from ``camera_model`` with the top-level keys overriding it."""
    cam = meta.get("camera_model", {})
    if not isinstance(cam, dict):
        raise ValueError(f"{where}: camera_model must be a JSON object; got {type(cam).__name__}")
    cam = dict(cam)
    sensor = cam.get("sensor", {})
    if not isinstance(sensor, dict):
        raise ValueError(f"{where}: camera_model.sensor must be a JSON object; got {type(sensor).__name__}")
    sensor = dict(sensor)
    if "black_level" in meta:
        sensor["black_level"] = _number(meta["black_level"], "black_level", where)
    bits = _integer(meta["bits"], "bits", where) if "bits" in meta else None
    if "white_level" in meta:
        white = _integer(meta["white_level"], "white_level", where)
        wbits = (white + 1).bit_length() - 1
        if white < 1 or 2**wbits - 1 != white:
            raise ValueError(
                f"{where}: white_level {white} is not 2**bits - 1 (MSB-aligned data must be shifted "
                "right to LSB alignment first)"
            )
        if bits is not None and bits != wbits:
            raise ValueError(f"{where}: white_level {white} does not match bits {bits}")
        bits = wbits
    if bits is not None:
        sensor["bits"] = bits
    if sensor:
        cam["sensor"] = sensor
    if "pattern_offset" in meta:
        po = meta["pattern_offset"]
        if not isinstance(po, list) or len(po) != 2:
            raise ValueError(f"{where}: pattern_offset must be [row, col]; got {po!r}")
        cam["pattern_offset"] = [_integer(v, "pattern_offset", where) for v in po]
    cam["exposures"] = list(exposures)
    try:
        model = CameraModel.from_dict(cam)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: invalid camera model ({e})") from e
    _check_levels(model.sensor.black_level, model.sensor.white_level, where)
    return model


def _check_order(raws: NDArray, model: CameraModel, names: list[str], where: str | Path) -> None:
    """Catch exposures and raw files that do not correspond (a shorter exposure much brighter).

    The mean signal above black grows with exposure time (clipping keeps it monotone), so a
    clearly exposed frame followed by one under half as bright means swapped files. Dark frames
    (mean signal under 1 % of the range) are not judged.
    """
    black = model.sensor.black_level
    span = model.sensor.white_level - black
    t = model.exposures
    signal = [float(np.mean(r, dtype=np.float64)) - black for r in raws]
    order = sorted(range(len(t)), key=lambda k: t[k])
    for a, b in zip(order[:-1], order[1:], strict=True):
        if t[a] < t[b] and signal[a] > 0.01 * span and signal[b] < 0.5 * signal[a]:
            raise ValueError(
                f"{where}: raw files look out of order: {names[b]} ({t[b]:g} s) is darker than "
                f"{names[a]} ({t[a]:g} s); exposures and raw frames must correspond"
            )


def load_capture(folder: str | os.PathLike) -> Capture:
    """Load a capture folder written by :func:`save_capture` or by hand (see the module docs).

    Frames are sorted by exposure time (the file list follows). All checks of
    :func:`validate_capture` are applied per file.

    Args:
        folder: the capture folder holding ``capture.json``.

    Returns:
        :class:`Capture` with ``raws`` ``(E, H, W)`` uint16 and the camera model.

    Raises:
        FileNotFoundError: the folder, ``capture.json`` or a listed raw file is missing.
        ValueError: invalid JSON or content (each message names the file).
        OSError: other read errors.
    """
    root = Path(folder)
    if not root.exists():
        raise FileNotFoundError(f"{root}: capture folder does not exist")
    if not root.is_dir():
        raise NotADirectoryError(f"{root}: capture path is not a folder")
    jpath = root / CAPTURE_JSON
    meta = _read_json(jpath)

    fmt = meta.get("format")
    if fmt != CAPTURE_FORMAT:
        raise ValueError(f"{jpath}: unsupported format {fmt!r}; expected {CAPTURE_FORMAT!r}")
    for key in ("exposures_s", "raw_files"):
        if key not in meta:
            raise ValueError(f"{jpath}: missing required key {key!r}")
        if not isinstance(meta[key], list):
            raise ValueError(f"{jpath}: {key} must be a list; got {type(meta[key]).__name__}")
    exposures = [_number(t, "exposures_s entry", jpath) for t in meta["exposures_s"]]
    names = meta["raw_files"]
    if len(exposures) != len(names):
        raise ValueError(f"{jpath}: {len(exposures)} exposures_s but {len(names)} raw_files")
    if not exposures:
        raise ValueError(f"{jpath}: no exposures listed")
    for t in exposures:
        if not math.isfinite(t) or t <= 0:
            raise ValueError(f"{jpath}: exposure time {t} s must be positive and finite")
    for n in names:
        if not isinstance(n, str) or not n or n in (".", "..") or Path(n).name != n or "\\" in n:
            raise ValueError(f"{jpath}: raw_files entries must be plain file names in the folder; got {n!r}")
    if len(set(names)) != len(names):
        raise ValueError(f"{jpath}: raw_files lists a file more than once: {names}")

    order = sorted(range(len(exposures)), key=lambda k: exposures[k])
    exposures = [exposures[k] for k in order]
    names = [names[k] for k in order]
    model = _model_from_meta(meta, tuple(exposures), jpath)

    frames = []
    for n in names:
        path = root / n
        raw = _read_raw(path)
        _check_bit_depth(raw, path, model.sensor.bits)
        frame = _check_frame(raw, str(path), model.sensor.white_level)
        if frames and frame.shape != frames[0].shape:
            raise ValueError(f"{path}: raw shape {frame.shape} differs from {frames[0].shape} of {root / names[0]}")
        frames.append(frame)
    raws = np.stack(frames)
    _check_order(raws, model, names, jpath)
    metadata = {k: v for k, v in meta.items() if k not in _RESERVED_KEYS}
    return Capture(raws=raws, model=model, folder=root, metadata=metadata, raw_files=tuple(names))


@dataclass
class DecodedCapture(Decoded):
    """:class:`pbrdf.sensor.decode.Decoded` of a capture, with its object mask.

    ``maps``, ``mask`` and ``stokes`` are exactly those of :func:`pbrdf.sensor.decode.decode`
    (``mask``: measured and ``s0`` above ``min_signal``; ``maps`` are 0 outside it).

    Attributes:
        measured: ``(H', W')`` bool, the pixels the decoder measured: some exposure unsaturated
            over the whole demosaic support and finite maps (no signal threshold: the dark
            background is "measured" too).
        foreground: ``(H', W')`` bool, the object: the folder's ``mask.png`` if there is one,
            else the automatic mask of :func:`pbrdf.sensor.foreground.capture_foreground`.
        foreground_source: the path of the ``mask.png`` used, or ``"auto"``.
    """

    measured: NDArray[np.bool_]
    foreground: NDArray[np.bool_]
    foreground_source: str

    @property
    def input_mask(self) -> NDArray[np.bool_]:
        """``(H', W')`` bool, the pixels to give the network: ``foreground & measured``."""
        return self.foreground & self.measured


def load_mask(path: str | os.PathLike, shape: tuple[int, int], raw_shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Read an object mask (``mask.png``, see the module docs) onto the decoded grid.

    Args:
        path: the mask image: 8- or 16-bit greyscale (or bilevel) PNG, nonzero = object.
        shape: ``(H', W')`` of the decoded grid.
        raw_shape: ``(H, W)`` of the raw frames; a mask of this size is reduced to the half grid
            by 2x2 blocks (object where at least two of the four pixels are).

    Returns:
        ``(H', W')`` bool.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a readable single-frame greyscale image, wrong size or no object pixel
            (one line naming the file).
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: mask file does not exist")
    try:
        with Image.open(path) as img:
            if getattr(img, "n_frames", 1) != 1:
                raise ValueError(f"{path}: mask has {img.n_frames} frames; expected one greyscale image")
            if img.mode not in _MASK_MODES:
                raise ValueError(
                    f"{path}: mask must be an 8- or 16-bit greyscale image (nonzero = object); got mode {img.mode!r}"
                )
            img.load()
            mask = np.array(img) != 0
    except UnidentifiedImageError as e:
        raise ValueError(f"{path}: mask is not a readable PNG image") from e
    except (OSError, SyntaxError) as e:
        if isinstance(e, FileNotFoundError | PermissionError):
            raise
        raise ValueError(f"{path}: cannot read mask image ({e})") from e
    shape, raw_shape = tuple(shape), tuple(raw_shape)
    if mask.shape != shape:
        h, w = raw_shape
        if mask.shape != raw_shape or shape != (h // 2, w // 2):
            raise ValueError(
                f"{path}: mask size {mask.shape[1]}x{mask.shape[0]} matches neither the decoded grid "
                f"{shape[1]}x{shape[0]} nor the raw frames {w}x{h}"
            )
        count = mask[0::2, 0::2].astype(np.uint8) + mask[0::2, 1::2] + mask[1::2, 0::2] + mask[1::2, 1::2]
        mask = count >= 2
    if not mask.any():
        raise ValueError(f"{path}: mask has no object pixel (nonzero marks the object)")
    return mask


def object_mask(capture: Capture, decoded: Decoded, *, grid: str = "half") -> tuple[NDArray[np.bool_], str]:
    """The object mask of a decoded capture: its folder's ``mask.png``, else the automatic one.

    Args:
        capture: the capture (its ``folder`` is searched for :data:`MASK_FILE`; None: automatic).
        decoded: its decoded maps on ``grid``.
        grid: the decode grid, ``"half"`` or ``"full"``.

    Returns:
        ``(mask (H', W') bool, source)``, ``source`` the mask file's path or ``"auto"``.

    Raises:
        ValueError: a bad ``mask.png`` (one line naming the file).
    """
    if capture.folder is not None and (Path(capture.folder) / MASK_FILE).exists():
        path = Path(capture.folder) / MASK_FILE
        return load_mask(path, decoded.mask.shape, capture.raws.shape[1:]), str(path)
    return capture_foreground(decoded, capture.model, grid=grid), "auto"


def decode_capture(
    capture: Capture | str | os.PathLike,
    *,
    grid: str = "half",
    eps: float = 1e-6,
    min_signal: float = 0.0,
) -> DecodedCapture:
    """Load (if given a folder) and decode a capture into the nine maps and its object mask.

    Args:
        capture: a :class:`Capture` or the path of a capture folder.
        grid: ``"half"`` (``(H/2, W/2)`` output) or ``"full"`` (``(H, W)``); see
            :func:`pbrdf.sensor.decode.decode`.
        eps: CP regulariser (:func:`pbrdf.sensor.decode.nine_maps`).
        min_signal: pixels whose total ``s0`` is not above this are left out of ``mask`` (and
            their maps are 0), as in :func:`pbrdf.sensor.decode.decode`.

    Returns:
        :class:`DecodedCapture` with ``maps`` ``(H', W', 9)`` float32, ``mask`` ``(H', W')`` bool
        and ``stokes`` ``(H', W', 3, 3)`` float32 exactly as :func:`pbrdf.sensor.decode.decode`
        gives them, plus ``measured``, ``foreground`` and ``input_mask`` (the network's mask).

    Raises:
        ValueError: bad capture content or a bad ``mask.png``.
    """
    cap = capture if isinstance(capture, Capture) else load_capture(capture)
    if isinstance(capture, Capture):
        validate_capture(cap)
    # Decode without a signal threshold (the measured pixels), then apply it exactly as decode().
    dec = decode(cap.raws, cap.model, grid=grid, eps=eps, min_signal=-np.inf)
    measured = dec.mask
    st = np.moveaxis(dec.stokes, (2, 3), (0, 1))  # decode()'s own (colour, component, H', W') layout
    mask = measured & (st[:, 0].sum(axis=0) > min_signal)
    maps = dec.maps
    if not mask.all():
        maps[~mask] = 0.0
    out = Decoded(maps=maps, mask=mask, stokes=dec.stokes)
    foreground, source = object_mask(cap, out, grid=grid)
    return DecodedCapture(
        maps=maps, mask=mask, stokes=dec.stokes, measured=measured, foreground=foreground, foreground_source=source
    )
