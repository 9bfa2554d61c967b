"""PBR map files as arrays: reading image channels, picking each map's channels, validation.

:func:`load_maps` reads the files matched by :func:`.map_names.match_map_files` (or given as
``{kind: file}``) and validates them into :class:`PBRMaps`; the add-on (``pbr_import.py``,
``bake.py``) turns those into Blender images. EXR channels are named as the network writes them
(``normal.X/Y/Z``, ``albedo.R/G/B``, ``roughness.Y``, ``metallic.Y``, ``mask.Y``, ``depth.Y``);
other names are recognised where unambiguous.

Convention (maps, as in docs/ARCHITECTURE.md):
    Images ``(H, W, C)`` float32, row 0 at the top. Normals in the camera frame, OpenGL
    convention (x right, y up, z toward the camera), unit length; EXR files hold them raw
    (``[-1, 1]``), 8/16-bit files encoded as ``0.5 + 0.5 n``. Albedo linear RGB in [0, 1] (PNG/JPEG
    albedo is sRGB-encoded unless told otherwise). Roughness, metallic, mask in [0, 1]. Depth: EXR
    only, metres along the optical axis (positive in front of the camera, as Blender's Z pass).
    Example: an 8-bit normal pixel ``(128, 128, 255)`` decodes to about ``(0.004, 0.004, 1)``
    and is renormalised to unit length.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pbrdf.data.predictions import MAP_NAMES
from pbrdf.geometry.relief import dilate, extend_maps

from .map_names import IMAGE_SUFFIXES, MapFiles, filename_tokens, match_kinds

__all__ = [
    "PBRMaps",
    "Reader",
    "dilate",  # pbrdf.geometry.relief.dilate, named here for the import and its tests
    "extend_past_mask",
    "load_map",
    "load_maps",
    "read_channels",
    "srgb_to_linear",
]

# Component names accepted for 3-vector maps in EXR files, and channel names tried for scalars.
_VECTOR_COMPONENTS = (("X", "Y", "Z"), ("R", "G", "B"))
_SCALAR_COMPONENTS = ("Y", "V", "Z", "R", "X", "A")
# |‖n‖ - 1| allowed before renormalising: float files are normalised by the writer; 8-bit
# encoding moves each component by up to 1/255 (|‖n‖ - 1| <= 0.007), tools add a bit more.
_UNIT_TOL = {"float": 1e-2, "int": 5e-2}
_RANGE_SLACK = 1e-3  # values this far outside [0, 1] are clipped silently; further ones are reported


def srgb_to_linear(x: NDArray) -> NDArray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), elementwise on values in [0, 1].

    Example:
        >>> round(float(srgb_to_linear(128 / 255)), 5)  # mid-grey 8-bit value
        0.21586
    """
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
        kind: one of :data:`pbrdf.data.predictions.MAP_NAMES`.
        srgb: decode sRGB (albedo only); None = for 8/16-bit files, not for EXR.
        reader: reads the file's channels; default :func:`read_channels`.

    Returns:
        ``(array, is_float)``: ``(H, W, 3)`` for normal (still raw: EXR values as stored, integer
        files decoded from ``0.5 + 0.5 n``) and albedo, ``(H, W)`` otherwise.

    Raises:
        ValueError: unknown kind, channels that cannot be told apart, NaN/Inf, a non-EXR depth map.
    """
    if kind not in MAP_NAMES:
        raise ValueError(f"unknown map kind {kind!r}; valid: {list(MAP_NAMES)}")
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
            k for k in MAP_NAMES if (self.mask_source == "file" if k == "mask" else getattr(self, k) is not None)
        )


def extend_past_mask(maps: PBRMaps, rings: int = 2, *, max_step: float = 0.04, tile: int = 32) -> PBRMaps:
    """A copy of ``maps`` whose normal, albedo, roughness, metallic and depth go on ``rings`` pixels past the mask.

    :func:`pbrdf.geometry.relief.extend_maps` (which says how and why); the mask is unchanged.
    Only pixels within ``rings`` of the mask change, each from values within ``2 * rings`` of it,
    so only the ``tile`` x ``tile`` tiles holding such pixels are extended (with that margin), in
    one call: a capture's outline is a few thousand of its million pixels. The result is
    :func:`~pbrdf.geometry.relief.extend_maps` over the whole frame, value for value (tested). The
    import needs this at the outline: with the maps extended, the relief mesh reaches past the
    outline (as a continuation of the surface, not a shelf that the edge would see and reflect)
    and the mask, as alpha, cuts it where the mask's pixels end.

    Example:
        >>> m = PBRMaps(mask=np.array([[0, 1, 1, 0]], np.float32), albedo=np.array([[[0, 0, 0], [0.5, 0.5, 0.5],
        ...             [0.3, 0.3, 0.3], [0, 0, 0]]], np.float32), depth=np.array([[0, 2.0, 2.01, np.inf]], np.float32))
        >>> e = extend_past_mask(m, 1)
        >>> e.albedo[0, :, 0].round(3).tolist(), e.depth[0].round(3).tolist(), e.mask[0].tolist()
        ([0.5, 0.5, 0.3, 0.3], [1.99, 2.0, 2.01, 2.02], [0.0, 1.0, 1.0, 0.0])
    """
    arrays = {k: getattr(maps, k) for k in ("normal", "albedo", "roughness", "metallic", "depth")}
    arrays = {k: v for k, v in arrays.items() if v is not None}
    valid = maps.valid
    if valid.all() or not valid.any() or not arrays:
        return replace(maps, **extend_maps(arrays, valid, rings, max_step=max_step))
    (h, w), halo = valid.shape, 2 * rings
    changed = dilate(valid, rings) & ~valid
    rows, cols = -(-h // tile), -(-w // tile)
    grid = np.zeros((rows * tile, cols * tile), bool)
    grid[:h, :w] = changed
    tiles = np.argwhere(grid.reshape(rows, tile, cols, tile).any(axis=(1, 3))) * tile
    # A window is a tile and its margin. Windows inside the frame are stacked in one column and extended in
    # one call (a tile never reaches a neighbour's); one crossing the frame's edge is cut there and extended
    # alone, since past the frame nothing may be filled (extend_maps' own border).
    inner = (tiles >= halo).all(axis=1) & (tiles[:, 0] + tile + halo <= h) & (tiles[:, 1] + tile + halo <= w)
    out = {
        k: np.where(valid.reshape(h, w, *([1] * (v.ndim - 2))), v, 0.0).astype(np.float32) for k, v in arrays.items()
    }
    side = tile + 2 * halo
    if inner.any():
        windows = [np.s_[y - halo : y + tile + halo, x - halo : x + tile + halo] for y, x in tiles[inner]]
        stacked = extend_maps({k: np.concatenate([v[s] for s in windows]) for k, v in arrays.items()},
                              np.concatenate([valid[s] for s in windows]), rings, max_step=max_step)  # fmt: skip
        for i, (y, x) in enumerate(tiles[inner]):
            for k, v in stacked.items():
                out[k][y : y + tile, x : x + tile] = v[i * side + halo : i * side + halo + tile, halo : halo + tile]
    for y, x in tiles[~inner]:
        y0, x0 = max(y - halo, 0), max(x - halo, 0)
        window = np.s_[y0 : y + tile + halo, x0 : x + tile + halo]
        alone = extend_maps({k: v[window] for k, v in arrays.items()}, valid[window], rings, max_step=max_step)
        for k, v in alone.items():
            out[k][y : y + tile, x : x + tile] = v[y - y0 : y - y0 + tile, x - x0 : x - x0 + tile]
    return replace(maps, **out)


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
