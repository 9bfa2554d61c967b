"""One dataset sample on disk: its arrays, EXR channels and JSON sidecar; validation, writing, reading.

The format shared by the renderer (writer) and the network (reader). Samples live in the
``samples`` folder of a dataset (:mod:`pbrdf.data.dataset`)::

    root/
      manifest.json            dataset-level info and the sorted list of completed samples
      samples/
        000000.exr             maps, mask and ground truth of sample 0 (channels below)
        000000.json            its sidecar: caller's metadata + format, index, channels, sha256
        000000_raw/            optional: the raw HDR bracket as a capture folder (pbrdf.data.capture)
        ...

A sample is a dict of arrays on the decoder's output grid ``(H, W)``:

=============  ===================  ==========================================================
key            shape, dtype         meaning (EXR channels)
=============  ===================  ==========================================================
``maps``       (H, W, 9) float32    nine maps in ``NINE_MAP_NAMES`` order (``maps.R_unpol``, ...)
``mask``       (H, W) bool          object pixels the decoder measured: the training mask
                                    (``mask.Y``, stored as uint32 0/1)
``normal``     (H, W, 3) float32    camera-frame unit normals, OpenGL axes, 0 outside the
                                    ground-truth region (``normal.X/Y/Z``)
``albedo``     (H, W, 3) float32    linear RGB in [0, 1] (``albedo.R/G/B``)
``roughness``  (H, W) float32       in [0, 1] (``roughness.Y``)
``metallic``   (H, W) float32       in [0, 1] (``metallic.Y``)
``depth``      (H, W) float32       camera-frame z distance in metres, > 0 inside the
                                    ground-truth region and 0 outside (``depth.Z``)
``stokes``     (H, W, 3, 4) float32 optional: per colour R, G, B the Stokes vector
                                    (``stokes.R.S0`` ... ``stokes.B.S3``)
``raw``        (E, 2H, 2W) uint16   optional: raw HDR bracket, saved with
                                    :func:`pbrdf.data.capture.save_capture` in ``<index>_raw/``;
                                    the camera model comes from ``metadata["camera_model"]``
``object``     (H, W) float32       optional: index of the object covering the pixel, -1 on the
                                    background (``object.Y``)
=============  ===================  ==========================================================

The ground-truth region (where ``normal``, ``albedo``, ``roughness``, ``metallic`` and ``depth``
are defined) is the object coverage ``object >= 0`` when ``object`` is stored, else ``mask``; the
mask lies inside it. Evaluation scores on the object coverage (dark pixels the decoder could not
measure, e.g. on mirror-like metals, count); training uses the mask.

Writes are atomic and ordered so that a killed run never leaves a sample that looks complete:
:func:`write_sample` first removes an old sidecar, then writes the EXR (temporary file + rename)
and the raw folder (temporary folder + rename), and writes the sidecar last (temporary file +
rename). A sample is complete only if its sidecar is valid and its ``sha256`` matches the EXR
(:func:`check_complete`). :func:`write_sample` overwrites the leftovers of a broken sample;
:func:`pbrdf.data.dataset.cleanup_partial` removes them.

Float channels are stored as float32, so every array reads back bit for bit.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from pbrdf.data._common import check_index, check_metadata, dumps_json, remove_path
from pbrdf.data.capture import CAPTURE_JSON, Capture, load_capture, save_capture, validate_capture
from pbrdf.data.capture_meta import parse_intrinsics
from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.exr import MissingChannelError, read_exr, stack_channels, write_exr
from pbrdf.io.strict_json import read_json_object
from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.decode import NINE_MAP_NAMES
from pbrdf.sensor.projection import crop_intrinsics, pinhole_intrinsics
from pbrdf.sensor.rig import Rig

__all__ = [
    "SAMPLE_FORMAT",
    "SAMPLES_DIR",
    "RAW_SUFFIX",
    "COLOURS",
    "STOKES_COMPONENTS",
    "LAYOUT",
    "CHANNELS",
    "REQUIRED_KEYS",
    "OPTIONAL_KEYS",
    "SAMPLE_KEYS",
    "TRAILING_SHAPES",
    "SIDECAR_KEYS",
    "NORMAL_TOLERANCE",
    "SamplePaths",
    "sample_paths",
    "parse_sample_name",
    "validate_sample",
    "write_sample",
    "read_sample",
    "check_complete",
    "sample_intrinsics",
]

#: ``"format"`` of a sample sidecar; bumped on incompatible changes.
SAMPLE_FORMAT = "pdir-sample/1"
#: Sub-folder of the dataset root holding the samples.
SAMPLES_DIR = "samples"
#: Suffix of a sample's raw capture folder: ``000012_raw``.
RAW_SUFFIX = "_raw"

#: Colour channel names (Stokes and albedo).
COLOURS = ("R", "G", "B")
#: Stokes channel names below the ``stokes`` prefix, in ``(colour, component)`` C order.
STOKES_COMPONENTS = tuple(f"{c}.S{k}" for c in COLOURS for k in range(4))
#: Sample key -> (EXR channel prefix, component names). The EXR channel of component ``n`` of
#: key ``k`` is ``f"{LAYOUT[k][0]}.{n}"``.
LAYOUT: dict[str, tuple[str, tuple[str, ...]]] = {
    "maps": ("maps", tuple(NINE_MAP_NAMES)),
    "mask": ("mask", ("Y",)),
    "normal": ("normal", ("X", "Y", "Z")),
    "albedo": ("albedo", COLOURS),
    "roughness": ("roughness", ("Y",)),
    "metallic": ("metallic", ("Y",)),
    "depth": ("depth", ("Z",)),
    "stokes": ("stokes", STOKES_COMPONENTS),
    "object": ("object", ("Y",)),
}
#: Sample key -> its EXR channel names, in array order.
CHANNELS: dict[str, tuple[str, ...]] = {
    key: tuple(f"{prefix}.{n}" for n in names) for key, (prefix, names) in LAYOUT.items()
}
#: Keys every sample has.
REQUIRED_KEYS = ("maps", "mask", "normal", "albedo", "roughness", "metallic", "depth")
#: Keys a sample may have.
OPTIONAL_KEYS = ("stokes", "object", "raw")
#: All sample keys.
SAMPLE_KEYS = REQUIRED_KEYS + OPTIONAL_KEYS
#: Shape of each EXR-stored key after the leading ``(H, W)``.
TRAILING_SHAPES: dict[str, tuple[int, ...]] = {
    "maps": (9,),
    "mask": (),
    "normal": (3,),
    "albedo": (3,),
    "roughness": (),
    "metallic": (),
    "depth": (),
    "stokes": (3, 4),
    "object": (),
}
#: Sidecar keys written by :func:`write_sample`; the caller's metadata may not use them.
SIDECAR_KEYS = ("format", "index", "exr", "sha256", "exr_bytes", "channels", "shape", "raw_capture")
#: Allowed deviation of ``|normal|`` from 1 inside the mask.
NORMAL_TOLERANCE = 1e-3

_UNIT_KEYS = ("albedo", "roughness", "metallic")
_ENTRY_RE = re.compile(r"^(\d{6,})(\.exr|\.json|" + re.escape(RAW_SUFFIX) + r")$")


class SamplePaths(NamedTuple):
    """Files of one sample: the EXR, its JSON sidecar and the (optional) raw capture folder."""

    exr: Path
    sidecar: Path
    raw: Path


def sample_paths(root: str | os.PathLike, index: int) -> SamplePaths:
    """Paths of sample ``index`` inside dataset ``root``.

    Example:
        >>> sample_paths("data", 12).exr.as_posix()
        'data/samples/000012.exr'
    """
    index = check_index(index)
    folder = Path(root) / SAMPLES_DIR
    stem = f"{index:06d}"
    return SamplePaths(folder / f"{stem}.exr", folder / f"{stem}.json", folder / f"{stem}{RAW_SUFFIX}")


def parse_sample_name(name: str) -> tuple[int, str] | None:
    """Index and kind of a sample's file or folder name, or None for any other name.

    Args:
        name: a file or folder name inside ``samples/`` (not a path).

    Returns:
        ``(index, kind)`` with kind ``".exr"``, ``".json"`` or :data:`RAW_SUFFIX`.

    Example:
        >>> parse_sample_name("000012_raw"), parse_sample_name("notes.txt")
        ((12, '_raw'), None)
    """
    m = _ENTRY_RE.match(name)
    return (int(m.group(1)), m.group(2)) if m else None


# --------------------------------------------------------------------------------------------
# validation


def _where(key: str) -> str:
    return f"sample[{key!r}]"


def _first_pixel(bad: NDArray[np.bool_]) -> str:
    r, c = (int(v) for v in np.argwhere(bad)[0][:2])
    return f"(row {r}, col {c})"


def _check_array(sample: Mapping[str, Any], key: str, hw: tuple[int, int] | None) -> NDArray:
    arr = sample[key]
    if not isinstance(arr, np.ndarray):
        raise ValueError(f"{_where(key)} must be a numpy array; got {type(arr).__name__}")
    want = np.bool_ if key == "mask" else np.float32
    if arr.dtype != want:
        raise ValueError(f"{_where(key)} must have dtype {np.dtype(want).name}; got {arr.dtype}")
    tail = TRAILING_SHAPES[key]
    spec = ", ".join(["H", "W", *(str(t) for t in tail)])
    if arr.ndim != 2 + len(tail) or tuple(arr.shape[2:]) != tail:
        raise ValueError(f"{_where(key)} must have shape ({spec}); got {arr.shape}")
    if hw is not None and tuple(arr.shape[:2]) != hw:
        raise ValueError(f"{_where(key)} has shape {arr.shape}; (H, W) must be {hw} like sample['maps']")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = ~np.isfinite(arr)
        what = "NaN" if np.isnan(arr).any() else "Inf"
        raise ValueError(f"{_where(key)} contains {what} ({int(bad.sum())} values, first at {_first_pixel(bad)})")
    return arr


def _check_raw(raw: Any, hw: tuple[int, int], metadata: Mapping[str, Any] | None) -> CameraModel:
    if not isinstance(raw, np.ndarray):
        raise ValueError(f"{_where('raw')} must be a numpy array; got {type(raw).__name__}")
    if raw.dtype != np.uint16:
        raise ValueError(f"{_where('raw')} must have dtype uint16; got {raw.dtype}")
    want = (2 * hw[0], 2 * hw[1])
    if raw.ndim != 3 or tuple(raw.shape[1:]) != want or raw.shape[0] < 1:
        raise ValueError(f"{_where('raw')} must have shape (E, 2H, 2W) = (E, {want[0]}, {want[1]}); got {raw.shape}")
    if metadata is None or "camera_model" not in metadata:
        raise ValueError("sample['raw'] needs metadata['camera_model'] (CameraModel.to_dict() of the rig)")
    cam = metadata["camera_model"]
    try:
        model = cam if isinstance(cam, CameraModel) else CameraModel.from_dict(cam)
    except (TypeError, ValueError) as e:
        raise ValueError(f"metadata['camera_model'] is not a valid camera model ({e})") from e
    t = model.exposures
    if len(t) != raw.shape[0]:
        raise ValueError(f"{_where('raw')} has {raw.shape[0]} frames for {len(t)} exposures {t} of the camera model")
    if any(b <= a for a, b in zip(t[:-1], t[1:], strict=True)):
        raise ValueError(f"metadata['camera_model'] exposures must be strictly increasing (raw frame order); got {t}")
    validate_capture(Capture(raws=raw, model=model))
    return model


def validate_sample(sample: Mapping[str, Any], metadata: Mapping[str, Any] | None = None) -> tuple[int, int]:
    """Check a sample against the format (see the module docs); raise ValueError naming the key.

    Checks: the required keys are there and no unknown ones; numpy arrays with the documented
    dtype and shape on one ``(H, W)`` grid; no NaN/Inf; albedo, roughness and metallic in
    [0, 1]; normals of unit length (to :data:`NORMAL_TOLERANCE`) inside the mask and 0 outside;
    depth > 0 inside the mask and 0 outside; ``raw`` ``(E, 2H, 2W)`` uint16 consistent with
    ``metadata["camera_model"]`` (exposures strictly increasing, one frame each).

    Args:
        sample: the sample dict.
        metadata: the sample's metadata (needed only with ``raw``).

    Returns:
        ``(H, W)``.

    Raises:
        ValueError: the first problem found, naming the key.
    """
    if not isinstance(sample, Mapping):
        raise ValueError(f"sample must be a dict of arrays; got {type(sample).__name__}")
    unknown = sorted(set(sample) - set(SAMPLE_KEYS))
    if unknown:
        raise ValueError(f"sample has unknown key(s) {unknown}; valid keys: {list(SAMPLE_KEYS)}")
    missing = [k for k in REQUIRED_KEYS if k not in sample]
    if missing:
        raise ValueError(f"sample is missing required key(s) {missing}")
    maps = _check_array(sample, "maps", None)
    hw = (int(maps.shape[0]), int(maps.shape[1]))
    if hw[0] < 1 or hw[1] < 1:
        raise ValueError(f"{_where('maps')} is empty: shape {maps.shape}")
    arrays = {"maps": maps}
    for key in SAMPLE_KEYS[1:]:
        if key in sample and key != "raw":
            arrays[key] = _check_array(sample, key, hw)
    for key in _UNIT_KEYS:
        a = arrays[key]
        lo, hi = float(a.min()), float(a.max())
        if lo < 0 or hi > 1:
            raise ValueError(f"{_where(key)} values must be in [0, 1]; got [{lo:g}, {hi:g}]")
    mask = arrays["mask"]
    region, inside, outside_of = mask, "inside the mask", "the mask"
    if "object" in arrays:
        obj = arrays["object"]
        if not np.all((obj == np.round(obj)) & (obj >= -1)):
            bad = ~((obj == np.round(obj)) & (obj >= -1))
            raise ValueError(f"{_where('object')} must hold object indices >= 0 or -1; not at {_first_pixel(bad)}")
        region, inside, outside_of = obj >= 0, "on the objects (object >= 0)", "the objects"
        stray = mask & ~region
        if stray.any():
            raise ValueError(f"{_where('mask')} must lie on the objects (object >= 0); not at {_first_pixel(stray)}")
    normal = arrays["normal"]
    length = np.sqrt(np.sum(normal.astype(np.float64) ** 2, axis=-1))
    off = region & (np.abs(length - 1) > NORMAL_TOLERANCE)
    if off.any():
        worst = float(length[off][np.argmax(np.abs(length[off] - 1))])
        raise ValueError(
            f"{_where('normal')} must be unit vectors {inside} (|n| = 1 +- {NORMAL_TOLERANCE:g}); "
            f"{int(off.sum())} are not, e.g. |n| = {worst:.6g} at {_first_pixel(off)}"
        )
    outside = ~region & np.any(normal != 0, axis=-1)
    if outside.any():
        raise ValueError(f"{_where('normal')} must be 0 outside {outside_of}; nonzero at {_first_pixel(outside)}")
    depth = arrays["depth"]
    bad = region & ~(depth > 0)
    if bad.any():
        raise ValueError(f"{_where('depth')} must be > 0 {inside}; not at {_first_pixel(bad)}")
    bad = ~region & (depth != 0)
    if bad.any():
        raise ValueError(f"{_where('depth')} must be 0 outside {outside_of}; nonzero at {_first_pixel(bad)}")
    if "raw" in sample:
        _check_raw(sample["raw"], hw, metadata)
    return hw


# --------------------------------------------------------------------------------------------
# files


def _sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def write_sample(
    root: str | os.PathLike,
    index: int,
    sample: Mapping[str, NDArray],
    metadata: Mapping[str, Any],
    *,
    raw_format: str = "png",
) -> Path:
    """Validate and write one sample: EXR, optional raw capture folder, then the sidecar.

    An existing sample with the same index (complete or not) is replaced: its sidecar is
    removed first, so the sample never looks complete with mixed files.

    Args:
        root: dataset folder (created if needed).
        index: sample index >= 0; files are ``samples/<index:06d>.*``.
        sample: the sample dict (see the module docs and :func:`validate_sample`).
        metadata: JSON-serialisable dict (numpy scalars and arrays are converted): rig, poses,
            material ids, Disney parameters, seeds, software versions, ... With ``raw`` it
            must hold ``"camera_model"`` (:meth:`pbrdf.sensor.camera.CameraModel.to_dict`, or the
            model itself). It may not use the keys :data:`SIDECAR_KEYS`.
        raw_format: file format of the raw frames: ``"png"``, ``"tiff"`` or ``"npy"``.

    Returns:
        Path of the sidecar JSON (written last).

    Raises:
        ValueError: invalid sample or metadata (the message names the key).
        OSError: the files cannot be written.
    """
    index = check_index(index)
    meta = check_metadata(metadata, SIDECAR_KEYS, "metadata")
    hw = validate_sample(sample, meta)
    if isinstance(meta.get("camera_model"), CameraModel):
        meta["camera_model"] = meta["camera_model"].to_dict()
    dumps_json(meta, "metadata")  # fail before touching the disk
    paths = sample_paths(root, index)
    paths.exr.parent.mkdir(parents=True, exist_ok=True)

    channels: dict[str, NDArray] = {}
    written = [k for k in SAMPLE_KEYS if k in sample and k != "raw"]
    for key in written:
        arr = sample[key].reshape(hw[0], hw[1], -1)
        for k, name in enumerate(CHANNELS[key]):
            channels[name] = arr[..., k]

    paths.sidecar.unlink(missing_ok=True)  # from here on the sample is incomplete
    write_exr(paths.exr, channels, header={"pdir.format": SAMPLE_FORMAT, "pdir.index": str(index)})
    if "raw" in sample:
        model = CameraModel.from_dict(meta["camera_model"])
        # Rendered raws are radiometrically calibrated by construction; the rig says the display radiance.
        extra = {"sample_index": index, "radiometry": "calibrated"}
        if "rig" in meta:
            extra["rig"] = json.loads(dumps_json({"rig": meta["rig"]}, f"{paths.sidecar}: rig"))["rig"]
        if "intrinsics" in meta:  # calibration a real capture carries: of the raw grid, twice the maps'
            k = sample_intrinsics(meta, hw, "metadata")
            extra["intrinsics"] = crop_intrinsics(k, (0, 0, *hw), sample["raw"].shape[-2:]).tolist()
        save_capture(paths.raw, sample["raw"], model, file_format=raw_format, extra=extra, overwrite=True)
    elif paths.raw.exists():
        remove_path(paths.raw)
    sidecar = {
        "format": SAMPLE_FORMAT,
        "index": index,
        "exr": paths.exr.name,
        "sha256": _sha256(paths.exr),
        "exr_bytes": paths.exr.stat().st_size,
        "channels": list(channels),
        "shape": list(hw),
        **({"raw_capture": paths.raw.name} if "raw" in sample else {}),
        **meta,
    }
    atomic_write_text(paths.sidecar, dumps_json(sidecar, f"{paths.sidecar}: sidecar"))
    return paths.sidecar


def _load_sidecar(path: Path, index: int | None = None) -> dict[str, Any]:
    """Read and check a sidecar's own fields (not the EXR); ValueError / FileNotFoundError."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: sample sidecar not found (sample missing or incomplete)")
    data = read_json_object(path, SAMPLE_FORMAT)
    for key, typ in (("index", int), ("exr", str), ("sha256", str), ("exr_bytes", int), ("channels", list)):
        if not isinstance(data.get(key), typ) or isinstance(data.get(key), bool):
            raise ValueError(f"{path}: key {key!r} missing or not a {typ.__name__}")
    if index is not None and data["index"] != index:
        raise ValueError(f"{path}: sidecar says index {data['index']}, file name says {index}")
    if data["exr"] != path.with_suffix(".exr").name:
        raise ValueError(f"{path}: sidecar names EXR {data['exr']!r}; expected {path.with_suffix('.exr').name!r}")
    raw = data.get("raw_capture")
    if raw is not None and raw != path.stem + RAW_SUFFIX:
        raise ValueError(f"{path}: raw_capture {raw!r}; expected {path.stem + RAW_SUFFIX!r}")
    return data


