"""PBR map files by name: filename tokens, synonyms per map kind and matching a folder's files.

The network (``headless/infer.py``) writes ``DIR/<name>_normal.exr``, ``_albedo.exr``,
``_roughness.exr``, ``_metallic.exr``, ``_mask.exr``, ``_depth.exr``, a PNG preview of each and
``<name>_camera.json`` (found by :func:`camera_file`); the names and the JSON files are
:mod:`pbrdf.data.predictions`'. Other tools name maps ``BaseColor``,
``nrm``, ``Metalness``...: :func:`match_map_files` finds each map kind by filename tokens;
:mod:`.map_io` then reads and validates the files. A sequence is ``<name>_NNNN_<map>.exr`` per
frame (NNNN from 0001) plus ``<name>_sequence.json``: :func:`find_sequence` and
:func:`match_sequence_files` check it is one Blender can play as image sequences (Blender takes
the frame number from the last run of digits in a file name, whatever follows it).

Convention (tokens):
    A file name (without its suffix) is split into lowercase tokens at every non-alphanumeric
    character, at lower-to-upper case changes and between letters and digits:
    ``"chart01_BaseColor.png"`` -> ``("chart", "01", "base", "color")``. A map kind matches when
    one of its synonyms (:data:`SYNONYMS`, one or more tokens) appears as whole consecutive tokens,
    so ``"metalness"`` is a metallic map but ``"dialbedo"`` is not an albedo map.

Example:
    >>> filename_tokens("chart01_BaseColor.png")
    ('chart', '01', 'base', 'color')
    >>> match_kinds(filename_tokens("chart01_BaseColor.png"))
    ('albedo',)
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from pbrdf.data.predictions import CAMERA_SUFFIX, MAP_NAMES, SEQUENCE_SUFFIX, SequenceRecord

__all__ = [
    "IMAGE_SUFFIXES",
    "SequenceFiles",
    "camera_file",
    "find_sequence",
    "match_sequence_files",
    "SYNONYMS",
    "MapFiles",
    "filename_tokens",
    "match_kinds",
    "match_map_files",
]

#: Filename synonyms per kind; a multi-token synonym (``base color``) must appear as consecutive tokens.
SYNONYMS: dict[str, tuple[tuple[str, ...], ...]] = {
    "normal": (("normal",), ("normals",), ("nrm",), ("nrml",)),
    "albedo": (("albedo",), ("diffuse",), ("basecolor",), ("base", "color"), ("color",), ("colour",)),
    "roughness": (("roughness",), ("rough",), ("rgh",)),
    "metallic": (("metallic",), ("metalness",), ("metal",)),
    "mask": (("mask",), ("alpha",), ("opacity",)),
    "depth": (("depth",), ("z",), ("zdepth",), ("height",), ("heightmap",)),
}

#: Readable suffixes, most preferred first: when ``x_normal.exr`` and its preview ``x_normal.png``
#: both exist, the EXR wins.
IMAGE_SUFFIXES = (".exr", ".png", ".jpg", ".jpeg")


def filename_tokens(name: str | os.PathLike) -> tuple[str, ...]:
    """Lowercase tokens of a file name without its image suffix.

    Args:
        name: file name or path (only the last component is used).

    Returns:
        The tokens, e.g. ``("chart", "01", "base", "color")`` for ``"chart01_BaseColor.png"``.

    Example:
        >>> filename_tokens("dir/Rock-Metalness_2K.PNG")
        ('rock', 'metalness', '2', 'k')
    """
    stem = Path(name).name
    if Path(stem).suffix.lower() in IMAGE_SUFFIXES:
        stem = stem[: -len(Path(stem).suffix)]
    tokens: list[str] = []
    for chunk in re.split(r"[^A-Za-z0-9]+", stem):
        # "RGBNormal" -> RGB, Normal; "baseColor" -> base, Color; "n2k" -> n, 2, k
        tokens += re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+", chunk)
    return tuple(t.lower() for t in tokens)


def _find(tokens: tuple[str, ...], synonym: tuple[str, ...]) -> int:
    """Index of the first occurrence of ``synonym`` as consecutive tokens, or -1."""
    n = len(synonym)
    for i in range(len(tokens) - n + 1):
        if tokens[i : i + n] == synonym:
            return i
    return -1


def match_kinds(tokens: Iterable[str]) -> tuple[str, ...]:
    """Map kinds whose synonyms appear in ``tokens`` (in :data:`pbrdf.data.predictions.MAP_NAMES` order).

    Example:
        >>> match_kinds(("rock", "metalness")), match_kinds(("dialbedo",)), match_kinds(("base", "color"))
        (('metallic',), (), ('albedo',))
    """
    tokens = tuple(tokens)
    return tuple(k for k in MAP_NAMES if any(_find(tokens, s) >= 0 for s in SYNONYMS[k]))


def _strip_common(token_lists: list[tuple[str, ...]]) -> list[tuple[str, ...]]:
    """Drop the token prefix and suffix shared by all lists (``"chart_color"`` in every name of an asset)."""
    if len(token_lists) < 2:
        return token_lists
    shortest = min(len(t) for t in token_lists)
    pre = 0
    while pre < shortest and len({t[pre] for t in token_lists}) == 1:
        pre += 1
    suf = 0
    while suf < shortest - pre and len({t[len(t) - 1 - suf] for t in token_lists}) == 1:
        suf += 1
    return [t[pre : len(t) - suf] for t in token_lists]


@dataclass(frozen=True)
class MapFiles:
    """The result of matching file names to map kinds.

    Attributes:
        files: kind -> chosen file, in :data:`pbrdf.data.predictions.MAP_NAMES` order.
        unmatched: image files whose names match no kind (ignored).
        superseded: files of a chosen map in a less preferred format (``x_normal.png`` beside
            ``x_normal.exr``).
    """

    files: dict[str, Path]
    unmatched: tuple[Path, ...] = ()
    superseded: tuple[Path, ...] = ()

    @property
    def missing(self) -> tuple[str, ...]:
        """Kinds without a file."""
        return tuple(k for k in MAP_NAMES if k not in self.files)

    def summary(self) -> str:
        """One line: the found maps, the missing ones and the ignored files."""
        found = ", ".join(f"{k}={p.name}" for k, p in self.files.items()) or "none"
        text = f"maps: {found}; missing: {', '.join(self.missing) or 'none'}"
        if self.unmatched:
            text += f"; ignored: {', '.join(p.name for p in self.unmatched)}"
        return text


def _folder_images(path: Path) -> list[Path]:
    return sorted(
        p for p in path.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES
    )


def _image_files(source: str | os.PathLike | Iterable[str | os.PathLike]) -> tuple[list[Path], str]:
    """Image files of a folder (not recursive, hidden files skipped) or of a list of files and folders."""
    source = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    files: list[Path] = []
    for item in source:
        p = Path(item)
        if p.is_dir():
            files += _folder_images(p)
            continue
        if not p.is_file():
            raise FileNotFoundError(f"{p}: map file not found")
        if p.suffix.lower() not in IMAGE_SUFFIXES:
            raise ValueError(f"{p}: unsupported map format {p.suffix!r}; use one of {', '.join(IMAGE_SUFFIXES)}")
        files.append(p)
    if not files and not any(Path(x).is_dir() for x in source):
        raise ValueError("no map files given")
    return files, ", ".join(str(x) for x in source)


def match_map_files(
    source: str | os.PathLike | Iterable[str | os.PathLike] | Mapping[str, str | os.PathLike],
    *,
    required: Iterable[str] = ("normal",),
) -> MapFiles:
    """Find the normal, albedo, roughness, metallic, mask and depth maps by filename tokens.

    Rules: tokens shared by all matching names (the asset name) are ignored; a name that then
    matches two kinds is ambiguous; two names for one kind are ambiguous (one asset per folder, or
    pass the files); the same name in several formats takes the first of :data:`IMAGE_SUFFIXES`.

    Args:
        source: a folder, a list of files (and folders), or an explicit ``{kind: file}`` mapping
            (no matching).
        required: kinds that must be found.

    Returns:
        The matched files.

    Raises:
        FileNotFoundError: the folder, a listed file or a required map is missing.
        ValueError: ambiguous names (all listed in one line), an unknown kind or format.
    """
    required = tuple(required)
    unknown = [k for k in required if k not in MAP_NAMES]
    if unknown:
        raise ValueError(f"unknown map kinds {unknown}; valid: {list(MAP_NAMES)}")
    if isinstance(source, Mapping):
        bad = [k for k in source if k not in MAP_NAMES]
        if bad:
            raise ValueError(f"unknown map kinds {bad}; valid: {list(MAP_NAMES)}")
        files = {k: Path(source[k]) for k in MAP_NAMES if k in source}
        for p in files.values():
            if not p.is_file():
                raise FileNotFoundError(f"{p}: map file not found")
        result, where = MapFiles(files), "the given mapping"
    else:
        if isinstance(source, (str, os.PathLike)) and not Path(source).exists():
            raise FileNotFoundError(f"{source}: no such folder or file")
        paths, where = _image_files(source)
        result = _match(paths)
    missing = [k for k in required if k not in result.files]
    if missing:
        looked = "; ".join(f"{k}: {', '.join(' '.join(s) for s in SYNONYMS[k])}" for k in missing)
        raise FileNotFoundError(f"no {' or '.join(missing)} map in {where} (name tokens looked for: {looked})")
    return result


def _match(paths: list[Path]) -> MapFiles:
    tokens = {p: filename_tokens(p) for p in paths}
    candidates = [p for p in paths if match_kinds(tokens[p])]
    stripped = dict(zip(candidates, _strip_common([tokens[p] for p in candidates]), strict=True))
    by_kind: dict[str, dict[str, list[Path]]] = {}  # kind -> stem -> files
    errors: list[str] = []
    unmatched = [p for p in paths if p not in stripped]
    for p in candidates:
        kinds = match_kinds(stripped[p]) or match_kinds(tokens[p])
        if len(kinds) > 1:
            errors.append(f"{p.name} matches several maps ({', '.join(kinds)})")
            continue
        stem = str(p.with_suffix("")).lower()
        by_kind.setdefault(kinds[0], {}).setdefault(stem, []).append(p)
    files: dict[str, Path] = {}
    superseded: list[Path] = []
    for kind in MAP_NAMES:
        stems = by_kind.get(kind, {})
        if len(stems) > 1:
            names = ", ".join(sorted(q.name for group in stems.values() for q in group))
            errors.append(f"{len(stems)} files match {kind} ({names})")
        elif stems:
            (group,) = stems.values()
            group = sorted(group, key=lambda q: IMAGE_SUFFIXES.index(q.suffix.lower()))
            files[kind] = group[0]
            superseded += group[1:]
    if errors:
        raise ValueError("ambiguous map files: " + "; ".join(errors) + " (pass the files explicitly, one per map)")
    return MapFiles(files, tuple(unmatched), tuple(superseded))


# --------------------------------------------------------------------------- camera and sequences


def camera_file(files: Mapping[str, str | os.PathLike]) -> Path | None:
    """The ``<prefix>_camera.json`` beside the normal map (else the first map) of ``files``, or None.

    It belongs to the maps when every map is named ``<prefix><separator><its kind's synonym>``
    (``cap_normal.exr``, ``cap_albedo.png`` for ``cap_camera.json``); a camera file of other
    maps in the same folder is ignored.

    Example:
        >>> import tempfile
        >>> d = Path(tempfile.mkdtemp())
        >>> for n in ("cap_normal.exr", "cap_camera.json", "other_camera.json"):
        ...     _ = (d / n).write_text("")
        >>> camera_file({"normal": d / "cap_normal.exr"}).name
        'cap_camera.json'
    """
    paths = {k: Path(v) for k, v in files.items()}
    if not paths:
        return None
    folder = paths.get("normal", next(iter(paths.values()))).parent
    if not folder.is_dir():
        return None
    for candidate in sorted(folder.glob(f"*{CAMERA_SUFFIX}")):
        prefix = candidate.name[: -len(CAMERA_SUFFIX)]
        if candidate.is_file() and prefix and all(_named(p, prefix, k) for k, p in paths.items()):
            return candidate
    return None


def _named(path: Path, prefix: str, kind: str) -> bool:
    """``path`` is ``<prefix><separator><a synonym of kind><image suffix>``."""
    stem = path.name[: -len(path.suffix)] if path.suffix.lower() in IMAGE_SUFFIXES else path.name
    rest = stem[len(prefix) :]
    if not stem.startswith(prefix) or not rest or rest[0].isalnum():
        return False
    return filename_tokens(rest.lstrip("_-. ") + ".exr") in SYNONYMS.get(kind, ())


def find_sequence(source: object) -> Path | None:
    """The ``<name>_sequence.json`` that ``source`` names, or None (not a sequence).

    ``source`` names one when it is that file (alone or as the only item of a list) or a folder
    holding exactly one such file; several in one folder are refused on one line.

    Raises:
        ValueError: a folder with several sequence files.
    """
    if isinstance(source, Mapping):
        return None
    if not isinstance(source, (str, os.PathLike)):
        items = list(source) if isinstance(source, Iterable) else []
        if len(items) != 1 or not isinstance(items[0], (str, os.PathLike)):
            return None
        source = items[0]
    path = Path(source)
    if path.is_file():
        return path if path.name.endswith(SEQUENCE_SUFFIX) else None
    if not path.is_dir():
        return None
    found = sorted(p for p in path.glob(f"*{SEQUENCE_SUFFIX}") if p.is_file() and not p.name.startswith("."))
    if len(found) > 1:
        names = ", ".join(p.name for p in found)
        raise ValueError(f"{path}: {len(found)} sequences ({names}); choose one {SEQUENCE_SUFFIX} file")
    return found[0] if found else None


@dataclass(frozen=True)
class SequenceFiles:
    """A sequence's files (see :func:`match_sequence_files`).

    Attributes:
        path: the ``<name>_sequence.json``.
        name: the sequence name.
        frames: number of frames n (files numbered 1..n).
        first: frame 1's matched maps (the files Blender's image sequences start from).
        camera: frame 1's ``<prefix>_camera.json``, or None.
    """

    path: Path
    name: str
    frames: int
    first: MapFiles
    camera: Path | None = None

    def frame(self, i: int) -> MapFiles:
        """Frame ``i``'s maps (1..``frames``): frame 1's files with Blender's frame number i in their names.

        Raises:
            ValueError: ``i`` outside 1..``frames``.
        """
        if not 1 <= i <= self.frames:
            raise ValueError(f"frame must be in 1..{self.frames}, got {i}")
        return MapFiles({kind: _frame_file(p, i) for kind, p in self.first.files.items()}, ())


def _frame_number(path: Path) -> tuple[str, str, str]:
    """``(head, digits, tail)`` of a file name as Blender splits it: the last digits before the suffix."""
    stem, suffix = path.name[: -len(path.suffix)], path.suffix
    m = re.search(r"(\d+)(\D*)$", stem)
    if m is None:
        return stem, "", suffix
    return stem[: m.start()], m.group(1), m.group(2) + suffix


def _frame_file(path: Path, i: int) -> Path:
    """Frame ``i``'s file of frame 1's ``path``: its last digits replaced by i, zero-padded as they were."""
    head, digits, tail = _frame_number(path)
    return path.with_name(head + str(i).zfill(len(digits)) + tail)


def match_sequence_files(path: str | os.PathLike, *, required: Iterable[str] = ("normal",)) -> SequenceFiles:
    """Check a ``<name>_sequence.json`` and the map files of its frames.

    Frame 1's maps are the image files named ``<prefix>_*`` beside the JSON (``prefix`` of its
    first frame), matched as :func:`match_map_files` does. Every frame i must have the same maps
    under the name Blender derives for frame i (the last digits of frame 1's name replaced by i,
    zero-padded to the same width), and the JSON's ``prefix`` of frame i must be that name's.

    Raises:
        FileNotFoundError: the JSON, a required map of frame 1 or a map of a later frame is missing.
        ValueError: a malformed JSON (one line naming the file and the field), frame names Blender
            cannot number, ambiguous map names.
    """
    path = Path(path)
    record = SequenceRecord.read(path)
    prefixes, name = record.prefixes, record.name
    folder = path.parent
    own = [
        p
        for p in _folder_images(folder)
        if p.name.startswith(prefixes[0]) and p.name[len(prefixes[0]) : len(prefixes[0]) + 1] in ("_", "-", ".")
    ]
    if not own:
        raise FileNotFoundError(f"{path}: frame 1 has no map files {prefixes[0]}_* in {folder}")
    first = match_map_files(own, required=required)
    head, digits, _ = _frame_number(Path(prefixes[0] + ".exr"))
    if not digits or int(digits) != 1:
        raise ValueError(
            f"{path}: frames[0].prefix: {prefixes[0]!r} must end in frame number 1 (<name>_0001): "
            f"Blender numbers image sequences by the last digits of a file name"
        )
    for p in first.files.values():
        if _frame_number(p)[:2] != (head, digits):
            raise ValueError(
                f"{p.name}: Blender would read the frame number from its last digits, not from {digits!r}; "
                f"name frames <name>_NNNN_<map> with no digits after the frame number"
            )
    for i, prefix in enumerate(prefixes[1:], start=2):
        expected = head + str(i).zfill(len(digits))
        if prefix != expected:
            raise ValueError(
                f"{path}: frames[{i - 1}].prefix: {prefix!r}, but Blender reads frame {i} from {expected!r}"
            )
        for p in first.files.values():
            frame_file = _frame_file(p, i)
            if not frame_file.is_file():
                raise FileNotFoundError(f"{path}: frame {i} has no {frame_file.name} (frame 1 has {p.name})")
    return SequenceFiles(path, name, len(prefixes), first, camera_file(first.files))
