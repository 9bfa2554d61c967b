"""Packed training samples: a rendered split written once into shards of many samples, read through ``np.memmap``.

Decoding an EXR per item costs the loader far more than the model's step on a GPU; a pack stores
what :class:`network.data.SampleDataset` reads, already checked (:func:`network.data.check_item`)
and optionally already resized, so an item is a slice of a memory-mapped file. Layout of a pack
folder (``headless/pack.py``):

``index.json``
    :data:`PACK_FORMAT`, the source split's name and folder, the stored ``shape`` and ``dtype``,
    ``size`` (the size samples were resized to before packing; None: as rendered), the
    ``record`` layout (byte ``offset``, ``dtype`` and channel-first ``shape`` of each of
    :data:`ARRAYS` inside one sample's record, records back to back) and the completed
    ``shards``: file name, bytes, sha256, the source sample indices and one small ``meta`` per
    sample (the sidecar's :data:`META_KEYS`, the rendered grid ``hw``, the object ``distance`` for
    the light input and the source EXR, named in errors).
``shard-NNNNN.bin``
    The records of up to ``shard_samples`` samples: ``maps`` and the float targets in ``dtype``,
    ``mask`` as uint8.
``manifest.json``
    ``{"format", "split"}``, so that :func:`pbrdf.data.splits.require_role` treats the pack as its
    source split (training refuses a packed test split as it refuses the split).

Writing is resumable: each shard goes to a temporary sibling, is fsynced and renamed, and only then
listed in the index (rewritten atomically), with its sha256 computed while writing; a resumed pack
removes a killed writer's temporaries and packs the source samples that no listed shard holds.
:class:`PackedDataset` hashes every shard on open and refuses a corrupt one with one line naming it.

Precision: ``"float16"`` (the default) stores each value rounded to half precision (relative error
at most ``2**-11`` above ``6.1e-5``, absolute at most ``2**-25`` below; finite values beyond
+-65504 are stored as +-65504, which calibrated input clamps to :data:`network.data.MAP_LIMIT`
long before); the mask is exact; ``"float32"`` is exact. Normalisation (:func:`network.data.normalize_maps`)
and the light input run on load, in float32, as in :class:`~network.data.SampleDataset`.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.data.capture_meta import display_radiance
from pbrdf.data.splits import dataset_split
from pbrdf.io.atomic import atomic_open, atomic_write_text, remove_leftovers

from .data import INPUT_SCALES, TARGET_KEYS, SampleDataset, check_item, normalize_maps, resize_batch, sample_to_tensors
from .light_input import sample_distance, sidecar_light

__all__ = [
    "ARRAYS",
    "INDEX_FILE",
    "META_KEYS",
    "PACK_DTYPES",
    "PACK_FORMAT",
    "PackedDataset",
    "is_pack",
    "open_samples",
    "pack_split",
    "read_index",
    "verify_shards",
]

#: Format tag of ``index.json``.
PACK_FORMAT = "pdir-pack/1"
#: The pack's index file (its presence makes a folder a pack: :func:`is_pack`).
INDEX_FILE = "index.json"
#: Arrays of a record, in :class:`~network.data.SampleDataset`'s key order, and their channels.
ARRAYS = {"maps": 9, "mask": 1, "normal": 3, "albedo": 3, "roughness": 1, "metallic": 1}
#: Sidecar keys a loaded item needs (display radiance, light input).
META_KEYS = ("rig", "intrinsics", "radiometry")
#: Storage dtypes of the float arrays.
PACK_DTYPES = ("float16", "float32")
_ALIGN = 64  # bytes; every array of a record starts on a cache line
_HALF_MAX = float(np.finfo(np.float16).max)
_HASH_CHUNK = 8 << 20


def is_pack(root: str | os.PathLike) -> bool:
    """Whether ``root`` is a pack folder (holds :data:`INDEX_FILE`)."""
    return (Path(root) / INDEX_FILE).is_file()


def _shard_name(number: int) -> str:
    return f"shard-{number:05d}.bin"


def _layout(hw: tuple[int, int], dtype: str) -> dict[str, Any]:
    """The record layout for ``hw`` maps in ``dtype`` (mask uint8): per array offset, dtype, shape; total bytes."""
    arrays, offset = {}, 0
    for name, channels in ARRAYS.items():
        kind = "uint8" if name == "mask" else dtype
        arrays[name] = {"offset": offset, "dtype": kind, "shape": [channels, *hw]}
        nbytes = channels * hw[0] * hw[1] * np.dtype(kind).itemsize
        offset += -(-nbytes // _ALIGN) * _ALIGN
    return {"bytes": offset, "arrays": arrays}


def read_index(root: str | os.PathLike) -> dict[str, Any]:
    """The pack's ``index.json`` (ValueError naming the file unless it is a pack index of :data:`PACK_FORMAT`)."""
    path = Path(root) / INDEX_FILE
    try:
        index = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: pack index not found (write the pack with headless/pack.py)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: unreadable pack index ({exc})") from None
    if not isinstance(index, dict) or index.get("format") != PACK_FORMAT:
        got = index.get("format") if isinstance(index, dict) else type(index).__name__
        raise ValueError(f"{path}: not a pack index (format {got!r}, expected {PACK_FORMAT!r})")
    return index


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _shard_problem(root: Path, shard: dict) -> str | None:
    """Why a listed shard is unusable (missing, wrong size, wrong sha256), or None."""
    path = root / shard["file"]
    if not path.is_file():
        return f"{path}: shard listed in {INDEX_FILE} is missing"
    if path.stat().st_size != shard["bytes"]:
        return f"{path}: shard is corrupt ({path.stat().st_size} bytes, the index lists {shard['bytes']})"
    got = _sha256(path)
    if got != shard["sha256"]:
        return f"{path}: shard is corrupt (sha256 {got[:16]}..., the index lists {shard['sha256'][:16]}...)"
    return None