def _check_complete(paths: SamplePaths, index: int, verify_hash: bool) -> dict[str, Any]:
    """Sidecar of a complete sample; raises ValueError / OSError describing what is wrong."""
    data = _load_sidecar(paths.sidecar, index)
    if not paths.exr.is_file():
        raise FileNotFoundError(f"{paths.exr}: EXR of sidecar {paths.sidecar.name} is missing")
    size = paths.exr.stat().st_size
    if size != data["exr_bytes"]:
        raise ValueError(f"{paths.exr}: {size} bytes; sidecar says {data['exr_bytes']}")
    if verify_hash and _sha256(paths.exr) != data["sha256"]:
        raise ValueError(f"{paths.exr}: sha256 does not match its sidecar")
    if data.get("raw_capture") is not None and not (paths.raw / CAPTURE_JSON).is_file():
        raise FileNotFoundError(f"{paths.raw}: raw capture of sidecar {paths.sidecar.name} is missing")
    return data


def _sample_for(path: Path, index: int | None) -> tuple[SamplePaths, int | None]:
    if index is not None:
        return sample_paths(path, index), check_index(index)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; pass the sample index or the path of a sample EXR/JSON")
    if path.suffix not in (".exr", ".json"):
        raise ValueError(f"{path}: expected a sample .exr or .json path")
    parsed = parse_sample_name(path.with_suffix(".exr").name)
    idx = parsed[0] if parsed else None
    return SamplePaths(path.with_suffix(".exr"), path.with_suffix(".json"), path.with_name(path.stem + RAW_SUFFIX)), idx


