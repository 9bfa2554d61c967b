"""Atomic writes: the one home for "temporary sibling, fsync, rename into place".

Every writer of the project (captures, EXR samples, sidecars, manifests, rigs, CLI outputs)
goes through these helpers, so a killed process leaves either the old file or the new one,
never half of one, and the leftovers are recognisable (:func:`temporary_target`) and cleaned
up on resume. A file is written with :func:`atomic_open` (or :func:`atomic_write_bytes`), a
set of files or a whole folder with :func:`atomic_folder`.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

__all__ = [
    "temporary_path",
    "temporary_target",
    "remove_leftovers",
    "fsync_path",
    "atomic_open",
    "atomic_folder",
    "atomic_write_bytes",
    "atomic_write_text",
]

# ".<target>.tmp-<pid>-<8 hex>" (files being written) or ".<target>.old-<pid>-<8 hex>" (set aside).
_TEMP_RE = re.compile(r"^\.(?P<target>.+)\.(?P<kind>tmp|old)-(?P<pid>\d+)-[0-9a-f]{8}$")


def temporary_path(target: str | os.PathLike, kind: str = "tmp") -> Path:
    """A fresh temporary sibling of ``target``: ``.<name>.<kind>-<pid>-<random hex>`` in its folder.

    Args:
        target: the final path.
        kind: ``"tmp"`` for a file being written, ``"old"`` for a previous version set aside.

    Returns:
        A path in the same folder (so that ``os.replace`` onto ``target`` is atomic).
    """
    t = Path(target)
    return t.parent / f".{t.name}.{kind}-{os.getpid()}-{secrets.token_hex(4)}"


def temporary_target(name: str) -> str | None:
    """The target file name a temporary sibling belongs to, or None if ``name`` is not one.

    Example:
        >>> temporary_target(".000012.exr.tmp-4242-0a1b2c3d")
        '000012.exr'
        >>> temporary_target("000012.exr") is None
        True
    """
    m = _TEMP_RE.match(name)
    return m.group("target") if m else None


def _writer_alive(pid: int) -> bool:
    """Whether ``pid`` is a running process of this machine (this process included; zombies are not).

    Without POSIX signals (Windows) nothing can be asked without side effects: every writer counts as gone.
    """
    if pid == os.getpid():
        return True
    if os.name != "posix" or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except (OverflowError, OSError):  # a pid no process can have
        return False
    try:  # a killed child nobody waited for yet is a zombie: its writes are over
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True  # no /proc (macOS): a live process
    return state not in ("Z", "X")


def remove_leftovers(
    folder: str | os.PathLike, targets: Iterable[str] | Callable[[str], bool] | None = None
) -> list[Path]:
    """Remove the temporary files (and folders) a killed writer left in ``folder`` (not recursive).

    Only entries named exactly like :func:`temporary_path`'s ``"tmp"`` kind are touched
    (``.<target>.tmp-<pid>-<8 hex>``); previous versions set aside (``"old"``), every other name
    and the temporaries of a writer still running on this machine (its pid is alive, this process
    included) stay. A writer on another machine sharing the folder cannot be told from a dead one:
    do not clean a folder another machine is writing to.

    Args:
        folder: the folder (a missing one holds nothing).
        targets: only leftovers of these target names (or for which this predicate is true);
            None: every target.

    Returns:
        The removed paths, sorted.

    Example:
        >>> import tempfile
        >>> d = Path(tempfile.mkdtemp())
        >>> _ = (d / ".model.pt.tmp-999999999-0a1b2c3d").write_bytes(b"half")
        >>> _ = (d / "model.pt").write_bytes(b"done")
        >>> [p.name for p in remove_leftovers(d, {"model.pt"})], sorted(p.name for p in d.iterdir())
        (['.model.pt.tmp-999999999-0a1b2c3d'], ['model.pt'])
        >>> shutil.rmtree(d)
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    if targets is None:
        wanted: Callable[[str], bool] = lambda name: True  # noqa: E731
    elif callable(targets):
        wanted = targets
    else:
        names = frozenset(targets)
        wanted = names.__contains__
    removed = []
    for entry in sorted(folder.iterdir()):
        m = _TEMP_RE.match(entry.name)
        if m is None or m["kind"] != "tmp" or not wanted(m["target"]) or _writer_alive(int(m["pid"])):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def fsync_path(path: str | os.PathLike, *, directory: bool = False) -> None:
    """Fsync a file, or a folder (best effort: some platforms refuse directory handles)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - e.g. platforms without directory handles
        if directory:
            return
        raise
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - some file systems refuse fsync on directories
        if not directory:
            raise
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Open ``path`` for binary writing through a temporary sibling; rename into place on success.

    The data is fsynced and the file gets mode 0644 before ``os.replace``; on any exception
    (KeyboardInterrupt included) the temporary file is removed and ``path`` is untouched.
    Missing parent folders are created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_path(path)
    try:
        with open(tmp, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_path(path.parent, directory=True)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_open`).

    A reader never sees a half-written file; a crash leaves the old file (or none).
    """
    with atomic_open(path) as f:
        f.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """UTF-8 text version of :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def atomic_folder(target: str | os.PathLike, *, merge: bool = False) -> Iterator[Path]:
    """Write a folder's files together: yield an empty staging folder, put its files into place on success.

    The staging folder is a temporary sibling of ``target`` (:func:`temporary_path`, so that
    :func:`remove_leftovers` recognises one a killed writer left). When the ``with`` block ends
    without an exception, every file in it is fsynced, then

    * ``merge=False``: the staging folder becomes ``target`` by one rename. An existing
      ``target`` is first renamed aside (an ``"old"`` sibling) and deleted once the new one is in
      place (put back if that rename fails), so a reader sees the old folder or the new one.
    * ``merge=True``: each staged file is renamed into ``target`` (created only now if missing),
      replacing files of the same name and leaving the others: each file appears whole, all of
      them after the work succeeded (a crash between two renames can leave some of the new files).

    On any exception (KeyboardInterrupt included) the staging folder is removed and ``target``
    is untouched: no half-written folder and no temporary one are left.

    Args:
        target: the folder to write; its parent folders are created if missing.
        merge: add the files to ``target`` instead of replacing the whole folder.

    Yields:
        The staging folder (empty), on the same file system as ``target``.

    Raises:
        NotADirectoryError: ``target`` exists and is not a folder.
        OSError: the staging folder cannot be created or renamed.

    Example:
        >>> import tempfile
        >>> d = Path(tempfile.mkdtemp())
        >>> with atomic_folder(d / "capture") as tmp:
        ...     _ = (tmp / "capture.json").write_text("{}")
        >>> sorted(p.name for p in d.iterdir()), (d / "capture" / "capture.json").read_text()
        (['capture'], '{}')
        >>> shutil.rmtree(d)
    """
    target = Path(target)
    if target.is_symlink() or (target.exists() and not target.is_dir()):
        raise NotADirectoryError(f"{target}: exists and is not a folder")
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = _new_folder(target, "tmp")
    try:
        yield staging
        _fsync_tree(staging)
        if merge:
            _merge_into(staging, target)
        else:
            _replace_folder(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # gone after a rename; the leftovers of a failure
    fsync_path(target.parent, directory=True)


def _new_folder(target: Path, kind: str) -> Path:
    """Create a new, uniquely named temporary sibling folder of ``target``."""
    for _ in range(100):
        path = temporary_path(target, kind)
        try:
            path.mkdir()
        except FileExistsError:  # pragma: no cover - 32 random bits collided
            continue
        return path
    raise FileExistsError(f"{target.parent}: cannot create a temporary folder")  # pragma: no cover


def _fsync_tree(folder: Path) -> None:
    """Fsync every file and folder under ``folder`` (the folder included) before it is renamed."""
    for path in sorted(folder.rglob("*")):
        fsync_path(path, directory=path.is_dir())
    fsync_path(folder, directory=True)


def _merge_into(staging: Path, target: Path) -> None:
    """Rename each entry of ``staging`` into ``target`` (created if missing)."""
    target.mkdir(exist_ok=True)
    for path in sorted(staging.iterdir()):
        os.replace(path, target / path.name)
    fsync_path(target, directory=True)


def _replace_folder(staging: Path, target: Path) -> None:
    """Rename the finished ``staging`` folder to ``target``, replacing an existing one."""
    if target.is_dir() and not any(target.iterdir()):
        target.rmdir()
    if not target.exists():
        os.replace(staging, target)
        return
    old = _new_folder(target, "old")
    old.rmdir()
    os.replace(target, old)
    try:
        os.replace(staging, target)
    except BaseException:
        os.replace(old, target)  # put the previous folder back
        raise
    shutil.rmtree(old, ignore_errors=True)
