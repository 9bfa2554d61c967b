"""PBR map files without bpy: filename-token matching, loading, validation and camera-frustum math.

The network (``headless/infer.py``) writes ``DIR/<name>_normal.exr`` (channels ``normal.X/Y/Z``),
``_albedo.exr`` (``albedo.R/G/B``), ``_roughness.exr`` (``roughness.Y``), ``_metallic.exr``
(``metallic.Y``), ``_mask.exr`` (``mask.Y``) and a PNG preview of each. Other tools name maps
``BaseColor``, ``nrm``, ``Metalness``...: :func:`match_map_files` finds each map kind by filename
tokens, :func:`load_maps` reads and validates the arrays, and the add-on (``pbr_import.py``,
``bake.py``) turns them into Blender images.

Convention (tokens):
    A file name (without its suffix) is split into lowercase tokens at every non-alphanumeric
    character, at lower-to-upper case changes and between letters and digits:
    ``"chart01_BaseColor.png"`` -> ``("chart", "01", "base", "color")``. A map kind matches when
    one of its synonyms (:data:`SYNONYMS`, one or more tokens) appears as whole consecutive tokens,
    so ``"metalness"`` is a metallic map but ``"dialbedo"`` is not an albedo map.

Convention (maps, as in docs/ARCHITECTURE.md):
    Images ``(H, W, C)`` float32, row 0 at the top. Normals in the camera frame, OpenGL
    convention (x right, y up, z toward the camera), unit length; EXR files hold them raw
    (``[-1, 1]``), 8/16-bit files encoded as ``0.5 + 0.5 n``. Albedo linear RGB in [0, 1] (PNG/JPEG
    albedo is sRGB-encoded unless told otherwise). Roughness, metallic, mask in [0, 1]. Depth: EXR
    only, metres along the optical axis (positive in front of the camera, as Blender's Z pass).

Convention (camera):
    A Blender camera looks down its local -z with x right and y up; :class:`Frustum` is its image
    rectangle at unit distance. Pixel ``(u, v)``: u right, v down, pixel ``(0, 0)`` covers
    ``[0, 1] x [0, 1]``. Example: a 4 x 2 image with a 36 mm sensor and a 36 mm lens has the
    rectangle ``x in [-0.5, 0.5], y in [-0.25, 0.25]`` at ``z = -1``, and pixel ``(0, 0)``'s centre is
    ``(-0.375, 0.125, -1)``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pbrdf.sensor import projection

__all__ = [
    "MAP_KINDS",
    "SYNONYMS",
    "IMAGE_SUFFIXES",
    "MapFiles",
    "PBRMaps",
    "Frustum",
    "filename_tokens",
    "match_kinds",
    "match_map_files",
    "read_channels",
    "load_map",
    "load_maps",
    "blender_frustum",
    "srgb_to_linear",
    "depth_mesh",
]

#: Map kinds in import order.
MAP_KINDS = ("normal", "albedo", "roughness", "metallic", "mask", "depth")

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

# Component names accepted for 3-vector maps in EXR files, and channel names tried for scalars.
_VECTOR_COMPONENTS = (("X", "Y", "Z"), ("R", "G", "B"))
_SCALAR_COMPONENTS = ("Y", "V", "Z", "R", "X", "A")
# |‖n‖ - 1| allowed before renormalising: float files are normalised by the writer; 8-bit
# encoding moves each component by up to 1/255 (|‖n‖ - 1| <= 0.007), tools add a bit more.
_UNIT_TOL = {"float": 1e-2, "int": 5e-2}
_RANGE_SLACK = 1e-3  # values this far outside [0, 1] are clipped silently; further ones are reported


# --------------------------------------------------------------------------- tokens and matching


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
    """Map kinds whose synonyms appear in ``tokens`` (in :data:`MAP_KINDS` order).

    Example:
        >>> match_kinds(("rock", "metalness")), match_kinds(("dialbedo",)), match_kinds(("base", "color"))
        (('metallic',), (), ('albedo',))
    """
    tokens = tuple(tokens)
    return tuple(k for k in MAP_KINDS if any(_find(tokens, s) >= 0 for s in SYNONYMS[k]))


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
        files: kind -> chosen file, in :data:`MAP_KINDS` order.
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
        return tuple(k for k in MAP_KINDS if k not in self.files)

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
    unknown = [k for k in required if k not in MAP_KINDS]
    if unknown:
        raise ValueError(f"unknown map kinds {unknown}; valid: {list(MAP_KINDS)}")
    if isinstance(source, Mapping):
        bad = [k for k in source if k not in MAP_KINDS]
        if bad:
            raise ValueError(f"unknown map kinds {bad}; valid: {list(MAP_KINDS)}")
        files = {k: Path(source[k]) for k in MAP_KINDS if k in source}
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
    for kind in MAP_KINDS:
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


# --------------------------------------------------------------------------- loading


def srgb_to_linear(x: NDArray) -> NDArray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), elementwise on values in [0, 1]."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def read_channels(path: str | os.PathLike) -> tuple[dict[str, NDArray], bool]:
    """All channels of an image file as float32 ``(H, W)`` arrays.

    EXR channels keep their names (via :func:`pbrdf.io.exr.read_exr`); 8/16-bit PNG/JPEG channels are
    named ``R, G, B, A`` or ``Y`` (grey) and scaled to [0, 1].

    Returns:
        ``(channels, is_float)``: is_float is True for EXR (raw values), False for integer files.

    Raises:
        FileNotFoundError: no such file.
        ValueError: unreadable file or unsupported format (one line naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: map file not found")
    suffix = path.suffix.lower()
    if suffix == ".exr":
        try:
            from pbrdf.io.exr import read_exr  # noqa: PLC0415 - OpenEXR only when an EXR is read
        except ImportError as e:  # Blender's bundled Python lacks OpenEXR
            raise ValueError(
                f"{path}: reading EXR maps needs the OpenEXR package ({e}); install it with "
                "'<blender python> -m pip install OpenEXR' or use PNG maps"
            ) from None

        return {k: np.asarray(v, dtype=np.float32) for k, v in read_exr(path).items()}, True
    if suffix not in IMAGE_SUFFIXES:
        raise ValueError(f"{path}: unsupported map format {suffix!r}; use one of {', '.join(IMAGE_SUFFIXES)}")
    try:
        from PIL import Image, UnidentifiedImageError  # noqa: PLC0415
    except ImportError as e:  # Blender's bundled Python lacks Pillow (the add-on passes its own reader)
        raise ValueError(f"{path}: reading PNG/JPEG maps needs Pillow ({e})") from None

    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.asarray(im, dtype=np.float32) / 65535.0
                return {"Y": arr}, False
            if mode not in ("L", "LA", "RGB", "RGBA"):
                im = im.convert("RGBA" if "A" in mode or "transparency" in im.info else "RGB")
                mode = im.mode
            arr = np.asarray(im, dtype=np.float32) / 255.0
    except (UnidentifiedImageError, OSError, SyntaxError) as e:
        raise ValueError(f"{path}: not a readable image: {' '.join(str(e).split())}") from None
    names = {"L": "Y", "LA": "YA", "RGB": "RGB", "RGBA": "RGBA"}[mode]
    if arr.ndim == 2:
        arr = arr[..., None]
    return {c: arr[..., i] for i, c in enumerate(names)}, False


def _split(name: str) -> tuple[str, str]:
    prefix, _, comp = name.rpartition(".")
    return prefix, comp


def _named_for(prefix: str, kind: str) -> bool:
    """Whether a channel prefix (``normal``, ``ViewLayer.Normal``) names ``kind``."""
    return bool(prefix) and kind in match_kinds(filename_tokens(prefix.replace(".", "_")))


def _pick_vector(ch: Mapping[str, NDArray], kind: str, path: Path) -> NDArray:
    groups: dict[str, dict[str, str]] = {}
    for name in ch:
        prefix, comp = _split(name)
        groups.setdefault(prefix, {})[comp.upper()] = name
    found = []
    for prefix, comps in groups.items():
        for names in _VECTOR_COMPONENTS:
            if all(c in comps for c in names):
                found.append((prefix, [comps[c] for c in names]))
                break
    named = [f for f in found if _named_for(f[0], kind)]
    chosen = named if named else found
    if len(chosen) != 1:
        raise ValueError(
            f"{path}: cannot tell which channels hold the {kind} map (want one X/Y/Z or R/G/B group); "
            f"channels: {sorted(ch)}"
        )
    return np.stack([ch[n] for n in chosen[0][1]], axis=-1)


def _pick_scalar(ch: Mapping[str, NDArray], kind: str, path: Path) -> NDArray:
    if len(ch) == 1:
        return next(iter(ch.values()))
    named = [n for n in ch if _named_for(_split(n)[0], kind)]
    pool = named if named else list(ch)
    if len(pool) == 1:
        return ch[pool[0]]
    by_comp = {_split(n)[1].upper(): n for n in pool}
    if len(by_comp) == len(pool):
        for comp in _SCALAR_COMPONENTS:
            if comp in by_comp:
                return ch[by_comp[comp]]
    raise ValueError(f"{path}: cannot tell which channel holds the {kind} map; channels: {sorted(ch)}")


def _nonfinite(arr: NDArray, kind: str, path: Path) -> None:
    bad = ~np.isfinite(arr)
    if arr.ndim == 3:
        bad = bad.any(axis=-1)
    if bad.any():
        r, c = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(f"{path}: {kind} map has NaN/Inf in {int(bad.sum())} pixel(s), first at (row {r}, col {c})")


#: A function reading every channel of an image file, like :func:`read_channels`.
Reader = Callable[[Path], tuple[dict[str, NDArray], bool]]


def load_map(
    path: str | os.PathLike, kind: str, *, srgb: bool | None = None, reader: Reader | None = None
) -> tuple[NDArray, bool]:
    """Read one map file as float32 in the conventions of the module docstring (not yet validated).

    Args:
        path: EXR, PNG or JPEG file.
        kind: one of :data:`MAP_KINDS`.
        srgb: decode sRGB (albedo only); None = for 8/16-bit files, not for EXR.
        reader: reads the file's channels; default :func:`read_channels`.

    Returns:
        ``(array, is_float)``: ``(H, W, 3)`` for normal (still raw: EXR values as stored, integer
        files decoded from ``0.5 + 0.5 n``) and albedo, ``(H, W)`` otherwise.

    Raises:
        ValueError: unknown kind, channels that cannot be told apart, NaN/Inf, a non-EXR depth map.
    """
    if kind not in MAP_KINDS:
        raise ValueError(f"unknown map kind {kind!r}; valid: {list(MAP_KINDS)}")
    path = Path(path)
    ch, is_float = (reader or read_channels)(path)
    if kind == "depth" and not is_float:
        raise ValueError(f"{path}: depth maps must be float EXR files in metres, not 8/16-bit images")
    if kind in ("normal", "albedo"):
        if not is_float and "Y" in ch:  # grey image used as a colour map
            ch = {"R": ch["Y"], "G": ch["Y"], "B": ch["Y"]}
        arr = _pick_vector(ch, kind, path)
    else:
        arr = _pick_scalar(ch, kind, path)
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    if kind != "depth":  # depth is checked inside the mask only (Blender's Z pass is huge or inf outside)
        _nonfinite(arr, kind, path)
    if kind == "normal" and not is_float:
        arr = arr * 2.0 - 1.0
    if kind == "albedo" and (srgb if srgb is not None else not is_float):
        arr = srgb_to_linear(np.clip(arr, 0.0, 1.0))
    return arr, is_float


@dataclass
class PBRMaps:
    """Validated maps of one view, all ``(H, W, ...)`` float32, row 0 at the top.

    Attributes:
        normal: ``(H, W, 3)`` unit camera-space normals; ``(0, 0, 1)`` outside the mask. None if absent.
        albedo: ``(H, W, 3)`` linear RGB in [0, 1], or None.
        roughness: ``(H, W)`` in [0, 1], or None.
        metallic: ``(H, W)`` in [0, 1], or None.
        mask: ``(H, W)`` in [0, 1]; from the mask file, else the pixels with a non-zero normal, else ones.
        depth: ``(H, W)`` metres along the optical axis, or None.
        files: kind -> source file.
        mask_source: ``"file"``, ``"normal"`` (non-zero normals) or ``"none"`` (all ones).
        warnings: one line per value that was clipped.
    """

    normal: NDArray | None = None
    albedo: NDArray | None = None
    roughness: NDArray | None = None
    metallic: NDArray | None = None
    mask: NDArray | None = None
    depth: NDArray | None = None
    files: dict[str, Path] = field(default_factory=dict)
    mask_source: str = "none"
    warnings: list[str] = field(default_factory=list)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``."""
        return tuple(self.mask.shape[:2])

    @property
    def valid(self) -> NDArray:
        """``(H, W)`` bool: mask > 0.5."""
        return self.mask > 0.5

    def present(self) -> tuple[str, ...]:
        """The kinds with data (mask only if it came from a file)."""
        return tuple(
            k for k in MAP_KINDS if (self.mask_source == "file" if k == "mask" else getattr(self, k) is not None)
        )


def _clip01(arr: NDArray, kind: str, path: Path, valid: NDArray, warnings: list[str]) -> NDArray:
    out_of_range = ((arr < -_RANGE_SLACK) | (arr > 1 + _RANGE_SLACK)) & (valid[..., None] if arr.ndim == 3 else valid)
    if out_of_range.any():
        n = int(out_of_range.any(axis=-1).sum()) if arr.ndim == 3 else int(out_of_range.sum())
        warnings.append(
            f"{path.name}: {kind} outside [0, 1] in {n} pixel(s) "
            f"(range {float(arr.min()):.3g}..{float(arr.max()):.3g}), clipped"
        )
    return np.clip(arr, 0.0, 1.0)


def _unit_normals(raw: NDArray, is_float: bool, valid: NDArray, path: Path) -> NDArray:
    """Validate and renormalise normals over ``valid``; EXR values in [0, 1] may be encoded."""
    tol = _UNIT_TOL["float" if is_float else "int"]
    norm = np.linalg.norm(raw, axis=-1)
    n = raw
    if is_float and valid.any() and np.median(np.abs(norm[valid] - 1)) > tol and raw[valid].min() >= 0:
        n = raw * 2.0 - 1.0  # an EXR holding 0.5 + 0.5 n
        norm = np.linalg.norm(n, axis=-1)
    bad = valid & (np.abs(norm - 1.0) > tol)
    if bad.any():
        r, c = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(
            f"{path}: normal map is not unit length in {int(bad.sum())} of {int(valid.sum())} pixel(s) "
            f"(first at row {r}, col {c}: |n| = {float(norm[r, c]):.4f}; tolerance {tol})"
        )
    out = np.zeros_like(n)
    out[..., 2] = 1.0
    out[valid] = n[valid] / norm[valid][:, None]
    return out


def load_maps(
    files: MapFiles | Mapping[str, str | os.PathLike], *, albedo_srgb: bool | None = None, reader: Reader | None = None
) -> PBRMaps:
    """Load and validate matched map files.

    Checks: every map has the same size, no NaN/Inf, unit normals inside the mask (renormalised;
    EXR normals stored as ``0.5 + 0.5 n`` are recognised), positive depth inside the mask. Values
    of albedo, roughness, metallic and mask outside [0, 1] are clipped and reported in
    ``warnings``.

    Args:
        files: a :class:`MapFiles` or ``{kind: path}``.
        albedo_srgb: decode the albedo file as sRGB; None = for PNG/JPEG, not for EXR.
        reader: reads a file's channels; default :func:`read_channels` (OpenEXR and Pillow).

    Returns:
        The maps.

    Raises:
        ValueError: sizes differ, invalid values (the message names the file and the first bad pixel).
        FileNotFoundError: a file is missing.
    """
    paths = dict(files.files if isinstance(files, MapFiles) else {k: Path(v) for k, v in files.items()})
    if not paths:
        raise ValueError("no map files to load")
    raw: dict[str, tuple[NDArray, bool]] = {}
    for kind, p in paths.items():
        raw[kind] = load_map(p, kind, srgb=albedo_srgb if kind == "albedo" else None, reader=reader)
    shapes = {k: v[0].shape[:2] for k, v in raw.items()}
    if len(set(shapes.values())) > 1:
        listing = ", ".join(f"{k} {paths[k].name} {h}x{w}" for k, (h, w) in shapes.items())
        raise ValueError(f"map sizes differ (H x W): {listing}")
    (h, w) = next(iter(shapes.values()))
    out = PBRMaps(files={k: Path(v) for k, v in paths.items()})
    if "mask" in raw:
        out.mask = _clip01(raw["mask"][0], "mask", paths["mask"], np.ones((h, w), bool), out.warnings)
        out.mask_source = "file"
    elif "normal" in raw:
        out.mask = (np.abs(raw["normal"][0]).max(axis=-1) > 0).astype(np.float32)
        if not raw["normal"][1]:  # an 8-bit background is encoded 0, decoded -1
            out.mask = (np.abs(raw["normal"][0] + 1.0).max(axis=-1) > 0).astype(np.float32)
        out.mask_source = "normal" if not out.mask.all() else "none"
    else:
        out.mask = np.ones((h, w), np.float32)
    valid = out.mask > 0.5
    if "normal" in raw:
        out.normal = _unit_normals(*raw["normal"], valid, paths["normal"])
    for kind in ("albedo", "roughness", "metallic"):
        if kind in raw:
            setattr(out, kind, _clip01(raw[kind][0], kind, paths[kind], valid, out.warnings))
    if "depth" in raw:
        d = raw["depth"][0]
        bad = valid & ~((d > 0) & np.isfinite(d))
        if bad.any():
            r, c = (int(v) for v in np.argwhere(bad)[0])
            raise ValueError(
                f"{paths['depth']}: depth must be finite and > 0 inside the mask; {int(bad.sum())} pixel(s) are not "
                f"(first at row {r}, col {c}: {float(d[r, c]):g})"
            )
        out.depth = d
    return out


# --------------------------------------------------------------------------- camera frustum


@dataclass(frozen=True)
class Frustum:
    """A pinhole camera's image rectangle at unit distance (camera frame: x right, y up, looking down -z).

    Attributes:
        width: image columns W.
        height: image rows H.
        half_width: half the rectangle's width at ``z = -1``.
        half_height: half its height at ``z = -1``.
        center_x: rectangle centre x at ``z = -1`` (lens shift).
        center_y: rectangle centre y at ``z = -1``.
    """

    width: int
    height: int
    half_width: float
    half_height: float
    center_x: float = 0.0
    center_y: float = 0.0

    def intrinsics(self) -> NDArray[np.float64]:
        """Pinhole matrix ``K (3, 3)`` of this frustum (:mod:`pbrdf.sensor.projection` convention)."""
        fx = self.width / (2.0 * self.half_width)
        fy = self.height / (2.0 * self.half_height)
        return np.array(
            [
                [fx, 0.0, self.width / 2 - self.center_x * fx],
                [0.0, fy, self.height / 2 + self.center_y * fy],
                [0, 0, 1.0],
            ]
        )

    def pixel_xy(self) -> NDArray[np.float64]:
        """``(H, W, 2)`` x, y of every pixel centre at ``z = -1`` (row 0 at the top)."""
        return projection.pixel_rays(self.intrinsics(), self.height, self.width)[..., :2]

    def project(self, points: NDArray) -> NDArray[np.float64]:
        """Continuous pixel coordinates ``(..., 2)`` = (u right, v down) of camera-frame points ``(..., 3)``.

        Points must lie in front of the camera (``z < 0``); others give NaN.
        """
        return projection.camera_to_pixel(points, self.intrinsics())[0]


def blender_frustum(
    width: int,
    height: int,
    *,
    lens: float,
    sensor_width: float,
    sensor_height: float,
    sensor_fit: str = "AUTO",
    shift_x: float = 0.0,
    shift_y: float = 0.0,
) -> Frustum:
    """The frustum of a Blender perspective camera rendering ``width x height`` square pixels.

    Blender fits the sensor to one image axis: ``HORIZONTAL`` (sensor_width spans the width),
    ``VERTICAL`` (sensor_height spans the height), ``AUTO`` (sensor_width spans the larger axis).
    Lens shift is in units of the fitted axis.

    Args:
        width: image columns.
        height: image rows.
        lens: focal length in mm.
        sensor_width: mm.
        sensor_height: mm.
        sensor_fit: ``AUTO``, ``HORIZONTAL`` or ``VERTICAL``.
        shift_x: horizontal lens shift.
        shift_y: vertical lens shift.
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    if not (lens > 0 and sensor_width > 0 and sensor_height > 0):
        raise ValueError(f"lens and sensor must be positive, got lens {lens}, sensor {sensor_width} x {sensor_height}")
    if sensor_fit == "AUTO":
        sensor_fit = "HORIZONTAL" if width >= height else "VERTICAL"
        sensor_height = sensor_width
    if sensor_fit == "HORIZONTAL":
        hw = 0.5 * sensor_width / lens
        hh = hw * height / width
        fitted = 2.0 * hw
    elif sensor_fit == "VERTICAL":
        hh = 0.5 * sensor_height / lens
        hw = hh * width / height
        fitted = 2.0 * hh
    else:
        raise ValueError(f"unknown sensor_fit {sensor_fit!r}; valid: AUTO, HORIZONTAL, VERTICAL")
    return Frustum(int(width), int(height), hw, hh, shift_x * fitted, shift_y * fitted)


def depth_mesh(
    depth: NDArray, valid: NDArray, frustum: Frustum, *, max_jump: float = 0.05
) -> tuple[NDArray, NDArray, NDArray]:
    """A camera-frame triangle mesh with one vertex per valid pixel centre, displaced to its depth.

    Two triangles per 2x2 block of valid pixels (one where three are valid), none across depth
    jumps larger than ``max_jump`` (relative), so silhouettes do not become skirts.

    Args:
        depth: ``(H, W)`` metres along the optical axis.
        valid: ``(H, W)`` bool.
        frustum: the camera's frustum (same size).
        max_jump: largest relative depth difference inside one triangle.

    Returns:
        ``(vertices (N, 3), faces (F, 3) counter-clockwise seen from the camera, uvs (N, 2))``;
        the UVs are the pixel centres (u right, v up, in [0, 1]), so a texture of the same size
        is sampled at its texel centres.
    """
    h, w = depth.shape
    if (frustum.height, frustum.width) != (h, w) or valid.shape != (h, w):
        raise ValueError(
            f"depth {depth.shape}, valid {valid.shape} and frustum {frustum.height}x{frustum.width} differ"
        )
    index = -np.ones((h, w), np.int64)
    index[valid] = np.arange(int(valid.sum()))
    xy = frustum.pixel_xy()
    d = depth.astype(np.float64)
    vertices = np.concatenate([xy[valid] * d[valid][:, None], -d[valid][:, None]], axis=1)
    rows, cols = np.nonzero(valid)
    uvs = np.stack([(cols + 0.5) / w, 1.0 - (rows + 0.5) / h], axis=1)
    # corners of each 2x2 block: a top-left, b top-right, c bottom-left, e bottom-right (image rows down)
    a, b, c, e = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    da, db, dc, de = d[:-1, :-1], d[:-1, 1:], d[1:, :-1], d[1:, 1:]
    ok = (a >= 0, b >= 0, c >= 0, e >= 0)
    n_ok = sum(o.astype(np.int8) for o in ok)
    # Seen from the camera (x right, y up) every triangle below is counter-clockwise. A full
    # block gets two triangles, a block with three valid pixels the triangle of those three.
    cases = (
        ((c, e, a), (dc, de, da), (n_ok == 4) | ((n_ok == 3) & ~ok[1])),
        ((e, b, a), (de, db, da), (n_ok == 4) | ((n_ok == 3) & ~ok[2])),
        ((c, e, b), (dc, de, db), (n_ok == 3) & ~ok[0]),
        ((c, b, a), (dc, db, da), (n_ok == 3) & ~ok[3]),
    )
    faces = []
    for tri, dd, use in cases:
        lo = np.minimum(np.minimum(dd[0], dd[1]), dd[2])
        hi = np.maximum(np.maximum(dd[0], dd[1]), dd[2])
        with np.errstate(invalid="ignore"):
            use = use & ((hi - lo) <= max_jump * lo)
        faces.append(np.stack([t[use] for t in tri], axis=1))
    faces_arr = np.concatenate(faces, axis=0)
    if not math.isfinite(float(vertices.sum())):
        raise ValueError("depth mesh has non-finite vertices")
    return vertices, faces_arr, uvs
