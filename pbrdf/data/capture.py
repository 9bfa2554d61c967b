"""Real (or synthetic) captures on disk: one raw mosaic per exposure plus ``capture.json``.

A capture folder holds

* one single-channel raw IMX250MYR mosaic per exposure, ``(H, W)`` with H and W multiples of 4,
  as a 16-bit grayscale PNG, a 16-bit TIFF or a ``.npy`` array (black level included, values in
  ``[0, white_level]``; the files: :mod:`pbrdf.data.raw_files`), and
* ``capture.json``, for example::

    {
      "format": "pdir-capture/1",
      "exposures_s": [0.01, 0.02, 0.1, 0.2],
      "raw_files": ["raw_0010.0ms.png", "raw_0020.0ms.png", "raw_0100.0ms.png", "raw_0200.0ms.png"],
      "dark_files": ["dark_0010.0ms.png", "dark_0020.0ms.png", "dark_0100.0ms.png", "dark_0200.0ms.png"],
      "black_level": 16.0,
      "white_level": 4095,
      "bits": 12,
      "pattern_offset": [0, 0],
      "camera_model": {"qwp_angle": 0.0, "qwp_retardance": [1.5708, 1.5708, 1.5708], ...},
      "radiometry": "calibrated",
      "rig": {"display": {"radiance": 1.0}},
      "intrinsics": [[2200.0, 0.0, 1224.0], [0.0, 2200.0, 1024.0], [0.0, 0.0, 1.0]],
      "distance_m": 0.7,
      "object": "any further keys are kept as metadata"
    }

``exposures_s`` and ``raw_files`` are required and correspond one to one (any order; they are
sorted by exposure on load). The optional ``dark_files``, one per exposure in the order of
``exposures_s``, are dark frames (display off: ambient light and sensor offset) that the decoder
subtracts (:func:`pbrdf.sensor.decode.decode`). ``black_level``, ``white_level``, ``bits`` and ``pattern_offset``
are optional and, where present, override the same quantities inside ``camera_model`` (the
:meth:`pbrdf.sensor.camera.CameraModel.to_dict` of the calibrated rig, itself optional: defaults are
used for what it does not give). ``white_level`` must be ``2**bits - 1``: the decoder assumes
LSB-aligned data, so MSB-aligned 16-bit exports (e.g. 12-bit data times 16) must be shifted
right before saving. 8-bit data (an 8-bit PNG/TIFF, mode ``"L"``, or a uint8 ``.npy``; e.g. a
photo) is refused unless ``bits`` is 8. Every other top-level key is returned as
:attr:`Capture.metadata`.

The radiometry and geometry keys (``"radiometry"``, ``"rig"``, ``"intrinsics"``, ``"distance_m"``):
:mod:`pbrdf.data.capture_meta`.

This module is the one reader of ``capture.json``: :func:`load_capture` parses and checks every
key once, the radiometry and geometry keys into
:class:`~pbrdf.data.capture_meta.CaptureMeta` (:attr:`Capture.meta`);
:func:`read_capture_meta` reads that part alone, without the raw frames.

Decoding a folder, with its object mask (``mask.png`` or automatic): :mod:`pbrdf.data.capture_decode`.

Errors: :class:`FileNotFoundError` (missing folder, ``capture.json`` or raw file) and other
:class:`OSError` for I/O, :class:`ValueError` for bad content; every message names the file.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.data._common import json_number, short_repr
from pbrdf.data.capture_meta import CaptureMeta, parse_capture_meta
from pbrdf.data.raw_files import RAW_FORMATS, RAW_SUFFIXES, read_raw, write_raw
from pbrdf.io.atomic import atomic_folder
from pbrdf.io.strict_json import read_json_object
from pbrdf.sensor.camera import CAMERA_RANGES, CameraModel

__all__ = [
    "CAPTURE_FORMAT",
    "CAPTURE_JSON",
    "Capture",
    "read_capture_meta",
    "read_capture_files",
    "save_capture",
    "load_capture",
    "validate_capture",
]

#: Value of the ``"format"`` key of ``capture.json``; bumped on incompatible changes.
CAPTURE_FORMAT = "pdir-capture/1"
#: Name of the sidecar inside a capture folder.
CAPTURE_JSON = "capture.json"
#: Keys of ``capture.json`` written by :func:`save_capture`; ``extra`` may not use them.
_RESERVED_KEYS = (
    "format",
    "exposures_s",
    "raw_files",
    "dark_files",
    "black_level",
    "white_level",
    "bits",
    "pattern_offset",
    "camera_model",
)


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
        meta: the radiometry and geometry keys (defaults for an in-memory capture).
        dark: ``(E, H, W)`` uint16 dark frames (display off) in the order of ``raws``, or None.
    """

    raws: NDArray[np.uint16]
    model: CameraModel
    folder: Path | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    raw_files: tuple[str, ...] = ()
    meta: CaptureMeta = field(default_factory=CaptureMeta)
    dark: NDArray[np.uint16] | None = None


