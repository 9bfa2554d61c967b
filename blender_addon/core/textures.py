"""Textures of a spatially varying material: what is looked up where, renderer-agnostic.

A :class:`TextureSpec` names an image (a file, or a seeded procedural pattern that is rebuilt
exactly from its parameters), the channels of it that hold the quantity, a per-channel factor
and glTF's ``KHR_texture_transform``. :class:`MaterialTextures` groups the textures of one
material (:class:`blender_addon.core.spec.MaterialSpec` ``textures``): base colour, roughness,
metallic, a tangent-space normal map with its scale, and for pBRDF tables a per-texel convex
mixture of up to :data:`MAX_TABLES` tables.

Conventions:
    * UVs are OpenGL's (what trimesh and Blender hold): ``(0, 0)`` the bottom-left corner of the
      image, ``v`` up. Image arrays have row 0 at the top, so texel ``(u, v)`` is at column
      ``u W`` and row ``(1 - v) H``; UVs wrap (glTF's default ``REPEAT``).
    * ``KHR_texture_transform`` is defined in glTF's UV space (``v`` down):
      ``uv' = T(offset) R(rotation) S(scale) uv`` with ``R = [[cos, sin], [-sin, cos]]``, the
      sign Blender's importer, three.js and Babylon use (the extension README's GLSL listing is
      transposed: KhronosGroup/glTF issue #1563). :meth:`TextureSpec.uv_matrix` gives the same
      map in OpenGL UVs.
    * Values: colour images are decoded from sRGB to linear when ``colorspace`` is ``"srgb"``;
      data (roughness, metallic, normals, weights) is read as stored (``"linear"``). The value of
      the quantity is ``factor * image[..., channels]``.
"""

from __future__ import annotations

import functools
import json
import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from pbrdf.io.errors import one_line

from .map_io import srgb_to_linear
from .spec_lights import _check_keys
from .texture_patterns import pattern_array

__all__ = [
    "CACHE_BYTES",
    "CACHE_ENTRIES",
    "COLORSPACES",
    "MAX_TABLES",
    "PROCEDURAL_PREFIX",
    "MaterialTextures",
    "TextureNotFoundError",
    "TextureSpec",
    "clear_texture_cache",
    "texture_array",
    "texture_mean",
    "texture_size_for",
]

#: How an image's values become the quantity's: sRGB-encoded colour, or linear data.
COLORSPACES = ("srgb", "linear")
#: Most pBRDF tables one textured table material mixes.
MAX_TABLES = 4
#: ``source`` prefix of a procedural pattern (``procedural:<pattern>``).
PROCEDURAL_PREFIX = "procedural:"


def _floats(value: Any, n: int, where: str) -> tuple[float, ...]:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected {n} numbers, got {value!r}") from None
    if a.size == 1 and n > 1:
        a = np.repeat(a, n)
    if a.size != n or not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: expected {n} finite numbers, got {value!r}")
    return tuple(float(x) for x in a)