def _shard_problems(root: Path, shards: list[dict]) -> list[str | None]:
    with ThreadPoolExecutor(max_workers=max(1, min(8, os.cpu_count() or 1, len(shards)))) as pool:
        return list(pool.map(lambda s: _shard_problem(root, s), shards))  # hashlib releases the GIL


def verify_shards(root: str | os.PathLike, index: dict[str, Any] | None = None) -> None:
    """Hash every listed shard (in threads); ValueError naming the first missing or corrupt one.

    Args:
        root: the pack folder.
        index: its :func:`read_index` (read when None).
    """
    root = Path(root)
    index = read_index(root) if index is None else index
    for problem in _shard_problems(root, index["shards"]):
        if problem is not None:
            raise ValueError(problem)


# ------------------------------------------------------------------------------------------------
# Writing


def _read_source(source: Path, index: int, size: int | None) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """One source sample as :class:`~network.data.SampleDataset` sees it before normalisation, and its meta entry."""
    where = str(psample.sample_paths(source, index).exr)
    keys = ("maps", "mask", *TARGET_KEYS)
    try:
        sample, meta = psample.read_sample(source, index, keys=(*keys, "depth"))
    except psample.MissingChannelError:  # no depth: no light input from this sample
        sample, meta = psample.read_sample(source, index, keys=keys)
    check_item(sample, where)
    entry: dict[str, Any] = {k: meta[k] for k in META_KEYS if k in meta}
    entry.update(index=index, exr=where, hw=list(sample["mask"].shape[:2]), distance=None)
    if "depth" in sample:
        try:
            entry["distance"] = sample_distance(sample["depth"], sample["mask"], where)
        except ValueError as exc:
            entry["distance_error"] = str(exc)
    else:
        entry["distance_error"] = f"{where}: no depth channel (no object distance for the light input)"
    t = sample_to_tensors({k: sample[k] for k in keys})
    if size is not None and t["maps"].shape[-1] != size:
        t = resize_batch(t, size)
    return t, entry


def _record_bytes(t: dict[str, torch.Tensor], layout: dict[str, Any]) -> bytes:
    """One sample's record: each array cast to its dtype at its offset (finite floats clipped to the dtype's range)."""
    buf = bytearray(layout["bytes"])
    for name, spec in layout["arrays"].items():
        a = t[name].numpy()
        if name == "mask":
            a = (a > 0.5).astype(np.uint8)
        else:
            if spec["dtype"] == "float16":
                a = np.where(np.isfinite(a), np.clip(a, -_HALF_MAX, _HALF_MAX), a)
            a = a.astype(spec["dtype"])
        raw = np.ascontiguousarray(a).tobytes()
        buf[spec["offset"] : spec["offset"] + len(raw)] = raw
    return bytes(buf)


def _write_shard(source: Path, out: Path, number: int, indices: list[int], index: dict[str, Any]) -> dict[str, Any]:
    """Pack ``indices`` of ``source`` into shard ``number`` (temporary sibling, fsync, rename); its index entry."""
    name, h, metas, written = _shard_name(number), hashlib.sha256(), [], 0
    with atomic_open(out / name) as f:
        for i in indices:
            t, entry = _read_source(source, i, index["size"])
            hw = list(t["mask"].shape[-2:])
            if index["shape"] is None:
                index["shape"], index["record"] = hw, _layout(tuple(hw), index["dtype"])
            elif hw != index["shape"]:
                have = f"{index['shape'][0]} x {index['shape'][1]}"
                raise ValueError(f"{entry['exr']}: maps are {hw[0]} x {hw[1]}, the pack's are {have} "
                                 "(pack with size= to resize every sample)")  # fmt: skip
            record = _record_bytes(t, index["record"])
            f.write(record)
            h.update(record)
            written += len(record)
            metas.append(entry)
    return {"file": name, "bytes": written, "sha256": h.hexdigest(), "samples": list(indices), "meta": metas}