def read_sample(
    root_or_path: str | os.PathLike,
    index: int | None = None,
    *,
    keys: Iterable[str] | None = None,
    verify: bool = False,
) -> tuple[dict[str, NDArray], dict[str, Any]]:
    """Read a sample written by :func:`write_sample` (inverse; arrays equal bit for bit).

    Args:
        root_or_path: the dataset root (with ``index``) or the path of a sample's EXR or JSON.
        index: sample index inside ``root``.
        keys: sample keys to return (default: all the sample has). Only their channels are
            returned (OpenEXR 3.5 decodes the whole file regardless); ``raw`` is read only
            when asked for or by default.
        verify: check the EXR's sha256 against the sidecar first.

    Returns:
        ``(sample, metadata)``: the arrays as documented in the module docs, and the whole
        sidecar (the caller's metadata plus :data:`SIDECAR_KEYS`).

    Raises:
        FileNotFoundError: the sidecar or EXR is missing (incomplete sample).
        ValueError: bad sidecar or EXR, unknown key, hash mismatch (``verify``).
        MissingChannelError: a requested optional key is not in this sample.
    """
    paths, idx = _sample_for(Path(root_or_path), index)
    meta = _check_complete(paths, idx, verify) if verify else _load_sidecar(paths.sidecar, idx)
    present = [k for k in SAMPLE_KEYS if k != "raw" and all(c in meta["channels"] for c in CHANNELS[k])]
    if meta.get("raw_capture") is not None:
        present.append("raw")
    if keys is None:
        wanted = present
    else:
        wanted = [keys] if isinstance(keys, str) else list(keys)
        unknown = [k for k in wanted if k not in SAMPLE_KEYS]
        if unknown:
            raise ValueError(f"unknown sample key(s) {unknown}; valid: {list(SAMPLE_KEYS)}")
        absent = [k for k in wanted if k not in present]
        if absent:
            raise MissingChannelError(f"{paths.sidecar}: sample has no {absent}; it has {present}")
    names = [c for k in wanted if k != "raw" for c in CHANNELS[k]]
    channels = read_exr(paths.exr, names) if names else {}
    sample: dict[str, NDArray] = {}
    for key in wanted:
        if key == "raw":
            sample["raw"] = load_capture(paths.raw).raws
            continue
        prefix, comps = LAYOUT[key]
        if key == "mask":
            m = channels[CHANNELS["mask"][0]]
            if not np.isin(m, (0, 1)).all():
                raise ValueError(f"{paths.exr}: channel {CHANNELS['mask'][0]!r} holds values other than 0 and 1")
            sample[key] = m.astype(bool)
            continue
        arr = stack_channels(channels, prefix, comps).astype(np.float32, copy=False)
        tail = TRAILING_SHAPES[key]
        sample[key] = arr.reshape(*arr.shape[:2], *tail)
    return sample, meta


