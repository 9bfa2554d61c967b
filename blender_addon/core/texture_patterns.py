"""Seeded procedural textures: tileable noise, stripes, decals and labels, wear, material segments.

A pattern is rebuilt exactly from its parameters: ``TextureSpec("procedural:<pattern>",
params={"seed": ..., "size": ...})`` gives the same array through
:func:`.textures.texture_array` on every machine (numpy's PCG64 generator, no global state).
:func:`.random_textures.random_material_textures` draws such textures for an asset without
materials. Pure numpy: this module knows nothing of the texture specs that name it.

Convention:
    Every pattern is a square ``(size, size, C)`` float32 image with values in [0, 1], row 0 at
    the top, sampled at texel centres of the OpenGL UV square (``u`` right, ``v`` up), and tiles:
    the texel right of the last column is the first column (UVs wrap, glTF's ``REPEAT``), so a
    mesh whose UVs cross the border shows no seam. Stripes snap their wave vector to whole
    numbers of periods across the square for that reason. Example: ``stripes`` with ``angle=0``
    and ``period=0.25`` has four stripes across ``u``, constant along ``v``.

Patterns (:data:`PATTERNS`; parameters beyond ``seed`` and ``size`` are keyword defaults of
the functions named ``_<pattern>``):
    * ``noise``: fractal value noise (fBm), smooth (quintic interpolation, C2), rescaled to [0, 1].
    * ``stripes``: stripes of a given angle, period, duty cycle and soft edge.
    * ``decals``: a few rectangles and discs on a background; some rectangles are labels with
      rows of text-like bars.
    * ``wear``: a scratches/wear mask (1 = worn): anisotropic noise thresholded so that a given
      fraction is worn. Real edge wear follows the geometry's edges, which UV space does not know;
      this is the texture-space stand-in.
    * ``segments``: ``count`` regions (a warped Voronoi tiling of the torus); channel ``k - 1``
      is the weight of region ``k`` for ``k >= 1`` (region 0 takes one minus their sum), hard
      (one-hot) with ``softness=0``, blended across boundaries otherwise.
    * ``normal``: a tangent-space normal map (OpenGL: +y along +v) of a noise height field.
    * ``checker``: a checkerboard of ``cells`` squares per side.

``low`` and ``high`` (a number, or three for RGB) map a pattern's mask to its values.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["MAX_SIZE", "PATTERNS", "fbm_noise", "pattern_array", "segment_labels"]

#: Largest pattern side in texels (a 4096^2 RGB float32 pattern is 200 MB).
MAX_SIZE = 4096


def _grid(size: int) -> tuple[NDArray, NDArray]:
    """OpenGL UVs of the texel centres, ``(size, 1)`` v and ``(1, size)`` u."""
    c = (np.arange(size) + 0.5) / size
    return c[::-1, None], c[None, :]


def _fade(t: NDArray) -> NDArray:
    return t * t * t * (t * (6 * t - 15) + 10)  # quintic: C2 across lattice cells


def _value_octave(rng: np.random.Generator, size: int, cells_u: int, cells_v: int) -> NDArray:
    """One octave of periodic value noise: a ``cells_v x cells_u`` random lattice, interpolated."""
    lattice = rng.random((cells_v, cells_u))
    x = np.arange(size) * (cells_u / size)
    y = np.arange(size) * (cells_v / size)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = _fade(x - x0), _fade(y - y0)
    rows = lattice[y0 % cells_v] + fy[:, None] * (lattice[(y0 + 1) % cells_v] - lattice[y0 % cells_v])
    return rows[:, x0 % cells_u] + fx[None, :] * (rows[:, (x0 + 1) % cells_u] - rows[:, x0 % cells_u])


def fbm_noise(
    size: int, seed: int, *, base: int = 4, octaves: int = 4, persistence: float = 0.5, stretch: int = 1
) -> NDArray[np.float64]:
    """Tileable fractal value noise, rescaled to span [0, 1] exactly.

    Args:
        size: side in texels.
        seed: generator seed.
        base: lattice cells across ``u`` of the coarsest octave (an integer, so that it tiles).
        octaves: octaves summed, each with twice the cells and ``persistence`` times the amplitude.
        persistence: amplitude ratio of successive octaves, in (0, 1].
        stretch: features ``stretch`` times longer along ``u`` than along ``v`` (anisotropic noise).

    Returns:
        ``(size, size)`` float64 in [0, 1].

    Example:
        >>> n = fbm_noise(32, seed=1)
        >>> n.shape, float(n.min()), float(n.max())
        ((32, 32), 0.0, 1.0)
    """
    rng = np.random.default_rng(seed)
    total = np.zeros((size, size))
    for o in range(octaves):
        cells = base * 2**o
        if cells > size:  # finer than a texel: invisible
            break
        total += persistence**o * _value_octave(rng, size, cells, min(cells * stretch, size))
    lo, hi = total.min(), total.max()
    return (total - lo) / (hi - lo) if hi > lo else np.zeros_like(total)


def _levels(value: Any, name: str) -> NDArray[np.float64]:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size not in (1, 3) or not np.all((a >= 0) & (a <= 1)):
        raise ValueError(f"{name}: expected a number or 3 numbers in [0, 1], got {value!r}")
    return a


def _colour(masks: NDArray | list[NDArray], **levels: Any) -> NDArray[np.float64]:
    """``(H, W, 1 or 3)``: the first level, blended toward each next level by its ``(H, W)`` mask in turn."""
    masks = masks if isinstance(masks, list) else [masks]
    values = [_levels(v, name) for name, v in levels.items()]
    out = np.broadcast_to(values[0], masks[0].shape + (max(v.size for v in values),)).copy()
    for m, v in zip(masks, values[1:], strict=True):
        out += m[..., None] * (v - out)
    return out


def _grain(img: NDArray, size: int, seed: int, grain: float) -> NDArray:
    """Multiply by ``1 - grain * noise`` (a fine fBm): dirt and mottling over a flat pattern."""
    if grain <= 0:
        return img
    return img * (1.0 - grain * fbm_noise(size, seed + 1, base=16, octaves=3))[..., None]


def _noise(size: int, seed: int, *, base: int = 4, octaves: int = 4, persistence: float = 0.5, stretch: int = 1,
           low: Any = 0.0, high: Any = 1.0) -> NDArray:  # fmt: skip
    n = fbm_noise(size, seed, base=base, octaves=octaves, persistence=persistence, stretch=stretch)
    return _colour(n, low=low, high=high)


def _soft_step(signed: NDArray, width: float) -> NDArray:
    """Coverage of a region with signed distance ``signed`` (positive inside), ramped over ``width``."""
    return (signed > 0).astype(np.float64) if width <= 0 else np.clip(0.5 + signed / width, 0.0, 1.0)


def _stripes(size: int, seed: int, *, angle: float = 0.0, period: float = 0.125, duty: float = 0.5,
             softness: float = 0.01, grain: float = 0.0, low: Any = 0.0, high: Any = 1.0) -> NDArray:  # fmt: skip
    """Stripes across the direction ``angle`` (radians from +u toward +v), ``period`` in UV units."""
    if not (period > 0 and 0 < duty < 1):
        raise ValueError(f"stripes: period must be > 0 and duty in (0, 1), got period={period}, duty={duty}")
    ku, kv = round(math.cos(angle) / period), round(math.sin(angle) / period)
    ku, kv = (1, 0) if ku == kv == 0 else (ku, kv)  # snapped: whole periods across the square (tiles)
    v, u = _grid(size)
    p = (ku * u + kv * v + np.random.default_rng(seed).random()) % 1.0
    inside = p < duty
    signed = np.where(inside, np.minimum(p, duty - p), -np.minimum(p - duty, 1.0 - p)) / math.hypot(ku, kv)
    width = max(softness, 1.0 / size)  # at least a texel: no aliased edge
    return _grain(_colour(_soft_step(signed, width), low=low, high=high), size, seed, grain)


def _wrap(d: NDArray) -> NDArray:
    return (d + 0.5) % 1.0 - 0.5  # periodic difference in UV: shapes continue across the border


def _box(u: NDArray, v: NDArray, cu: float, cv: float, hu: float, hv: float) -> NDArray:
    """Signed distance (positive inside, UV units, Chebyshev) to an axis-aligned box on the torus."""
    return np.minimum(hu - np.abs(_wrap(u - cu)), hv - np.abs(_wrap(v - cv)))


def _decals(size: int, seed: int, *, count: int = 3, labels: float = 0.5, discs: float = 0.3, grain: float = 0.0,
            background: Any = 1.0, fill: Any = 0.3, ink: Any = 0.05) -> NDArray:  # fmt: skip
    """``count`` decals on ``background``: discs and rectangles, some rectangles labels with ``ink`` text bars."""
    rng = np.random.default_rng(seed)
    v, u = _grid(size)
    px = 1.0 / size
    shape = np.zeros((size, size))
    text = np.zeros((size, size))
    for _ in range(count):
        cu, cv = rng.random(2)
        if rng.random() < discs:
            r = rng.uniform(0.05, 0.15)
            d = r - np.hypot(_wrap(u - cu), _wrap(v - cv))
            shape = np.maximum(shape, _soft_step(d, px))
            continue
        hu, hv = rng.uniform(0.06, 0.2), rng.uniform(0.04, 0.12)
        shape = np.maximum(shape, _soft_step(_box(u, v, cu, cv, hu, hv), px))
        if rng.random() >= labels:
            continue
        lines = int(rng.integers(2, 5))
        pitch = 1.6 * hv / lines
        for i in range(lines):
            lv = cv + hv - 0.2 * hv - (i + 0.5) * pitch
            start = cu - 0.85 * hu
            while True:  # words of random length, left to right
                w = rng.uniform(0.1, 0.45) * hu
                if start + w > cu + 0.85 * hu:
                    break
                bar = _box(u, v, start + w / 2, lv, w / 2, 0.2 * pitch)
                text = np.maximum(text, _soft_step(bar, px))
                start += w + 0.08 * hu
    text *= shape
    return _grain(_colour([shape, text], background=background, fill=fill, ink=ink), size, seed, grain)


def _wear(size: int, seed: int, *, amount: float = 0.15, base: int = 4, stretch: int = 8, axis: str = "u",
          softness: float = 0.03, low: Any = 0.0, high: Any = 1.0) -> NDArray:  # fmt: skip
    """Worn fraction ``amount``: anisotropic noise (scratches along ``axis``) above its quantile."""
    if not 0 <= amount <= 1 or axis not in ("u", "v"):
        raise ValueError(f"wear: amount must be in [0, 1] and axis 'u' or 'v', got {amount}, {axis!r}")
    n = fbm_noise(size, seed, base=base, octaves=5, persistence=0.6, stretch=stretch)
    n = n * (0.5 + 0.5 * fbm_noise(size, seed + 1, base=2, octaves=2))  # wear clusters in patches
    n = n if axis == "u" else n.T[::-1]
    if amount <= 0:
        return _colour(np.zeros_like(n), low=low, high=high)
    t = np.quantile(n, 1.0 - amount)
    return _colour(_soft_step(n - t, softness), low=low, high=high)


def _sites(rng: np.random.Generator, count: int) -> NDArray:
    """``count`` points on the UV torus, kept apart (dart throwing) so that every region has area."""
    spacing = 0.5 / math.sqrt(count)
    pts = [rng.random(2)]
    for _ in range(200 * count):
        if len(pts) == count:
            break
        p = rng.random(2)
        if min(math.hypot(*_wrap(p - q)) for q in pts) >= spacing:
            pts.append(p)
    while len(pts) < count:  # crowded: accept the rest anywhere
        pts.append(rng.random(2))
    return np.asarray(pts)


def _site_distances(size: int, seed: int, count: int, warp: float) -> NDArray:
    """``(count, size, size)`` periodic distances to the sites from domain-warped texel centres."""
    if not 2 <= count <= 16:
        raise ValueError(f"segments: count must be in 2..16, got {count}")
    rng = np.random.default_rng(seed)
    sites = _sites(rng, count)
    v, u = _grid(size)
    wu = u + warp * (fbm_noise(size, seed + 1, base=3) - 0.5)  # periodic warp: boundaries wiggle, still tile
    wv = v + warp * (fbm_noise(size, seed + 2, base=3) - 0.5)
    return np.stack([np.hypot(_wrap(wu - su), _wrap(wv - sv)) for su, sv in sites])


def segment_labels(size: int, seed: int, count: int = 2, *, warp: float = 0.15) -> NDArray[np.int64]:
    """The hard label map of ``segments``: which of ``count`` regions each texel is in.

    Returns:
        ``(size, size)`` int64 labels in ``0..count-1``; every label occurs.

    Example:
        >>> sorted(set(segment_labels(64, seed=3, count=3).ravel().tolist()))
        [0, 1, 2]
    """
    return np.argmin(_site_distances(size, seed, count, warp), axis=0)


def _segments(size: int, seed: int, *, count: int = 2, softness: float = 0.0, warp: float = 0.15) -> NDArray:
    """Weights of regions ``1..count-1`` (``count - 1`` channels), convex; ``softness`` in UV units."""
    d = _site_distances(size, seed, count, warp)
    if softness <= 0:
        w = (np.argmin(d, axis=0) == np.arange(count)[:, None, None]).astype(np.float64)
    else:  # a softmax of the distance: weights cross over within about softness of a boundary
        w = np.exp(-(d - d.min(axis=0)) / softness)
        w /= w.sum(axis=0)
    return np.moveaxis(w[1:], 0, -1)


def _normal(size: int, seed: int, *, depth: float = 0.005, base: int = 4, octaves: int = 4,
            persistence: float = 0.5) -> NDArray:  # fmt: skip
    """Normals of the height field ``depth * noise`` (UV units), encoded ``0.5 + 0.5 n``."""
    h = depth * fbm_noise(size, seed, base=base, octaves=octaves, persistence=persistence)
    dh_du = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) * (size / 2)  # periodic central differences
    dh_dv = (np.roll(h, 1, axis=0) - np.roll(h, -1, axis=0)) * (size / 2)  # row 0 is the top: v grows upward
    n = np.stack([-dh_du, -dh_dv, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return 0.5 + 0.5 * n


def _checker(size: int, seed: int, *, cells: int = 8, low: Any = 0.0, high: Any = 1.0) -> NDArray:
    """``cells x cells`` squares, ``high`` where the cell's (column + row from the bottom) is even."""
    v, u = _grid(size)
    mask = ((np.floor(u * cells) + np.floor(v * cells)) % 2 == 0).astype(np.float64)
    return _colour(mask, low=low, high=high)


