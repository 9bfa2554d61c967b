"""A textured material's quantities on one texel grid: what the renderer draws and the truth reports.

:func:`material_grid` resamples every texture of a material (:class:`.textures.MaterialTextures`)
onto one grid, the finest of them with its ``KHR_texture_transform``, so that the quantities that
combine several textures (a table mixture's weights with an albedo scale, a metal's reflectance
with its metallic weight) are combined texel by texel, and the Mitsuba bitmaps of the render
(:mod:`.textured_bsdf`) and of the truth pass (:mod:`.texture_truth`) are the same arrays looked
up with the same ``to_uv``. Where every texture of a material has one size and transform (glTF's
usual case) nothing is resampled.

Realized values (:func:`realized`): what the renderer can draw, per texel and colour channel.
A metal's base colour is its normal-incidence reflectance ``R0``, reachable with the metal's
real index ``n`` only above ``((n - 1) / (n + 1))^2`` (clipped there); a table material's albedo
texture scales each table's Mueller matrices by ``min(1, albedo / table albedo)`` (a convex mix
with the zero matrix), so its realized albedo is ``sum_i w_i min(albedo, a_i)``.

Conventions: arrays have row 0 at the top of the image (as :func:`.textures.texture_array`);
``to_uv`` maps OpenGL UVs (v up) to the grid's texture coordinates, in which ``(0, 0)`` is the
image's bottom-left corner; lookups are bilinear with wrap-around (Mitsuba's bitmap defaults).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pbrdf.polar.fresnel import METAL_N, conductor_extinction

from .textures import TextureSpec, texture_array

if TYPE_CHECKING:
    from .spec import MaterialSpec

__all__ = [
    "MAX_TEXTURE_SIZE",
    "MaterialGrid",
    "material_grid",
    "realized",
    "sample_bilinear",
    "table_parameters",
]


def sample_bilinear(image: NDArray, uv: NDArray) -> NDArray[np.float32]:
    """Bilinear lookup with wrap-around at texture coordinates ``uv`` (``(0, 0)`` the bottom-left corner).

    Texel centres sit at ``((j + 0.5) / W, 1 - (i + 0.5) / H)`` for row ``i`` (from the top) and
    column ``j``, as in Mitsuba's bitmap with its data flipped upside down.

    Args:
        image: ``(H, W)`` or ``(H, W, C)``, row 0 at the top.
        uv: ``(..., 2)`` texture coordinates (any real values; they wrap).

    Returns:
        ``(..., C)`` (or ``(...)`` for a 2-D image) float32.

    >>> img = np.array([[1.0, 2.0], [3.0, 4.0]])  # top row 1, 2; bottom row 3, 4
    >>> sample_bilinear(img, np.array([[0.25, 0.25], [0.25, 0.75], [0.5, 0.75]])).tolist()
    [3.0, 1.0, 1.5]
    """
    img = np.asarray(image, dtype=np.float32)
    flat = img.ndim == 2
    if flat:
        img = img[..., None]
    h, w = img.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[..., 0] * w - 0.5
    y = (1.0 - uv[..., 1]) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xa, xb = np.mod(x0, w), np.mod(x0 + 1, w)
    ya, yb = np.mod(y0, h), np.mod(y0 + 1, h)
    out = (img[ya, xa] * (1 - fx) + img[ya, xb] * fx) * (1 - fy) + (img[yb, xa] * (1 - fx) + img[yb, xb] * fx) * fy
    return (out[..., 0] if flat else out).astype(np.float32)


@dataclass(frozen=True, eq=False)  # compared and hashed by identity (one per material and file version)
class MaterialGrid:
    """A textured material's textures on one grid (row 0 at the top); a slot is None where it is constant.

    Attributes:
        to_uv: ``(3, 3)`` OpenGL UVs -> the grid's texture coordinates.
        albedo: ``(H, W, 3)`` base colour, linear.
        roughness: ``(H, W)`` Disney roughness.
        metallic: ``(H, W)`` Disney metallic.
        normal: ``(H, W, 3)`` unit tangent-space normals (``normal_scale`` applied; z > 0).
        weights: ``(H, W, T)`` convex weights of ``tables`` (they sum to 1 in every texel).
        tables: the material's table and its ``textures.tables``, each once.
    """

    to_uv: NDArray[np.float64]
    albedo: NDArray[np.float32] | None = None
    roughness: NDArray[np.float32] | None = None
    metallic: NDArray[np.float32] | None = None
    normal: NDArray[np.float32] | None = None
    weights: NDArray[np.float32] | None = None
    tables: tuple[str, ...] = ()

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the grid."""
        for a in (self.albedo, self.roughness, self.metallic, self.normal, self.weights):
            if a is not None:
                return a.shape[:2]
        return (1, 1)