def check_complete(root: str | os.PathLike, index: int, *, verify_hash: bool = True) -> dict[str, Any]:
    """The sidecar of sample ``index`` if the sample is complete; raise saying what is missing otherwise.

    Complete means: the sidecar is valid, the EXR exists with the recorded size (and sha256 with
    ``verify_hash``), and the raw capture folder exists if the sidecar names one.

    Args:
        root: dataset folder.
        index: sample index >= 0.
        verify_hash: hash the EXR (slower); otherwise only its size is compared.

    Returns:
        The sidecar dict.

    Raises:
        FileNotFoundError: the sidecar, EXR or raw folder is missing.
        ValueError: a bad sidecar, or an EXR of the wrong size or hash.
    """
    index = check_index(index)
    return _check_complete(sample_paths(root, index), index, verify_hash)


def sample_intrinsics(meta: Mapping[str, Any], shape: tuple[int, int], where: str | os.PathLike) -> NDArray[np.float64]:
    """``K (3, 3)`` of a sample's map grid: its sidecar's ``intrinsics``, else the default camera's.

    The sidecar's ``intrinsics`` are those of the rendered crop, which is the maps' grid. Without
    them the default rig camera's field of view spans the map's width, principal point at the centre.

    Args:
        meta: the sidecar (or the metadata passed to :func:`write_sample`).
        shape: ``(H, W)`` of the maps.
        where: the file, first in error messages.

    Raises:
        ValueError: ``intrinsics`` that are not a finite 3x3 matrix.

    Example:
        >>> sample_intrinsics({"intrinsics": np.eye(3).tolist()}, (8, 8), "s.json")[2]
        array([0., 0., 1.])
    """
    if "intrinsics" in meta:
        return parse_intrinsics(meta["intrinsics"], where)
    cam = Rig().camera
    return pinhole_intrinsics(cam.focal_length_px * shape[1] / cam.sensor_width_px, shape[1], shape[0])