def _start_index(source: Path, out: Path, size: int | None, dtype: str, resume: bool) -> dict[str, Any]:
    """A fresh index, or (``resume``) the existing one after checking it matches and its shards are whole."""
    if not is_pack(out):
        return {"format": PACK_FORMAT, "split": dataset_split(source), "source": str(source), "size": size,
                "dtype": dtype, "shape": None, "record": None, "shards": []}  # fmt: skip
    if not resume:
        raise FileExistsError(f"{out}: already holds a pack; pass resume=True to continue it or choose another out")
    index = read_index(out)
    for key, value in (("size", size), ("dtype", dtype), ("split", dataset_split(source))):
        if index[key] != value:
            raise ValueError(f"{out / INDEX_FILE}: the pack was written with {key}={index[key]!r}, not {value!r}")
    keep = []
    for shard, problem in zip(index["shards"], _shard_problems(out, index["shards"]), strict=True):
        if problem is None:
            keep.append(shard)
        else:  # its samples are packed again below, into a new shard
            warnings.warn(f"{problem}; its samples are packed again", stacklevel=3)
            (out / shard["file"]).unlink(missing_ok=True)
    index["shards"] = keep
    return index


def pack_split(
    source: str | os.PathLike,
    out: str | os.PathLike,
    *,
    shard_samples: int = 64,
    size: int | None = None,
    dtype: str = "float16",
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, int]:
    """Write the completed samples of a rendered split into a pack (resumable).

    Args:
        source: dataset folder written by ``headless/render.py``.
        out: the pack folder (created).
        shard_samples: samples per shard (the last may hold fewer).
        size: resize every sample to ``size x size`` first (as ``SampleDataset(size=...)`` does); None keeps
            the rendered size, which must then be the same for every sample.
        dtype: :data:`PACK_DTYPES`, for the maps and the float targets.
        resume: continue a pack in ``out`` (its settings must match); otherwise ``out`` must hold none.
        progress: called as ``progress(done, total)`` after each shard (samples).

    Returns:
        ``{"shards", "samples"}`` (the whole pack) and ``{"shards_written", "samples_written"}`` (this call).

    Raises:
        ValueError: a bad setting or sample (named), or a pack written with other settings.
        FileExistsError: ``out`` holds a pack and ``resume`` is off.
    """
    source, out = Path(source), Path(out)
    if not isinstance(shard_samples, int) or isinstance(shard_samples, bool) or shard_samples < 1:
        raise ValueError(f"shard_samples must be a positive integer; got {shard_samples!r}")
    if size is not None and (not isinstance(size, int) or size < 1):
        raise ValueError(f"size must be a positive integer or None; got {size!r}")
    if dtype not in PACK_DTYPES:
        raise ValueError(f"dtype must be one of {PACK_DTYPES}; got {dtype!r}")
    if not source.is_dir():
        raise FileNotFoundError(f"{source}: dataset folder not found")
    done = sorted(pdataset.completed_indices(source))
    if not done:
        raise ValueError(f"{source}: no completed samples (render some with headless/render.py)")
    out.mkdir(parents=True, exist_ok=True)
    index = _start_index(source, out, size, dtype, resume)
    remove_leftovers(out, lambda name: name in (INDEX_FILE, "manifest.json") or name.startswith("shard-"))
    atomic_write_text(out / "manifest.json", json.dumps({"format": PACK_FORMAT, "split": index["split"]}) + "\n")
    packed = {i for shard in index["shards"] for i in shard["samples"]}
    todo = [i for i in done if i not in packed]
    number = max((int(s["file"][6:11]) for s in index["shards"]), default=-1) + 1
    written = 0
    for start in range(0, len(todo), shard_samples):
        chunk = todo[start : start + shard_samples]
        index["shards"].append(_write_shard(source, out, number, chunk, index))
        atomic_write_text(out / INDEX_FILE, json.dumps(index) + "\n")  # after the shard: only whole shards listed
        number, written = number + 1, written + len(chunk)
        if progress is not None:
            progress(len(packed) + written, len(packed) + len(todo))
    total = sum(len(s["samples"]) for s in index["shards"])
    return {"shards": len(index["shards"]), "samples": total,
            "shards_written": -(-len(todo) // shard_samples), "samples_written": written}  # fmt: skip


# ------------------------------------------------------------------------------------------------
# Reading


class PackedDataset(Dataset):
    """A pack's samples as normalised tensors: what :class:`~network.data.SampleDataset` yields for them.

    Keys, shapes and dtypes are :class:`~network.data.SampleDataset`'s; values equal to the pack's
    precision (module docs). Items were checked when packed; every shard is hashed on open. Shards
    are memory-mapped lazily, in each process that reads them (loader workers map their own).

    Args:
        root: pack folder written by :func:`pack_split`.
        size: as in :class:`~network.data.SampleDataset`; a pack packed at this size is not resized again.
        indices: the source sample indices to use, in this order (default: all, sorted).
        input_scale, light_input: as in :class:`~network.data.SampleDataset`.
        verify: hash every shard on open (:func:`verify_shards`).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        *,
        size: int | None = None,
        indices: list[int] | None = None,
        input_scale: str = "exposure-invariant",
        light_input: bool = False,
        verify: bool = True,
    ) -> None:
        if input_scale not in INPUT_SCALES:
            raise ValueError(f"unknown input scale {input_scale!r}; choose one of {INPUT_SCALES}")
        self.root, self.size, self.input_scale, self.light_input = Path(root), size, input_scale, light_input
        index = read_index(self.root)
        if not index["shards"]:
            raise ValueError(f"{self.root / INDEX_FILE}: the pack holds no shard yet")
        if verify:
            verify_shards(self.root, index)
        self.record = index["record"]
        self.files = [shard["file"] for shard in index["shards"]]
        self.where: dict[int, tuple[int, int]] = {}
        self.meta: list[list[dict]] = []
        for s, shard in enumerate(index["shards"]):
            self.meta.append(shard["meta"])
            self.where.update({i: (s, j) for j, i in enumerate(shard["samples"])})
        done = sorted(self.where)
        self.indices = done if indices is None else [i for i in indices if i in self.where]
        self._maps: dict[int, np.ndarray] = {}
        self._radiance: dict[int, float] = {}

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_maps"] = {}  # a worker maps the shards itself (a pickled memmap would copy its data)
        return state

    def __len__(self) -> int:
        return len(self.indices)

    def _arrays(self, s: int, j: int) -> dict[str, np.ndarray]:
        mm = self._maps.get(s)
        if mm is None:
            # copy-on-write: writable views for torch.from_numpy; nothing writes them, so nothing is copied
            mm = self._maps[s] = np.memmap(self.root / self.files[s], dtype=np.uint8, mode="c")
        base = j * self.record["bytes"]
        out = {}
        for name, spec in self.record["arrays"].items():
            count = int(np.prod(spec["shape"]))
            a = np.frombuffer(mm, dtype=spec["dtype"], count=count, offset=base + spec["offset"])
            out[name] = a.reshape(spec["shape"])
        return out

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        s, j = self.where[self.indices[i]]
        meta = self.meta[s][j]
        where = f"{self.root / self.files[s]} (sample {meta['index']}, from {meta['exr']})"
        t = {name: torch.from_numpy(a).to(torch.float32, copy=True) for name, a in self._arrays(s, j).items()}
        if self.size is not None and t["maps"].shape[-1] != self.size:
            t = resize_batch(t, self.size)
        radiance = None
        if self.input_scale == "calibrated":  # parsing the rig costs as much as the rest of the item: once per sample
            if meta["index"] not in self._radiance:
                self._radiance[meta["index"]] = display_radiance(meta, where)
            radiance = self._radiance[meta["index"]]
        t["maps"] = normalize_maps(t["maps"], t["mask"], radiance=radiance)
        if self.light_input:
            if meta["distance"] is None:
                raise ValueError(meta["distance_error"])
            shape = tuple(t["mask"].shape[-2:])
            t["light"] = sidecar_light(meta, tuple(meta["hw"]), shape, meta["distance"], where)
            t["distance"] = torch.tensor(meta["distance"], dtype=torch.float32)
        return t


def open_samples(root: str | os.PathLike, **kwargs: Any) -> SampleDataset | PackedDataset:
    """:class:`PackedDataset` for a pack folder (:func:`is_pack`), else :class:`~network.data.SampleDataset`.

    Args:
        root: a pack or a rendered dataset folder.
        **kwargs: the datasets' common arguments (``size``, ``indices``, ``input_scale``, ``light_input``).
    """
    return PackedDataset(root, **kwargs) if is_pack(root) else SampleDataset(root, **kwargs)