def _resample(image: NDArray, src: NDArray, shape: tuple[int, int], dst: NDArray) -> NDArray[np.float32]:
    """``image`` (looked up through ``src``) at the texel centres of a ``shape`` grid looked up through ``dst``."""
    if image.shape[:2] == tuple(shape) and np.allclose(src, dst):
        return image.astype(np.float32)
    h, w = shape
    gu, gv = np.meshgrid((np.arange(w) + 0.5) / w, 1.0 - (np.arange(h) + 0.5) / h)
    grid = np.stack([gu, gv, np.ones_like(gu)], axis=-1)
    uv = grid @ np.linalg.inv(dst).T  # grid texture coordinates -> OpenGL UVs
    return sample_bilinear(image, (uv @ np.asarray(src).T)[..., :2])


def _file_key(tex: TextureSpec) -> tuple:
    try:
        st = os.stat(tex.source)
        return (st.st_mtime_ns, st.st_size)
    except OSError:
        return ()


def material_grid(material: MaterialSpec) -> MaterialGrid:
    """The material's textures on one grid (the finest texture's size and transform); cached per process.

    Raises:
        ValueError: ``material`` has no textures, or a texture cannot be read.
    """
    tex = material.textures
    if tex is None:
        raise ValueError(f"material {material.name!r}: material_grid needs textures")
    keys = tuple(_file_key(t) for t in tex.slots().values())
    return _material_grid(material, keys)


#: Longest texture side a render uses: larger images are area-averaged down on reading. What a
#: 512 px render can show (:func:`.textures.texture_size_for`); it bounds memory (48 MB for four
#: slots) and keeps the number of texture sizes, each compiled once, small.
MAX_TEXTURE_SIZE = 1024


@functools.lru_cache(maxsize=16)
def _material_grid(material: MaterialSpec, _file_keys: tuple) -> MaterialGrid:
    tex = material.textures
    slots = tex.slots()
    images = {s: texture_array(t, max_size=MAX_TEXTURE_SIZE) for s, t in slots.items()}
    if not images:
        return MaterialGrid(to_uv=np.eye(3))
    finest = max(images, key=lambda s: images[s].shape[0] * images[s].shape[1])
    to_uv = slots[finest].uv_matrix()
    shape = images[finest].shape[:2]
    grid = {s: _resample(images[s], slots[s].uv_matrix(), shape, to_uv) for s in images}
    out: dict = {"to_uv": to_uv}
    if "albedo" in grid:
        out["albedo"] = np.clip(grid["albedo"], 0.0, 1.0)
    for s in ("roughness", "metallic"):
        if s in grid:
            out[s] = np.clip(grid[s][..., 0], 0.0, 1.0)
    if "normal" in grid:
        n = 2.0 * grid["normal"] - 1.0
        n[..., :2] *= tex.normal_scale
        n[..., 2] = np.maximum(n[..., 2], 1e-3)  # a normal below the surface has no meaning
        out["normal"] = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    if material.kind == "measured":
        tables, weights = _table_weights(material, grid.get("weights"), shape)
        out.update(tables=tables, weights=weights)
    return MaterialGrid(**out)