def _raw_file_name(exposure: float, suffix: str) -> str:
    return f"raw_{exposure * 1e3:06.1f}ms.{suffix}"


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
    if capture.dark is not None:
        dark = np.asarray(capture.dark)
        if dark.shape != raws.shape:
            raise ValueError(f"{where}: dark frames have shape {dark.shape}; the raws {raws.shape}")
        for k in range(dark.shape[0]):
            _check_frame(dark[k], f"{where} (dark {k})", model.sensor.white_level)


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
    dark: ArrayLike | None = None,
) -> Path:
    """Write a capture folder atomically: raws (one file per exposure) plus ``capture.json``.

    Everything is written into a temporary sibling folder that is renamed into place at the end
    (:func:`pbrdf.io.atomic.atomic_folder`), so an interrupted run leaves either no folder or a
    complete one (never a half-written capture). With ``overwrite=True`` an existing folder is
    first renamed aside and deleted after the new one is in place.

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
        dark: ``(E, H, W)`` dark frames (display off) in the order of ``raws``, or None.

    Returns:
        The path of the written folder.

    Raises:
        ValueError: invalid raws, model, file format or ``extra``.
        FileExistsError: ``folder`` exists, is not empty and ``overwrite`` is False.
        OSError: the folder cannot be written.
    """
    target = Path(folder)
    if file_format not in RAW_FORMATS:
        raise ValueError(f"file_format must be one of {sorted(RAW_FORMATS)}; got {file_format!r}")
    extra = dict(extra or {})
    clash = sorted(set(extra) & set(_RESERVED_KEYS))
    if clash:
        raise ValueError(f"extra may not set the capture format keys {clash}")
    r = np.asarray(raws)
    order = np.argsort(np.asarray(model.exposures, dtype=np.float64), kind="stable")
    d = None if dark is None else np.asarray(dark)
    if r.ndim == 3 and r.shape[0] == len(order):
        r = r[order]
        d = d[order] if d is not None and d.shape == r.shape else d
    model = model.replace(exposures=tuple(model.exposures[i] for i in order))
    capture = Capture(raws=r, model=model, folder=None, dark=d)
    validate_capture(capture)
    r = r.astype(np.uint16, copy=False)

    names = [_raw_file_name(t, file_format) for t in model.exposures]
    if len(set(names)) != len(names):  # repeated or nearly equal exposure times
        names = [f"raw_{k:02d}_{n[4:]}" for k, n in enumerate(names)]
    meta = {
        "format": CAPTURE_FORMAT,
        "exposures_s": list(model.exposures),
        "raw_files": names,
        **({} if d is None else {"dark_files": ["dark" + n[3:] for n in names]}),
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

    with atomic_folder(target) as tmp:
        for name, raw in zip(names, r, strict=True):
            write_raw(tmp / name, raw, file_format)
        for name, frame in zip(names if d is not None else [], d if d is not None else [], strict=True):
            write_raw(tmp / ("dark" + name[3:]), frame.astype(np.uint16), file_format)
        (tmp / CAPTURE_JSON).write_text(text + "\n", encoding="utf-8")
    return target


def _check_bit_depth(raw: NDArray, path: Path, bits: int) -> None:
    """Refuse 8-bit data (an 8-bit photo saved as a raw) for a sensor of more than 8 bits."""
    if raw.dtype.kind in "iu" and raw.dtype.itemsize == 1 and bits > 8:
        found = f"a {raw.dtype} array" if path.suffix.lower() == ".npy" else "an 8-bit greyscale image (mode 'L')"
        raise ValueError(
            f"{path}: raw is 8-bit ({found}) but the capture is {bits}-bit; expected the {bits}-bit raw "
            "mosaic as a 16-bit greyscale PNG/TIFF or a uint16 .npy"
        )


def _integer(value: Any, name: str, where: Path) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ValueError(f"{where}: {name} must be an integer; got {short_repr(value)}")
    return value


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
        sensor["black_level"] = json_number(meta["black_level"], "black_level", where)
    bits = _integer(meta["bits"], "bits", where) if "bits" in meta else None
    if "white_level" in meta:
        white = _integer(meta["white_level"], "white_level", where)
        wbits = (white + 1).bit_length() - 1
        if white < 1 or 2**wbits - 1 != white:
            raise ValueError(
                f"{where}: white_level {short_repr(white)} is not 2**bits - 1 (MSB-aligned data must be shifted "
                "right to LSB alignment first)"
            )
        if bits is not None and bits != wbits:
            raise ValueError(f"{where}: white_level {short_repr(white)} does not match bits {short_repr(bits)}")
        bits = wbits
    if bits is not None:
        sensor["bits"] = bits
    if sensor:
        cam["sensor"] = sensor
    if "pattern_offset" in meta:
        po = meta["pattern_offset"]
        if not isinstance(po, list) or len(po) != 2:
            raise ValueError(f"{where}: pattern_offset must be [row, col]; got {short_repr(po)}")
        cam["pattern_offset"] = [_integer(v, "pattern_offset", where) for v in po]
    cam["exposures"] = list(exposures)
    try:
        model = CameraModel.from_dict(cam)
    except (TypeError, ValueError, OverflowError) as e:
        raise ValueError(f"{where}: invalid camera model ({' '.join(str(e).split())})") from None
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
    :func:`validate_capture` are applied per file; a ``.npy`` header is checked before its
    array is read (a declared size no sensor has is an error, not an allocation).

    Args:
        folder: the capture folder holding ``capture.json``.

    Returns:
        :class:`Capture` with ``raws`` ``(E, H, W)`` uint16, the camera model and :class:`CaptureMeta`.

    Raises:
        FileNotFoundError: the folder, ``capture.json`` or a listed raw file is missing.
        ValueError: invalid JSON or content (each message names the file).
        OSError: other read errors.
    """
    root = _capture_folder(folder)
    jpath = root / CAPTURE_JSON
    model, names, metadata, meta, dark_names = _parse_capture_json(jpath)
    frames = _read_frames(root, names + (dark_names or []), model)  # dark frames: the raws' size too
    raws, dark = frames[: len(names)], frames[len(names) :] if dark_names else None
    _check_order(raws, model, names, jpath)
    return Capture(raws=raws, model=model, folder=root, metadata=metadata, raw_files=tuple(names), meta=meta, dark=dark)


def _read_frames(root: Path, names: list[str], model: CameraModel) -> NDArray[np.uint16]:
    """The listed raw files of a capture folder, checked, as ``(E, H, W)`` uint16."""
    frames = []
    for n in names:
        path = root / n
        if path.suffix.lower() in RAW_SUFFIXES and not path.is_file():
            raise FileNotFoundError(f"{path}: raw file listed in {CAPTURE_JSON} does not exist")
        raw = read_raw(path)
        _check_bit_depth(raw, path, model.sensor.bits)
        frame = _check_frame(raw, str(path), model.sensor.white_level)
        if frames and frame.shape != frames[0].shape:
            raise ValueError(f"{path}: raw shape {frame.shape} differs from {frames[0].shape} of {root / names[0]}")
        frames.append(frame)
    return np.stack(frames)


def read_capture_meta(folder: str | os.PathLike) -> CaptureMeta:
    """The radiometry and geometry of a capture folder, without reading its raw frames.

    ``capture.json`` is checked whole, as :func:`load_capture` checks it (same messages).

    Raises:
        FileNotFoundError: the folder or ``capture.json`` is missing.
        ValueError: invalid JSON or content (the message names the file).
    """
    return _parse_capture_json(_capture_folder(folder) / CAPTURE_JSON)[3]


def read_capture_files(folder: str | os.PathLike) -> tuple[tuple[float, ...], list[str]]:
    """Exposure times (ascending) and raw file names of a capture folder, checked as in :func:`load_capture`."""
    model, names, *_ = _parse_capture_json(_capture_folder(folder) / CAPTURE_JSON)
    return model.exposures, names


def _capture_folder(folder: str | os.PathLike) -> Path:
    root = Path(folder)
    if not root.exists():
        raise FileNotFoundError(f"{root}: capture folder does not exist")
    if not root.is_dir():
        raise NotADirectoryError(f"{root}: capture path is not a folder")
    return root


def _parse_capture_json(jpath: Path) -> tuple[CameraModel, list[str], dict[str, Any], CaptureMeta, list[str] | None]:
    """``capture.json`` parsed and checked: camera model, raw files (by exposure), metadata, meta, dark files."""
    meta = read_json_object(jpath, CAPTURE_FORMAT, what="capture sidecar")
    for key in ("exposures_s", "raw_files"):
        if key not in meta:
            raise ValueError(f"{jpath}: missing required key {key!r}")
        if not isinstance(meta[key], list):
            raise ValueError(f"{jpath}: {key} must be a list; got {type(meta[key]).__name__}")
    exposures = [json_number(t, "exposures_s entry", jpath) for t in meta["exposures_s"]]
    names = meta["raw_files"]
    if len(exposures) != len(names):
        raise ValueError(f"{jpath}: {len(exposures)} exposures_s but {len(names)} raw_files")
    if not exposures:
        raise ValueError(f"{jpath}: no exposures listed")
    lo, hi = CAMERA_RANGES["exposures"]
    for t in exposures:
        if not lo <= t <= hi:
            raise ValueError(f"{jpath}: exposures_s entry {t:g} s is outside the valid range [{lo:g}, {hi:g}] s")
    dark = meta.get("dark_files")
    if dark is not None and (not isinstance(dark, list) or len(dark) != len(names)):
        raise ValueError(f"{jpath}: dark_files must be a list of {len(names)} file names, one per exposures_s entry")
    for key, files in (("raw_files", names), ("dark_files", dark or [])):
        for n in files:
            if not isinstance(n, str) or not n or n in (".", "..") or Path(n).name != n or "\\" in n or len(n) > 255:
                raise ValueError(
                    f"{jpath}: {key} entries must be plain file names in the folder; got {short_repr(n, 60)}"
                )
        if len(set(files)) != len(files):
            raise ValueError(f"{jpath}: {key} lists a file more than once: {files}")

    order = sorted(range(len(exposures)), key=lambda k: exposures[k])
    exposures = [exposures[k] for k in order]
    names = [names[k] for k in order]
    dark = None if dark is None else [dark[k] for k in order]
    model = _model_from_meta(meta, tuple(exposures), jpath)
    metadata = {k: v for k, v in meta.items() if k not in _RESERVED_KEYS}
    return model, names, metadata, parse_capture_meta(metadata, jpath), dark
