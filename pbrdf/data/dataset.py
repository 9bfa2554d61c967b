"""A dataset folder: its samples' bookkeeping, manifest, shards and resumable work plans.

A dataset is a folder::

    root/
      manifest.json            dataset-level info and the sorted list of completed samples
      samples/
        000000.exr             maps, mask and ground truth of sample 0
        000000.json            its sidecar: caller's metadata + format, index, channels, sha256
        000000_raw/            optional: the raw HDR bracket as a capture folder (pbrdf.data.capture)
        ...

One sample's format, validation, writing and reading live in :mod:`pbrdf.data.sample`.

Writers of one dataset may run as shards ``(K, N)`` (sample ``i`` belongs to shard ``i % N``)
sharing the folder. A killed run resumes exactly: :func:`plan_work` with ``resume=True`` lists the
samples of the shard that are not complete (:func:`pbrdf.data.sample.check_complete`);
:func:`pbrdf.data.sample.write_sample` overwrites the leftovers of a broken sample, and :func:`cleanup_partial`
removes them; :func:`remove_manifest_leftovers` removes the temporary manifests of killed writers.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from pbrdf.data._common import check_index, check_metadata, dumps_json, remove_path
from pbrdf.data.sample import SAMPLES_DIR, check_complete, parse_sample_name, sample_paths
from pbrdf.io.atomic import atomic_write_text, remove_leftovers, temporary_target
from pbrdf.io.strict_json import read_json_object

__all__ = [
    "MANIFEST_FORMAT",
    "MANIFEST_JSON",
    "completed_indices",
    "cleanup_partial",
    "remove_manifest_leftovers",
    "write_manifest",
    "read_manifest",
    "shard_indices",
    "parse_shard",
    "plan_work",
]

logger = logging.getLogger(__name__)

#: ``"format"`` of ``manifest.json``.
MANIFEST_FORMAT = "pdir-dataset/1"
#: Name of the manifest inside the dataset root.
MANIFEST_JSON = "manifest.json"


# --------------------------------------------------------------------------------------------
# dataset bookkeeping


def _entries(root: Path) -> dict[int, list[Path]]:
    """Sample index -> files/folders of that sample in ``root/samples`` (temporaries included)."""
    folder = root / SAMPLES_DIR
    found: dict[int, list[Path]] = {}
    if not folder.is_dir():
        return found
    for entry in folder.iterdir():
        parsed = parse_sample_name(temporary_target(entry.name) or entry.name)
        if parsed:
            found.setdefault(parsed[0], []).append(entry)
    return found


def _in_shard(index: int, shard: tuple[int, int] | None) -> bool:
    return shard is None or index % shard[1] == shard[0]


def completed_indices(
    root: str | os.PathLike, *, shard: tuple[int, int] | None = None, verify_hash: bool = True
) -> set[int]:
    """Indices of the complete samples of a dataset.

    A sample is complete if its sidecar is valid, its EXR exists with the recorded size and
    sha256, and its raw capture folder (if it has one) exists. Broken sidecars are logged as
    warnings and treated as missing.

    Args:
        root: dataset folder (a missing folder has no samples).
        shard: only look at indices of shard ``(K, N)`` (``i % N == K``).
        verify_hash: hash every EXR (slower); otherwise only sizes are compared.

    Returns:
        The set of complete indices.
    """
    folder = Path(root) / SAMPLES_DIR
    done: set[int] = set()
    if not folder.is_dir():
        return done
    if shard is not None:
        shard = _check_shard(shard)
    for entry in sorted(folder.iterdir()):
        parsed = parse_sample_name(entry.name)
        if parsed is None or parsed[1] != ".json" or not _in_shard(parsed[0], shard):
            continue
        if _is_complete(root, parsed[0], verify_hash):
            done.add(parsed[0])
    return done


def _is_complete(root: str | os.PathLike, index: int, verify_hash: bool) -> bool:
    """Whether sample ``index`` is complete; a broken sidecar is logged as a warning."""
    if not sample_paths(root, index).sidecar.exists():
        return False
    try:
        check_complete(root, index, verify_hash=verify_hash)
    except (OSError, ValueError) as e:
        logger.warning("sample %d is incomplete, treated as missing: %s", index, e)
        return False
    return True


def cleanup_partial(
    root: str | os.PathLike, *, shard: tuple[int, int] | None = None, verify_hash: bool = True
) -> list[Path]:
    """Remove the leftovers of incomplete samples.

    That is temporary files and folders, EXRs and raw folders without a valid sidecar, and
    sidecars that do not match their EXR. Do not run it while a writer of the same samples is
    running (its files in progress would look like leftovers); restrict it to your own
    ``shard`` when shards share a folder.

    Args:
        root: dataset folder.
        shard: only touch indices of shard ``(K, N)``.
        verify_hash: as in :func:`completed_indices`.

    Returns:
        The removed paths, sorted.
    """
    root = Path(root)
    if shard is not None:
        shard = _check_shard(shard)
    removed: list[Path] = []
    for index, entries in sorted(_entries(root).items()):
        if not _in_shard(index, shard):
            continue
        complete = _is_complete(root, index, verify_hash)
        for entry in sorted(entries, key=lambda p: p.suffix != ".json"):  # sidecar first
            if complete and temporary_target(entry.name) is None:
                continue
            remove_path(entry)
            removed.append(entry)
    if removed:
        logger.info("removed %d leftover(s) of incomplete samples in %s", len(removed), root / SAMPLES_DIR)
    return sorted(removed)


def remove_manifest_leftovers(root: str | os.PathLike) -> list[Path]:
    """Remove the temporary manifests (``.manifest.json.tmp-*``) that killed writers left in ``root``.

    Every shard writes the manifest, so those of writers still running on this machine stay
    (:func:`pbrdf.io.atomic.remove_leftovers`); nothing else in ``root`` is touched.

    Args:
        root: dataset folder (a missing one holds nothing).

    Returns:
        The removed paths, sorted.
    """
    removed = remove_leftovers(root, {MANIFEST_JSON})
    if removed:
        logger.info("removed %d temporary manifest(s) of killed runs in %s", len(removed), root)
    return removed


def write_manifest(
    root: str | os.PathLike,
    info: Mapping[str, Any],
    *,
    completed: Iterable[int] | None = None,
    verify_hash: bool = True,
) -> Path:
    """Write ``root/manifest.json`` atomically: ``info`` plus the sorted completed indices.

    Args:
        root: dataset folder (created if needed).
        info: JSON-serialisable dataset-level info: count, resolution, seed, shard, config,
            software versions, ... (keys ``format``, ``completed`` and ``num_completed`` are
            reserved).
        completed: the completed indices if already known; by default
            :func:`completed_indices` of ``root`` (all shards).
        verify_hash: passed to :func:`completed_indices`.

    Returns:
        The manifest path.

    Raises:
        ValueError: ``info`` uses a reserved key or is not valid JSON.
    """
    root = Path(root)
    data = check_metadata(info, ("format", "completed", "num_completed"), "manifest info")
    dumps_json(data, "manifest info")
    done = sorted(
        completed_indices(root, verify_hash=verify_hash) if completed is None else {check_index(i) for i in completed}
    )
    text = dumps_json({"format": MANIFEST_FORMAT, **data, "num_completed": len(done), "completed": done}, "manifest")
    root.mkdir(parents=True, exist_ok=True)
    path = root / MANIFEST_JSON
    atomic_write_text(path, text)
    return path


def read_manifest(root: str | os.PathLike) -> dict[str, Any]:
    """Read ``root/manifest.json`` (or the manifest path itself).

    Returns:
        The manifest dict (``info`` keys plus ``format``, ``num_completed``, ``completed``).

    Raises:
        FileNotFoundError: no manifest.
        ValueError: invalid JSON or content.
    """
    p = Path(root)
    path = p / MANIFEST_JSON if p.is_dir() else p
    if not path.is_file():
        raise FileNotFoundError(f"{path}: dataset manifest not found")
    data = read_json_object(path, MANIFEST_FORMAT)
    done = data.get("completed")
    if not isinstance(done, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in done):
        raise ValueError(f"{path}: 'completed' must be a list of sample indices")
    return data


# --------------------------------------------------------------------------------------------
# work planning


def _check_shard(shard: Any) -> tuple[int, int]:
    try:
        k, n = shard
    except (TypeError, ValueError):
        raise ValueError(f"shard must be a pair (K, N); got {shard!r}") from None
    for v in (k, n):
        if isinstance(v, bool) or not isinstance(v, int | np.integer):
            raise ValueError(f"shard (K, N) must hold integers; got {shard!r}")
    k, n = int(k), int(n)
    if n < 1 or not 0 <= k < n:
        raise ValueError(f"shard (K, N) needs N >= 1 and 0 <= K < N; got K={k}, N={n}")
    return k, n


def shard_indices(count: int, shard: tuple[int, int] = (0, 1)) -> list[int]:
    """Indices of ``range(count)`` handled by shard ``K`` of ``N``: round robin, ``i % N == K``.

    Example:
        >>> shard_indices(10, (1, 3))
        [1, 4, 7]
    """
    if isinstance(count, bool) or not isinstance(count, int | np.integer) or count < 0:
        raise ValueError(f"count must be an integer >= 0; got {count!r}")
    k, n = _check_shard(shard)
    return list(range(k, int(count), n))


def parse_shard(text: str) -> tuple[int, int]:
    """Parse ``"K/N"`` (shard K of N, ``0 <= K < N``) as given on a command line.

    Example:
        >>> parse_shard("2/8")
        (2, 8)
    """
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text) if isinstance(text, str) else None
    if not m:
        raise ValueError(f"shard must look like 'K/N' (shard K of N, 0 <= K < N), e.g. '0/4'; got {text!r}")
    k, n = int(m.group(1)), int(m.group(2))
    if n < 1 or k >= n:
        raise ValueError(f"shard {text!r}: need N >= 1 and 0 <= K < N (K counts from 0)")
    return k, n


def plan_work(
    root: str | os.PathLike,
    count: int,
    shard: tuple[int, int] = (0, 1),
    resume: bool = False,
    *,
    verify_hash: bool = True,
) -> list[int]:
    """Sample indices this run still has to write.

    Without ``resume`` the folder may not yet hold files of this shard's samples (complete or
    partial); shards of one dataset may share a folder. With ``resume`` the complete samples of
    the shard are skipped; incomplete ones are listed again (:func:`pbrdf.data.sample.write_sample` overwrites
    their leftovers).

    Args:
        root: dataset folder.
        count: total number of samples of the dataset.
        shard: ``(K, N)``, this run's shard (see :func:`shard_indices`).
        resume: continue an earlier run.
        verify_hash: passed to :func:`completed_indices`.

    Returns:
        Sorted indices to write.

    Raises:
        FileExistsError: not resuming and the folder already holds samples of this shard.
        ValueError: bad ``count`` or ``shard``.
    """
    todo = shard_indices(count, shard)
    shard = _check_shard(shard)
    root = Path(root)
    if not resume:
        mine = sorted(i for i in _entries(root) if _in_shard(i, shard))
        if mine:
            k, n = shard
            raise FileExistsError(
                f"{root}: already holds files of {len(mine)} sample(s) of shard {k}/{n} (e.g. index {mine[0]}); "
                "pass --resume to continue that run, or choose another folder"
            )
        return todo
    done = completed_indices(root, shard=shard, verify_hash=verify_hash)
    return [i for i in todo if i not in done]