def _table_weights(material: MaterialSpec, extra: NDArray | None, shape) -> tuple[tuple[str, ...], NDArray | None]:
    """The tables, each once, and their convex weights per texel (None for the table alone)."""
    tables = (str(material.table), *material.textures.tables)
    if extra is None:
        return tables[:1], None
    w = np.clip(extra, 0.0, None)
    total = w.sum(axis=-1, keepdims=True)
    w = np.where(total > 1.0, w / np.maximum(total, 1e-12), w)  # clipped so the own weight stays >= 0
    w = np.concatenate([1.0 - w.sum(axis=-1, keepdims=True), w], axis=-1)
    unique: list[str] = []
    merged: list[NDArray] = []
    for path, plane in zip(tables, np.moveaxis(w, -1, 0), strict=True):
        key = os.path.realpath(path)
        if key in unique:  # one table listed twice: one BSDF with the summed weight
            merged[unique.index(key)] = merged[unique.index(key)] + plane
        else:
            unique.append(key)
            merged.append(plane)
    names = tuple(tables[[os.path.realpath(t) for t in tables].index(k)] for k in unique)
    return names, np.clip(np.stack(merged, axis=-1), 0.0, 1.0).astype(np.float32)


def table_parameters(material: MaterialSpec, table: str) -> tuple[NDArray[np.float64], float, float]:
    """Fitted ``(albedo (3,), roughness, metallic)`` of one of a table material's tables.

    The material's own table has the material's constants; another one is looked up in the
    ``materials.json`` beside it (:func:`.scenegen.load_material_library`'s format) and falls back
    to the material's constants where it is not listed.
    """
    own = (np.asarray(material.albedo, np.float64), float(material.roughness), float(material.metallic))
    if os.path.realpath(table) == os.path.realpath(str(material.table)):
        return own
    entry = _library_entry(os.path.realpath(table))
    if entry is None:
        return own
    return np.asarray(entry.albedo, np.float64), float(entry.roughness), float(entry.metallic)


@functools.lru_cache(maxsize=64)
def _library_entry(table: str) -> MaterialSpec | None:
    """The entry of ``table`` in the pBRDF library beside it (:func:`.scenegen.load_material_library`), or None."""
    from .scenegen import load_material_library  # noqa: PLC0415 - the library's one reader

    try:
        entries = load_material_library(Path(table).parent)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return next((e for e in entries if os.path.realpath(str(e.table)) == table), None)


def realized(material: MaterialSpec, grid: MaterialGrid) -> dict[str, NDArray[np.float32] | float]:
    """The ground truth the renderer draws: albedo per channel, roughness, metallic, on the grid or constant.

    Returns:
        ``{"albedo": (H, W, 3) or (3,), "roughness": (H, W) or float, "metallic": ...}``.
    """
    albedo = grid.albedo if grid.albedo is not None else np.asarray(material.albedo, np.float32)
    rough = grid.roughness if grid.roughness is not None else material.roughness
    metal = grid.metallic if grid.metallic is not None else material.metallic
    if material.kind == "measured":
        return _realized_tables(material, grid)
    if material.kind == "conductor" and grid.albedo is not None:
        r0 = conductor_extinction(albedo, np.asarray(material.eta))[1].astype(np.float32)
        albedo = r0 if grid.metallic is None else (metal[..., None] * r0 + (1 - metal[..., None]) * albedo)
    elif material.kind == "pplastic" and grid.metallic is not None:
        r0 = conductor_extinction(albedo, METAL_N)[1].astype(np.float32)
        albedo = metal[..., None] * r0 + (1 - metal[..., None]) * albedo
    elif material.kind == "pplastic":
        metal = material.metallic  # an untextured pplastic renders no metal
    return {"albedo": albedo, "roughness": rough, "metallic": metal}


def _realized_tables(material: MaterialSpec, grid: MaterialGrid) -> dict:
    params = [table_parameters(material, t) for t in grid.tables]
    w = grid.weights if grid.weights is not None else np.ones((*grid.shape, 1), np.float32)
    albedo = np.zeros((*w.shape[:2], 3), np.float32)
    rough = np.zeros(w.shape[:2], np.float32)
    metal = np.zeros(w.shape[:2], np.float32)
    for i, (a, r, m) in enumerate(params):
        wi = w[..., i]
        seen = np.minimum(grid.albedo, a) if grid.albedo is not None else np.broadcast_to(a, albedo.shape)
        albedo += wi[..., None] * seen
        rough += wi * r
        metal += wi * m
    return {"albedo": albedo, "roughness": rough, "metallic": metal}
