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
      ``uv' = T(offset) R(rotation) S(scale) uv``. :meth:`TextureSpec.uv_matrix` gives the same
      map in OpenGL UVs.
    * Values: colour images are decoded from sRGB to linear when ``colorspace`` is ``"srgb"``;
      data (roughness, metallic, normals, weights) is read as stored (``"linear"``). The value of
      the quantity is ``factor * image[..., channels]``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .spec_lights import _check_keys

__all__ = ["COLORSPACES", "MAX_TABLES", "PROCEDURAL_PREFIX", "MaterialTextures", "TextureSpec", "texture_array"]

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
            one number per channel.
        colorspace: ``"srgb"`` (colour images, decoded to linear) or ``"linear"`` (data).
        offset, rotation, scale: ``KHR_texture_transform`` (rotation in radians).
        params: the procedural pattern's parameters (JSON values); empty for a file.
    """

    source: str
    channels: tuple[int, ...] = (0, 1, 2)
    factor: tuple[float, ...] = (1.0, 1.0, 1.0)
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
        put(self, "factor", _floats(self.factor, len(channels), f"{where}: factor"))
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
        gltf = gltf @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float64)  # the spec's column-major mat3
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


def texture_array(tex: TextureSpec) -> NDArray[np.float32]:
    """The quantity's values over the image: ``factor * image[..., channels]``, linear, row 0 at the top.

    Files are read with :func:`.map_io.read_channels` (PNG/JPEG scaled to [0, 1], EXR as stored);
    a grey image serves every channel, and a missing alpha channel reads as 1.

    Returns:
        ``(H, W, len(channels))`` float32.

    Raises:
        FileNotFoundError: no such file.
        ValueError: unreadable file, or a procedural source (not built yet).
    """
    from . import map_io  # noqa: PLC0415

    if tex.procedural:
        raise ValueError(f"texture {tex.source!r}: procedural textures are not available yet")
    chans, is_float = map_io.read_channels(tex.source)
    names = list(chans)
    if set("RGB") <= set(names):
        order = [chans["R"], chans["G"], chans["B"], chans.get("A")]
    else:
        grey = chans.get("Y", next(iter(chans.values())))
        order = [grey, grey, grey, chans.get("A")]
    planes = [order[c] if order[c] is not None else np.ones_like(order[0]) for c in tex.channels]
    img = np.stack(planes, axis=-1).astype(np.float32)
    if tex.colorspace == "srgb" and not is_float:
        img = map_io.srgb_to_linear(img)
    return (img * np.asarray(tex.factor, np.float32)).astype(np.float32)
