"""A prediction folder: the predicted maps' names and files, ``<name>_camera.json`` and ``<name>_sequence.json``.

The network's inference (``headless/infer.py``) writes these files and the Blender add-on's
import (:mod:`blender_addon.core.map_names`, :mod:`blender_addon.core.frustum`) reads them, both
through this module, so writer and reader cannot drift apart. It lives in ``pbrdf``, the bottom
layer that ``network``, ``blender_addon.core`` and the add-on's bpy half may all import
(``tests/test_layers.py``); the extension zip vendors ``pbrdf`` as ``_vendor/pbrdf``
(``tools/build_addon.py``), so an installed add-on has it too. Only numpy (and Pillow and
OpenEXR for :func:`write_predictions`) are needed.

Files of a prediction ``<name>`` in a folder:

* ``<name>_<map>.exr`` for each map of :data:`MAP_NAMES` the prediction holds: float32, full
  input size, zero outside the mask; normals are camera-space unit vectors (x right, y up, z
  toward the camera; channels X, Y, Z), depth in m along the viewing axis, one-channel maps in Y;
  ``<name>_<map>.png`` is an 8-bit preview of each.
* ``<name>_camera.json``: the maps' pinhole camera (:class:`CameraRecord`)::

    {"intrinsics": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "width": W, "height": H, "distance_m": 0.7}

A sequence is ``<name>_NNNN_<map>.exr`` per frame (``NNNN`` from 0001: Blender numbers image
sequences by the last digits of a file name) plus ``<name>_sequence.json`` (:class:`SequenceRecord`)::

    {"name": "face", "frames": [{"frame": 1, "prefix": "face_0001", "capture": "/abs/frame_a",
     "seconds": 2.5}, ...], "frames_per_second": 0.4, "timed": "..."}

Errors: readers raise FileNotFoundError for a missing file and a one-line ValueError starting
with the file and the field (``cap_camera.json: width: missing``).
"""

from __future__ import annotations

import io
import json
import math
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.io.atomic import atomic_folder, atomic_write_text
from pbrdf.io.strict_json import read_json_object

__all__ = [
    "OUTPUT_CHANNELS",
    "MAP_NAMES",
    "CAMERA_SUFFIX",
    "SEQUENCE_SUFFIX",
    "CameraRecord",
    "SequenceRecord",
    "write_predictions",
    "write_sequence",
]

#: The network's output maps and their channel counts (the decoder's heads, in this order).
OUTPUT_CHANNELS = {"normal": 3, "albedo": 3, "roughness": 1, "metallic": 1}
#: Every map a prediction folder may hold: the outputs, the object mask and the relief depth.
MAP_NAMES = (*OUTPUT_CHANNELS, "mask", "depth")
#: ``<prefix>_camera.json``: the maps' pinhole camera.
CAMERA_SUFFIX = "_camera.json"
#: ``<name>_sequence.json``: the frames of a sequence.
SEQUENCE_SUFFIX = "_sequence.json"