@dataclass(frozen=True)
class TextureSpec:
    """One image looked up at an object's UVs.

    Attributes:
        source: an image file (PNG, JPEG, EXR) or ``procedural:<pattern>`` (rebuilt from
            ``params``, which then hold at least its ``seed``).
        channels: the image channels that hold the quantity (``(0, 1, 2)`` for a colour,
            ``(1,)`` for glTF's roughness in G, ``(2,)`` for its metallic in B).
        factor: multiplies the channels (glTF's ``baseColorFactor``, ``roughnessFactor``, ...);
            one number per channel, or one for all; default 1.
        colorspace: ``"srgb"`` (colour images, decoded to linear) or ``"linear"`` (data).
        offset, rotation, scale: ``KHR_texture_transform`` (rotation in radians).
        params: the procedural pattern's parameters (JSON values); empty for a file.
    """

    source: str
    channels: tuple[int, ...] = (0, 1, 2)
    factor: tuple[float, ...] | None = None
    colorspace: str = "linear"
    offset: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0
    scale: tuple[float, float] = (1.0, 1.0)
    params: dict | None = None

    def __post_init__(self) -> None:
        put = object.__setattr__
        if isinstance(self.source, os.PathLike):
            put(self, "source", os.fspath(self.source))
        if not isinstance(self.source, str) or not self.source:
            raise ValueError(f"texture source must be a file or {PROCEDURAL_PREFIX}<pattern>, got {self.source!r}")
        where = f"texture {self.source!r}"
        try:
            channels = tuple(int(c) for c in self.channels)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: channels must be integers, got {self.channels!r}") from None
        if not 1 <= len(channels) <= 4 or not all(0 <= c < 4 for c in channels):
            raise ValueError(f"{where}: channels must be 1 to 4 indices in 0..3, got {self.channels!r}")
        put(self, "channels", channels)
        put(self, "factor", _floats(1.0 if self.factor is None else self.factor, len(channels), f"{where}: factor"))
        if self.colorspace not in COLORSPACES:
            raise ValueError(f"{where}: colorspace must be one of {list(COLORSPACES)}, got {self.colorspace!r}")
        put(self, "offset", _floats(self.offset, 2, f"{where}: offset"))
        put(self, "rotation", _floats(self.rotation, 1, f"{where}: rotation")[0])
        put(self, "scale", _floats(self.scale, 2, f"{where}: scale"))
        if self.params is not None and not isinstance(self.params, dict):
            raise ValueError(f"{where}: params must be a JSON object, got {type(self.params).__name__}")
        if self.params is not None:
            try:  # through JSON, so that a round trip is exact (tuples become lists)
                put(self, "params", json.loads(json.dumps(self.params, allow_nan=False)))
            except (TypeError, ValueError) as e:
                raise ValueError(f"{where}: params must be JSON-serialisable: {e}") from None
        if self.procedural and "seed" not in (self.params or {}):
            raise ValueError(f"{where}: a procedural texture needs params with its 'seed'")

    def __hash__(self) -> int:  # params is a dict: hash the JSON form
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    @property
    def procedural(self) -> bool:
        """Whether the image is a seeded procedural pattern (else a file)."""
        return self.source.startswith(PROCEDURAL_PREFIX)

    def uv_matrix(self) -> NDArray[np.float64]:
        """``KHR_texture_transform`` as a 3x3 matrix acting on OpenGL UVs ``(u, v, 1)``.

        Example:
            >>> m = TextureSpec("a.png", offset=(0.5, 0.25)).uv_matrix()
            >>> (m @ [0.0, 1.0, 1.0]).round(6).tolist()  # glTF's (0, 0) is OpenGL's (0, 1)
            [0.5, 0.75, 1.0]
        """
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        gltf = np.array([[1, 0, self.offset[0]], [0, 1, self.offset[1]], [0, 0, 1]], np.float64)
        gltf = gltf @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], np.float64)  # glTF issue #1563
        gltf = gltf @ np.diag([self.scale[0], self.scale[1], 1.0])
        flip = np.array([[1, 0, 0], [0, -1, 1], [0, 0, 1]], np.float64)  # v -> 1 - v, its own inverse
        return flip @ gltf @ flip

    def to_dict(self) -> dict:
        """JSON-friendly dict (defaults left out)."""
        d: dict[str, Any] = {"source": self.source, "channels": list(self.channels), "factor": list(self.factor)}
        if self.colorspace != "linear":
            d["colorspace"] = self.colorspace
        if self.offset != (0.0, 0.0) or self.rotation != 0.0 or self.scale != (1.0, 1.0):
            d.update(offset=list(self.offset), rotation=self.rotation, scale=list(self.scale))
        if self.params:
            d["params"] = dict(self.params)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TextureSpec:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError."""
        _check_keys(d, "texture", ("source",), ("channels", "factor", "colorspace", "offset", "rotation", "scale",
                                                 "params"))  # fmt: skip
        return cls(**d)


_SLOTS = ("albedo", "roughness", "metallic", "normal", "weights")
_CHANNELS = {"albedo": 3, "roughness": 1, "metallic": 1, "normal": 3}


@dataclass(frozen=True)
class MaterialTextures:
    """The textures of one material; a slot left None keeps the material's constant.

    Attributes:
        albedo: base colour (3 channels, linear after decoding).
        roughness: Disney roughness (1 channel).
        metallic: Disney metallic (1 channel); a dielectric and a metal mixed per texel.
        normal: tangent-space normal map (3 channels in [0, 1], ``n = 2 c - 1``; OpenGL's +y).
        normal_scale: glTF's ``normalTexture.scale`` (scales the map's x and y).
        tables: ``measured`` only: the pBRDF tables mixed after the material's own ``table``.
        weights: ``measured`` with ``tables``: one channel per extra table; the own table's
            weight is one minus their sum (clipped, so every texel's mix is convex).
    """

    albedo: TextureSpec | None = None
    roughness: TextureSpec | None = None
    metallic: TextureSpec | None = None
    normal: TextureSpec | None = None
    normal_scale: float = 1.0
    tables: tuple[str, ...] = ()
    weights: TextureSpec | None = None

    def __post_init__(self) -> None:
        for slot in _SLOTS:
            t = getattr(self, slot)
            if t is not None and not isinstance(t, TextureSpec):
                raise ValueError(f"textures: {slot} must be a TextureSpec or None, got {type(t).__name__}")
            if t is not None and slot in _CHANNELS and len(t.channels) != _CHANNELS[slot]:
                raise ValueError(f"textures: {slot} needs {_CHANNELS[slot]} channel(s), got {list(t.channels)}")
        scale = _floats(self.normal_scale, 1, "textures: normal_scale")[0]
        object.__setattr__(self, "normal_scale", scale)
        if isinstance(self.tables, (str, bytes)):
            raise ValueError(f"textures: tables must be a list of table paths, got {self.tables!r}")
        tables = tuple(os.fspath(t) for t in self.tables)
        if not all(isinstance(t, str) and t for t in tables):
            raise ValueError(f"textures: tables must be non-empty paths, got {list(self.tables)}")
        object.__setattr__(self, "tables", tables)
        if len(tables) + 1 > MAX_TABLES:
            raise ValueError(f"textures: at most {MAX_TABLES} tables per material, got {len(tables) + 1}")
        if bool(tables) != (self.weights is not None):
            raise ValueError("textures: tables and weights go together (one weight channel per extra table)")
        if self.weights is not None and len(self.weights.channels) != len(tables):
            raise ValueError(f"textures: weights needs {len(tables)} channel(s), one per extra table, "
                             f"got {list(self.weights.channels)}")  # fmt: skip

    def slots(self) -> dict[str, TextureSpec]:
        """The textures present, by slot name."""
        return {s: getattr(self, s) for s in _SLOTS if getattr(self, s) is not None}

    def to_dict(self) -> dict:
        """JSON-friendly dict (empty slots left out)."""
        d: dict[str, Any] = {s: t.to_dict() for s, t in self.slots().items()}
        if self.normal_scale != 1.0:
            d["normal_scale"] = self.normal_scale
        if self.tables:
            d["tables"] = list(self.tables)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> MaterialTextures:
        """Inverse of :meth:`to_dict`; unknown keys raise ValueError."""
        _check_keys(d, "textures", (), (*_SLOTS, "normal_scale", "tables"))
        kw = {k: (TextureSpec.from_dict(v) if k in _SLOTS else v) for k, v in d.items()}
        if "tables" in kw:
            kw["tables"] = tuple(kw["tables"])
        return cls(**kw)


class TextureNotFoundError(FileNotFoundError, ValueError):
    """A texture file that does not exist: a ``FileNotFoundError`` and, as all bad texture input, a ``ValueError``."""


class _Image(NamedTuple):
    """A decoded source before channel selection.

    pixels: ``(H, W, K)`` uint8 / uint16 (integer-coded, scaled to [0, 1] by the type's maximum)
        or float32 (as stored). bands: ``"L"``, ``"LA"``, ``"RGB"``, ``"RGBA"`` (which image
        channel is which), or ``""`` for channels picked by index. encoded: whether ``"srgb"``
        decoding applies (integer files and procedural patterns; EXR floats are linear).
    """

    pixels: NDArray
    bands: str
    encoded: bool


#: Decoded textures kept for reuse by a dataset run: entries, and bytes in all.
CACHE_ENTRIES = 16
CACHE_BYTES = 512 * 2**20
_cache: OrderedDict[tuple, NDArray[np.float32]] = OrderedDict()
_cache_lock = threading.Lock()
# Pillow modes converted before reading, by the mode they become (paletted, bilevel, other colour models).
_CONVERT = {"1": "L", "P": "RGB", "PA": "RGBA", "La": "LA", "RGBa": "RGBA", "CMYK": "RGB", "YCbCr": "RGB",
            "LAB": "RGB", "HSV": "RGB", "RGBX": "RGB"}  # fmt: skip


def texture_size_for(resolution: int, coverage: float = 1.0, *, texels_per_pixel: float = 2.0) -> int:
    """The texture side that a render can show: ``texels_per_pixel`` texels per rendered pixel.

    A pixel averages the texture over its footprint, so detail finer than about two texels per
    pixel (the Nyquist rate of the pixel grid) is averaged away in the image and in its
    ground truth alike; a larger texture only costs memory and time. ``coverage`` is the fraction
    of the image's longer side the texture's UV square spans (1: the whole frame, the safe
    bound for a single object). A texture atlas whose parts use a fraction ``f`` of the UV square
    needs ``1 / f`` times more: pass ``coverage / f``; a texture repeated ``s`` times (UV scale)
    needs ``1 / s``.

    Args:
        resolution: the render's longer side in pixels.
        coverage: see above, > 0.
        texels_per_pixel: texels kept per pixel of the texture's footprint.

    Returns:
        The largest texture side worth keeping (at least 8): ``max_size`` for :func:`texture_array`.

    Example:
        >>> texture_size_for(384), texture_size_for(384, 0.5)
        (768, 384)
    """
    if not resolution > 0 or not coverage > 0 or not texels_per_pixel > 0:
        raise ValueError(f"resolution, coverage and texels_per_pixel must be > 0, got {resolution}, {coverage}, "
                         f"{texels_per_pixel}")  # fmt: skip
    return max(8, math.ceil(texels_per_pixel * resolution * coverage))


def texture_array(tex: TextureSpec, *, max_size: int | None = None) -> NDArray[np.float32]:
    """The quantity's values over the image: ``factor * image[..., channels]``, linear, row 0 at the top.

    Sources (one dispatch, :func:`_read_source`): PNG, JPEG and whatever else Pillow reads
    (8-bit values / 255, 16-bit grey / 65535; paletted, bilevel and CMYK images converted to RGB(A);
    Pillow reads 16-bit colour PNGs at 8-bit precision), EXR (floats as stored, never sRGB-decoded;
    NaN or Inf refused), and ``procedural:<pattern>`` (:mod:`.texture_patterns`, treated as an
    8-bit image's values). Channels: ``0, 1, 2`` are R, G, B (a grey image serves all three);
    ``3`` is alpha, 1.0 (opaque) where the image has none. ``"srgb"`` decodes the colour channels
    only, never alpha. An image declaring more pixels than
    :func:`pbrdf.data.raw_files.max_raw_pixels` is refused before its pixels are decoded.

    Decoded arrays are cached (:data:`CACHE_ENTRIES`, :data:`CACHE_BYTES`, least recently used
    dropped), keyed by the source, the file's modification time and size, the channels, the
    colour space and ``max_size``: samples of a dataset run reuse them.

    Args:
        tex: the texture.
        max_size: the longest side kept (:func:`texture_size_for`); a larger image is reduced by
            area averaging (a box filter over the exact texel footprints, on linear values, so the
            mean is kept), its longer side to ``max_size`` and the other in proportion. None keeps
            the full size.

    Returns:
        ``(H, W, len(channels))`` float32.

    Raises:
        TextureNotFoundError: no such file (a ``FileNotFoundError`` and a ``ValueError``).
        ValueError: one line naming the source and the reason: unreadable, truncated, too large,
            non-finite values, a channel a procedural pattern lacks, an unknown pattern.

    Example:
        >>> p = {"seed": 0, "size": 8, "cells": 4}
        >>> t = TextureSpec("procedural:checker", channels=(0,), factor=(1.0,), params=p)
        >>> texture_array(t, max_size=4)[..., 0].tolist()[0]  # a 2x2-texel checker halved exactly
        [0.0, 1.0, 0.0, 1.0]
    """
    if max_size is not None and (isinstance(max_size, bool) or not isinstance(max_size, int) or max_size < 1):
        raise ValueError(f"max_size must be a positive integer or None, got {max_size!r}")
    key = (_stamp(tex), tex.channels, tex.colorspace, max_size)
    with _cache_lock:
        img = _cache.get(key)
        if img is not None:
            _cache.move_to_end(key)
    if img is None:
        img = _decode(tex, max_size)
        img.setflags(write=False)  # shared by every caller of the cache
        _remember(key, img)
    return img * np.asarray(tex.factor, np.float32)


def texture_mean(tex: TextureSpec) -> tuple[float, ...]:
    """The texture's mean value per channel (a textured material's constant, e.g. its albedo).

    Example:
        >>> t = TextureSpec("procedural:checker", channels=(0,), factor=(0.5,), params={"seed": 0, "size": 64})
        >>> texture_mean(t)
        (0.25,)
    """
    return tuple(float(m) for m in texture_array(tex, max_size=64).mean(axis=(0, 1), dtype=np.float64))


def clear_texture_cache() -> None:
    """Forget every cached texture (a test, or a caller freeing memory)."""
    with _cache_lock:
        _cache.clear()


def _remember(key: tuple, img: NDArray) -> None:
    if img.nbytes > CACHE_BYTES:
        return
    with _cache_lock:
        _cache[key] = img
        while len(_cache) > CACHE_ENTRIES or sum(a.nbytes for a in _cache.values()) > CACHE_BYTES:
            _cache.popitem(last=False)


def _split_source(source: str) -> tuple[str, str | None]:
    """``(file, fragment)``: ``"model.glb#image=3"`` names an image inside a file."""
    path, sep, fragment = source.rpartition("#")
    if not sep or not path or os.path.exists(source):  # a file whose name holds '#' stays a file
        return source, None
    return path, fragment


def _stamp(tex: TextureSpec) -> tuple:
    """What identifies the source's content: the pattern and its params, or the file and its mtime/size."""
    if tex.procedural:
        return (tex.source, json.dumps(tex.params, sort_keys=True))
    path, fragment = _split_source(tex.source)
    try:
        st = os.stat(path)
    except OSError:
        return (tex.source, None)  # reading it reports why
    return (tex.source, fragment, st.st_mtime_ns, st.st_size)


def _read_source(tex: TextureSpec) -> _Image:
    """The one dispatch on a texture's source: a procedural pattern, an image inside a file, a file."""
    if tex.procedural:
        try:
            arr = pattern_array(tex.source[len(PROCEDURAL_PREFIX) :], tex.params or {})
        except ValueError as e:
            raise ValueError(f"texture {tex.source!r}: {e}") from None
        return _Image(arr, {1: "L", 3: "RGB", 4: "RGBA"}.get(arr.shape[-1], ""), True)
    path, fragment = _split_source(tex.source)
    if fragment is not None:
        return _read_embedded(Path(path), fragment)
    return _read_file(Path(path))


def _read_embedded(path: Path, fragment: str) -> _Image:
    """Hook for images inside a file (``model.glb#image=3``): not supported yet."""
    raise ValueError(f"{path}#{fragment}: images embedded in a file are not supported yet")


def _read_file(path: Path) -> _Image:
    if not path.is_file():
        if path.exists():
            raise ValueError(f"{path}: texture is not a file")
        raise TextureNotFoundError(f"{path}: texture file not found")
    if path.suffix.lower() == ".exr":
        return _read_exr(path)
    from PIL import Image, UnidentifiedImageError  # noqa: PLC0415

    from pbrdf.data.raw_files import open_image  # noqa: PLC0415

    try:
        im = open_image(path, "texture")  # an image bomb: refused from its header, one line naming the file
    except UnidentifiedImageError:
        raise ValueError(f"{path}: not a readable image (unknown format)") from None
    except OSError as e:
        raise ValueError(f"{path}: cannot read texture ({one_line(e)})") from None
    with im:
        try:
            im.load()
        except (OSError, SyntaxError, ValueError, EOFError, Image.DecompressionBombError) as e:
            raise ValueError(f"{path}: cannot read texture ({one_line(e)})") from None  # truncated, corrupt
        return _pillow_pixels(path, im)


def _pillow_pixels(path: Path, im) -> _Image:
    """A loaded Pillow image as stored values: 8/16-bit integers, or floats; other modes converted."""
    mode = im.mode
    if mode in ("F", "L", "LA", "RGB", "RGBA") or mode.startswith("I;16") or mode == "I":
        if "transparency" in im.info and mode in ("L", "RGB"):  # a tRNS colour key: make it alpha
            mode = mode + "A" if mode == "L" else "RGBA"
            return _Image(np.asarray(im.convert(mode)), mode, True)
        arr = np.asarray(im)
    else:  # paletted, bilevel, CMYK, ...: converted (a palette keeps its transparency as alpha)
        has_alpha = "A" in mode or "transparency" in im.info
        target = _CONVERT.get(mode, "RGB")
        target = {"L": "LA", "RGB": "RGBA"}.get(target, target) if has_alpha else target
        return _Image(np.asarray(im.convert(target)), target, True)
    if mode == "F":  # a float image (TIFF): linear values, like EXR
        return _checked_float(path, arr[..., None].astype(np.float32), "L")
    if mode.startswith("I"):  # 16-bit (or 32-bit integer) grey
        if arr.size and (arr.min() < 0 or arr.max() > 65535):
            raise ValueError(f"{path}: integer texture values outside 0..65535 (mode {mode})")
        return _Image(arr.astype(np.uint16)[..., None], "L", True)
    return _Image(arr.reshape(*arr.shape[:2], -1), mode, True)


def _read_exr(path: Path) -> _Image:
    from pbrdf.data.raw_files import max_raw_pixels  # noqa: PLC0415

    try:
        from pbrdf.io.exr import read_exr, read_exr_header  # noqa: PLC0415
    except ImportError as e:  # Blender's bundled Python lacks OpenEXR
        raise ValueError(f"{path}: reading EXR textures needs the OpenEXR package ({e})") from None
    head = read_exr_header(path)
    if head["width"] * head["height"] > max_raw_pixels():
        raise ValueError(f"{path}: texture image too large to read ({head['width']}x{head['height']} pixels)")
    chans = read_exr(path)
    comps: dict[str, list[str]] = {}
    for name in chans:
        comps.setdefault(name.rpartition(".")[2].upper(), []).append(name)
    pick = {c: names[0] for c, names in comps.items() if len(names) == 1}
    alpha = ["A"] if "A" in pick else []
    if all(c in pick for c in "RGB"):
        bands = ["R", "G", "B", *alpha]
    elif "Y" in pick or len(chans) == 1:
        bands = ["Y" if "Y" in pick else next(iter(comps)), *alpha]
    else:
        raise ValueError(f"{path}: cannot tell which EXR channels are R, G, B or Y; channels: {sorted(chans)}")
    arr = np.stack([np.asarray(chans[pick[c]], np.float32) for c in bands], axis=-1)
    return _checked_float(path, arr, {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}[len(bands)])


def _checked_float(path: Path, arr: NDArray, bands: str) -> _Image:
    bad = int(np.count_nonzero(~np.isfinite(arr)))
    if bad:
        raise ValueError(f"{path}: texture holds {bad} NaN/Inf value(s)")
    return _Image(arr, bands, False)


def _plane(image: _Image, c: int, where: str) -> int | None:
    """The image channel serving texture channel ``c``; None for a missing alpha (reads 1.0)."""
    bands = image.bands
    if bands:
        if c == 3:
            return bands.index("A") if "A" in bands else None
        return c if bands.startswith("RGB") else 0
    if c < image.pixels.shape[-1]:
        return c
    raise ValueError(f"{where}: has {image.pixels.shape[-1]} channel(s), no channel {c}")


def _decode(tex: TextureSpec, max_size: int | None) -> NDArray[np.float32]:
    """The selected channels, linear, area-averaged to ``max_size``; uncached, without factor."""
    image = _read_source(tex)
    planes = [_plane(image, c, f"texture {tex.source!r}") for c in tex.channels]
    decode = [tex.colorspace == "srgb" and image.encoded and c != 3 for c in tex.channels]

    def linear(rows: NDArray) -> NDArray[np.float32]:  # (h, W, K) stored values -> (h, W, C) linear
        out = np.empty(rows.shape[:2] + (len(planes),), np.float32)
        for i, (p, d) in enumerate(zip(planes, decode, strict=True)):
            out[..., i] = 1.0 if p is None else _to_linear(rows[..., p], d)
        return out

    h, w = image.pixels.shape[:2]
    if max_size is None or max(h, w) <= max_size:
        return linear(image.pixels)
    s = max_size / max(h, w)
    return _area_resample(image.pixels, linear, max(1, round(h * s)), max(1, round(w * s)))


def _to_linear(values: NDArray, srgb: bool) -> NDArray[np.float32]:
    """Stored values to linear floats: integers scaled by their maximum (a lookup table), sRGB decoded."""
    if values.dtype.kind == "f":
        return srgb_to_linear(np.clip(values, 0.0, 1.0)) if srgb else values.astype(np.float32)
    return _lut(np.iinfo(values.dtype).max, srgb)[values]


@functools.lru_cache(maxsize=4)
def _lut(top: int, srgb: bool) -> NDArray[np.float32]:
    """Linear value of every integer code ``0..top`` (8 or 16 bits)."""
    lut = np.arange(top + 1, dtype=np.float64) / top
    return srgb_to_linear(lut) if srgb else lut.astype(np.float32)


def _box_weights(n_in: int, n_out: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Area-averaging weights: output cell ``i`` covers input ``[i r, (i + 1) r)``, ``r = n_in / n_out``.

    Returns:
        ``(index, weight)``, each ``(n_out, k)``: output ``i`` is ``sum_j weight[i, j] * in[index[i, j]]``;
        each row of weights sums to 1 (the overlap of the input cell with the footprint, over ``r``).
    """
    r = n_in / n_out
    start = np.arange(n_out) * r
    index = np.floor(start).astype(np.int64)[:, None] + np.arange(math.ceil(r) + 1)
    overlap = np.minimum(start[:, None] + r, index + 1) - np.maximum(start[:, None], index)
    return np.minimum(index, n_in - 1), np.clip(overlap, 0.0, None) / r


def _area_resample(pixels: NDArray, linear, h_out: int, w_out: int) -> NDArray[np.float32]:
    """Box-filter ``pixels`` (stored values) to ``(h_out, w_out)`` in linear values, a strip of rows at a time.

    Only a strip of rows is converted to float at once: a large 8-bit image never exists as floats.
    """
    h, w = pixels.shape[:2]
    ri, rw = _box_weights(h, h_out)
    ci, cw = _box_weights(w, w_out)
    rw, cw = rw.astype(np.float32), cw.astype(np.float32)  # a few taps per sum: float32 keeps 1e-7
    block = max(1, 2**22 // (ri.shape[1] * w * pixels.shape[-1]))  # output rows per strip: ~4 M input values
    out = []
    for r0 in range(0, h_out, block):
        idx, wts = ri[r0 : r0 + block], rw[r0 : r0 + block]
        lo = int(idx.min())
        strip = linear(pixels[lo : int(idx.max()) + 1])
        rows = sum(wts[:, j, None, None] * strip[idx[:, j] - lo] for j in range(idx.shape[1]))
        out.append(sum(cw[None, :, j, None] * rows[:, ci[:, j]] for j in range(ci.shape[1])))
    return np.concatenate(out).astype(np.float32)