_FUNCTIONS = {
    "noise": _noise,
    "stripes": _stripes,
    "decals": _decals,
    "wear": _wear,
    "segments": _segments,
    "normal": _normal,
    "checker": _checker,
}
#: Names of the procedural patterns (``procedural:<name>``).
PATTERNS = tuple(_FUNCTIONS)


def pattern_array(name: str, params: Mapping[str, Any]) -> NDArray[np.float32]:
    """The pattern ``name`` built from ``params`` (``seed``, ``size`` default 256, its keywords).

    Args:
        name: one of :data:`PATTERNS`.
        params: JSON values; unknown keys raise.

    Returns:
        ``(size, size, C)`` float32 in [0, 1].

    Example:
        >>> pattern_array("checker", {"seed": 0, "size": 4, "cells": 2})[..., 0].tolist()
        [[0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0], [1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0]]
    """
    where = f"pattern {name!r}"
    fn = _FUNCTIONS.get(name)
    if fn is None:
        raise ValueError(f"unknown pattern {name!r}; valid: {list(PATTERNS)}")
    kw = dict(params)
    allowed = [p for p in inspect.signature(fn).parameters if p != "size"]
    unknown = sorted(set(kw) - {"size", *allowed})
    if unknown:
        raise ValueError(f"{where}: unknown params {unknown}; valid: ['size', {', '.join(map(repr, allowed))}]")
    size, seed = kw.pop("size", 256), kw.pop("seed", None)
    if isinstance(size, bool) or not isinstance(size, int) or not 2 <= size <= MAX_SIZE:
        raise ValueError(f"{where}: size must be an integer in 2..{MAX_SIZE}, got {size!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"{where}: seed must be an integer >= 0, got {seed!r}")
    try:
        img = fn(size, seed, **kw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {' '.join(str(e).split())}") from None
    return np.clip(img, 0.0, 1.0).astype(np.float32)