@dataclass(frozen=True)
class CameraRecord:
    """A ``<name>_camera.json``: the maps' pinhole camera, for a matching Blender camera.

    Attributes:
        intrinsics: ``K (3, 3)`` of the maps' grid, pixel centres at integer + 0.5 (OpenCV
            convention, :mod:`pbrdf.sensor.projection`); finite, positive focal lengths.
        width: map columns W.
        height: map rows H.
        distance_m: the capture's object distance in m, or None.
    """

    intrinsics: NDArray[np.float64]
    width: int
    height: int
    distance_m: float | None = None

    @classmethod
    def of_maps(cls, intrinsics: ArrayLike, shape: tuple[int, int], distance_m: float | None) -> CameraRecord:
        """The record of maps of ``shape (H, W)`` with these intrinsics; ValueError naming the bad field.

        Example:
            >>> CameraRecord.of_maps(np.diag([80.0, 80.0, 1.0]), (48, 64), None).to_dict()["width"]
            64
        """
        return cls._checked(intrinsics, shape[1], shape[0], distance_m)

    @classmethod
    def read(cls, path: str | os.PathLike) -> CameraRecord:
        """Read and check a ``<name>_camera.json``.

        Raises:
            FileNotFoundError: no such file.
            ValueError: one line naming the file and the bad field (or the JSON error).
        """
        path = Path(path)
        doc = read_json_object(path, what="camera file")
        missing = [k for k in ("intrinsics", "width", "height") if k not in doc]
        if missing:
            raise ValueError(f"{path}: {missing[0]}: missing")
        try:
            return cls._checked(doc["intrinsics"], doc["width"], doc["height"], doc.get("distance_m"))
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None

    @classmethod
    def _checked(cls, k: Any, width: Any, height: Any, distance: Any) -> CameraRecord:
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"{name}: must be a positive integer, got {v!r}")
        if distance is not None and (
            isinstance(distance, bool)
            or not isinstance(distance, int | float)
            or not (math.isfinite(distance) and distance > 0)
        ):
            raise ValueError(f"distance_m: must be null or a positive number of metres, got {distance!r}")
        numbers = isinstance(k, np.ndarray) or (
            isinstance(k, list | tuple) and all(isinstance(r, list | tuple) for r in k)
            and all(not isinstance(v, bool) and isinstance(v, int | float) for r in k for v in r)
        )  # fmt: skip
        shown = json.dumps(k.tolist() if isinstance(k, np.ndarray) else k, default=repr)[:120]
        if not numbers:
            raise ValueError(f"intrinsics: must be a 3x3 list of numbers, got {shown}")
        try:
            matrix = np.asarray(k, dtype=np.float64)
        except ValueError:  # rows of different lengths
            matrix = np.zeros(0)
        if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
            raise ValueError(f"intrinsics: must be a finite 3x3 matrix, got {shown}")
        if not (matrix[0, 0] > 0 and matrix[1, 1] > 0):
            raise ValueError(f"intrinsics: focal lengths must be positive, got fx {matrix[0, 0]}, fy {matrix[1, 1]}")
        return cls(matrix, int(width), int(height), None if distance is None else float(distance))

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: ``{"intrinsics": K as nested lists, "width", "height", "distance_m": d or null}``."""
        return {"intrinsics": self.intrinsics.tolist(), "width": self.width, "height": self.height,
                "distance_m": self.distance_m}  # fmt: skip


@dataclass(frozen=True)
class SequenceRecord:
    """A ``<name>_sequence.json``: the frames of a predicted sequence.

    Attributes:
        name: the sequence name.
        prefixes: each frame's file name prefix (``<name>_0001``, ...), in frame order.
        captures: each frame's capture folder (absolute), or None where the file does not say.
        seconds: each frame's decode + prediction time in s, or None where the file does not say.
    """

    name: str
    prefixes: tuple[str, ...]
    captures: tuple[str | None, ...] = ()
    seconds: tuple[float | None, ...] = ()

    @classmethod
    def of_frames(cls, name: str, frames: Sequence[str | os.PathLike], seconds: Sequence[float]) -> SequenceRecord:
        """The record of a sequence ``name`` predicted from capture folders ``frames`` in ``seconds`` each."""
        return cls(
            name, tuple(f"{name}_{i:04d}" for i in range(1, len(frames) + 1)),
            tuple(str(Path(f).resolve()) for f in frames), tuple(float(t) for t in seconds),
        )  # fmt: skip

    @classmethod
    def read(cls, path: str | os.PathLike) -> SequenceRecord:
        """Read and check a ``<name>_sequence.json`` (the name defaults to the file's).

        Raises:
            FileNotFoundError: no such file.
            ValueError: one line naming the file and the field (``frames[0].prefix: ...``).
        """
        path = Path(path)
        doc = read_json_object(path, what="sequence file")
        frames = doc.get("frames")
        if not isinstance(frames, list) or not frames:
            raise ValueError(f"{path}: frames: must be a non-empty list of {{'prefix': ...}} objects")
        prefixes = []
        for i, frame in enumerate(frames):
            prefix = frame.get("prefix") if isinstance(frame, dict) else None
            if not isinstance(prefix, str) or not prefix or Path(prefix).name != prefix:
                raise ValueError(f"{path}: frames[{i}].prefix: must be a file name prefix, got {prefix!r}")
            prefixes.append(prefix)
        name = doc.get("name")
        if not isinstance(name, str) or not name:
            name = path.name[: -len(SEQUENCE_SUFFIX)] if path.name.endswith(SEQUENCE_SUFFIX) else path.stem
        captures = tuple(f.get("capture") if isinstance(f.get("capture"), str) else None for f in frames)
        seconds = tuple(_seconds(f.get("seconds")) for f in frames)
        return cls(name, tuple(prefixes), captures, seconds)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object (frames numbered from 1; frames per second over the timed frames)."""
        timed = [t for t in self.seconds if t is not None]
        return {
            "name": self.name,
            "frames": [
                {"frame": i, "prefix": p, "capture": c, "seconds": None if t is None else round(t, 4)}
                for i, (p, c, t) in enumerate(zip(self.prefixes, self.captures, self.seconds, strict=True), start=1)
            ],
            "frames_per_second": round(len(timed) / sum(timed), 4) if timed and sum(timed) > 0 else None,
            "timed": "decode + prediction (+ depth integration) per frame, model loaded once",
        }


def _seconds(value: Any) -> float | None:
    ok = not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
    return float(value) if ok else None


def write_sequence(folder: str | os.PathLike, record: SequenceRecord) -> Path:
    """Write ``folder/<name>_sequence.json`` atomically; returns its path."""
    path = Path(folder) / f"{record.name}{SEQUENCE_SUFFIX}"
    atomic_write_text(path, json.dumps(record.to_dict(), indent=1) + "\n")
    return path


def _png(img: NDArray) -> bytes:
    """An 8-bit PNG of ``img (H, W, C)`` clipped to [0, 1] (C = 1 or 3)."""
    from PIL import Image

    a = np.clip(np.nan_to_num(img), 0, 1)
    a = (a[..., 0] if a.shape[-1] == 1 else a) * 255
    buf = io.BytesIO()
    Image.fromarray(np.rint(a).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _preview(key: str, img: NDArray, mask: NDArray | None) -> NDArray:
    """What the PNG of a map shows: normals from [-1, 1] to [0, 1], depth near = bright, zero outside the mask."""
    preview = img * 0.5 + 0.5 if key == "normal" else img
    if key == "depth":  # near = bright, far = dark, over the mask's range
        inside = img[..., 0][mask] if mask is not None and mask.any() else img[..., 0].ravel()
        lo, hi = float(inside.min()), float(inside.max())
        preview = (hi - img) / (hi - lo) if hi > lo else np.ones_like(img)
    return preview * mask[..., None] if mask is not None else preview


def write_predictions(
    out: str | os.PathLike,
    name: str,
    pred: Mapping[str, NDArray],
    camera: CameraRecord | None = None,
    *,
    pending: Future | None = None,
) -> list[Path]:
    """Write ``<name>_<map>.exr`` (float32) and a ``.png`` preview for every predicted map.

    File names follow the Blender import's token rules (``_normal``, ``_albedo``, ``_roughness``,
    ``_metallic``, ``_mask``, ``_depth``). Everything is checked and encoded first and written
    together (:func:`pbrdf.io.atomic.atomic_folder`, merged into ``out``): on any error nothing
    is written, and ``out`` is created only when the files are ready. Other files in ``out``
    stay (the frames of a sequence share one folder).

    Args:
        out: the output folder (created if missing).
        name: the file name prefix.
        pred: ``{map: (H, W, C) float32}``, all finite (``network.infer.predict``'s result, plus
            ``"depth"`` where a relief was integrated).
        camera: the maps' camera, written as ``<name>_camera.json`` (the Blender import gives its
            camera these intrinsics, so a relief mesh keeps the capture's shape).
        pending: more maps still being computed (a future of ``{map: (H, W, C)}``, e.g. the relief depth on
            another thread): ``pred``'s files are encoded while it runs, its own once it is done, and all are
            put into place together; its exception is raised with nothing written.

    Returns:
        The written paths (EXR then PNG per map).

    Raises:
        ValueError: a map that is not ``(H, W, C)`` or holds NaN/Inf (nothing written).
        Exception: whatever ``pending`` raised (nothing written).
        OSError: the folder cannot be written (nothing left behind).
    """
    out = Path(out)
    _check_maps(pred)
    mask = pred["mask"][..., 0] > 0 if "mask" in pred else None
    names = []
    with atomic_folder(out, merge=True) as staging:
        names += _encode(staging, name, pred, mask)
        if pending is not None:
            more = dict(pending.result())  # raised here: inside the staging folder, so nothing is written
            _check_maps(more)
            names += _encode(staging, name, more, mask)
        if camera is not None:
            (staging / f"{name}{CAMERA_SUFFIX}").write_text(json.dumps(camera.to_dict(), indent=1) + "\n")
    return [out / n for n in names]


def _check_maps(pred: Mapping[str, NDArray]) -> None:
    for key, img in pred.items():
        if img.ndim != 3 or not np.all(np.isfinite(img)):
            raise ValueError(f"predicted {key} map is not a finite (H, W, C) array; nothing written")


def _encode(staging: Path, name: str, pred: Mapping[str, NDArray], mask: NDArray | None) -> list[str]:
    """``<name>_<map>.exr`` and ``.png`` of every map into ``staging``; returns their names (EXR then PNG per map)."""
    from pbrdf.io.exr import write_exr  # noqa: PLC0415 (the add-on reads these names without OpenEXR)

    def exr(key: str) -> None:
        img = pred[key]
        chans = "XYZ" if key == "normal" else ("RGB" if img.shape[-1] == 3 else "Y")
        write_exr(staging / f"{name}_{key}.exr", {f"{key}.{c}": img[..., i] for i, c in enumerate(chans)})

    # Two threads: PNG (zlib) and EXR compression release the GIL (a full frame's files: 1.4 s of CPU).
    with ThreadPoolExecutor(2) as pool:
        previews = dict(zip(pred, pool.map(lambda k: _png(_preview(k, pred[k], mask)), pred), strict=True))
        list(pool.map(exr, pred))  # list: the first error is raised here, inside the staging folder
    names = []
    for key in pred:
        (staging / f"{name}_{key}.png").write_bytes(previews[key])
        names += [f"{name}_{key}.exr", f"{name}_{key}.png"]
    return names
