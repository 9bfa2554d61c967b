"""A depth map as a camera-frame triangle mesh, and maps extended past an object's mask (numpy only).

The one home of the relief mesh's geometry: the Blender import
(:func:`blender_addon.core.frustum.depth_mesh`, which adds Blender's UVs) and the glTF asset
(:mod:`pbrdf.data.gltf_asset`) build the same triangles from the same depth map. numpy only:
Blender's Python has no scipy, and the add-on vendors ``pbrdf``.

Convention:
    Camera frame and pixels as :mod:`pbrdf.sensor.projection`: x right, y up, looking down -z;
    pixel ``(i, j)`` (row i from the top) has its centre at ``(j + 0.5, i + 0.5)``. A vertex sits
    on its pixel centre's ray at the pixel's depth. Example: ``f = 2`` px, a 2 x 2 image, depth 1 m:
    the top-left vertex is ``(-0.25, 0.25, -1)``.

    >>> k = [[2.0, 0.0, 1.0], [0.0, 2.0, 1.0], [0.0, 0.0, 1.0]]
    >>> v, faces, pixels = relief_mesh(np.ones((2, 2)), np.ones((2, 2), bool), k)
    >>> v[0].tolist(), faces.tolist(), pixels[3].tolist()
    ([-0.25, 0.25, -1.0], [[2, 3, 0], [3, 1, 0]], [1, 1])
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.sensor.projection import pixel_rays

__all__ = ["relief_mesh", "dilate", "extend_maps"]


def relief_mesh(
    depth: NDArray, valid: NDArray, intrinsics: ArrayLike, *, max_jump: float = 0.05
) -> tuple[NDArray, NDArray, NDArray]:
    """A camera-frame triangle mesh with one vertex per valid pixel centre, displaced to its depth.

    Two triangles per 2x2 block of valid pixels (one where three are valid), none across depth
    jumps larger than ``max_jump`` (relative), so silhouettes do not become skirts.

    Args:
        depth: ``(H, W)`` metres along the optical axis.
        valid: ``(H, W)`` bool.
        intrinsics: ``K (3, 3)`` of the depth map's grid.
        max_jump: largest relative depth difference inside one triangle.

    Returns:
        ``(vertices (N, 3) float64, faces (F, 3) int64 counter-clockwise seen from the camera,
        pixels (N, 2) int64 (row, column) of each vertex)``, vertices in row-major pixel order.

    Raises:
        ValueError: ``depth`` and ``valid`` differ in shape, or a valid pixel's vertex is not finite.
    """
    h, w = depth.shape
    if valid.shape != (h, w):
        raise ValueError(f"depth {depth.shape} and valid {valid.shape} differ")
    index = -np.ones((h, w), np.int64)
    index[valid] = np.arange(int(valid.sum()))
    d = depth.astype(np.float64)
    vertices = pixel_rays(intrinsics, h, w)[valid] * d[valid][:, None]
    rows, cols = np.nonzero(valid)
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
    if not math.isfinite(float(vertices.sum())):
        raise ValueError("depth mesh has non-finite vertices")
    return vertices, np.concatenate(faces, axis=0), np.stack([rows, cols], axis=1)


def dilate(region: NDArray, rings: int = 1) -> NDArray:
    """``region`` (``(H, W)`` bool) grown by ``rings`` pixels, 8-connected (numpy only: Blender's Python has no scipy).

    Example:
        >>> dilate(np.eye(4, dtype=bool)[:1], 1).astype(int).tolist()
        [[1, 1, 0, 0]]
    """
    out = np.asarray(region, dtype=bool).copy()
    for _ in range(rings):
        p = np.pad(out, 1)
        out = np.zeros_like(out)
        for dy in range(3):
            for dx in range(3):
                out |= p[dy : dy + out.shape[0], dx : dx + out.shape[1]]
    return out


def extend_maps(
    maps: Mapping[str, NDArray], filled: NDArray, rings: int = 2, *, max_step: float = 0.04
) -> dict[str, NDArray]:
    """Copies of ``maps`` that go on ``rings`` pixels past the ``filled`` region (float32).

    Ring by ring, each new pixel gets the mean of its already-filled 8-neighbours (``"normal"``
    renormalised); ``"depth"`` continues the surface: the mean of ``2 d_p - d_pp`` over the filled
    neighbours ``p`` whose next pixel ``pp`` on the same line is filled too (else ``d_p``), each
    step limited to ``max_step`` of ``d_p`` (under :func:`relief_mesh`'s 5 % jump limit, so the
    extended triangles are kept). Textures are sampled bilinearly and pixels are filtered, so an
    edge pixel would otherwise blend with the zeros outside the mask, and a mesh over the mask
    alone would end at the edge pixels' centres, half a pixel inside the outline; extended, the
    mesh reaches past the outline and the mask, as alpha, cuts it where its pixels end.

    Args:
        maps: ``{name: (H, W) or (H, W, C)}``; ``"normal"`` and ``"depth"`` are treated as above.
        filled: ``(H, W)`` bool, the pixels whose values are kept.
        rings: how many pixels to extend.
        max_step: largest relative depth step per ring.

    Returns:
        ``{name: float32 array}``; values outside the extension are zero. Empty when ``filled``
        is all or nothing (nothing to extend).

    Example:
        >>> e = extend_maps({"albedo": np.array([[0, 0.5, 0.3, 0]]), "depth": np.array([[0, 2, 2.01, 0]])},
        ...                 np.array([[0, 1, 1, 0]], bool), 1)
        >>> e["albedo"][0].round(3).tolist(), e["depth"][0].round(3).tolist()
        ([0.5, 0.5, 0.3, 0.3], [1.99, 2.0, 2.01, 2.02])
    """
    filled = np.asarray(filled, dtype=bool)
    if filled.all() or not filled.any():
        return {}
    h, w = filled.shape
    arrays = {k: np.array(v, dtype=np.float64) for k, v in maps.items()}
    arrays = {k: np.where(filled.reshape(h, w, *([1] * (v.ndim - 2))), v, 0.0) for k, v in arrays.items()}
    offsets = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]

    def padded(a: NDArray) -> NDArray:
        """``a`` in two rings of zeros (False): ``shift(padded(a), dy, dx)`` is ``a`` at ``(y + dy, x + dx)``."""
        return np.pad(a, [(2, 2), (2, 2)] + [(0, 0)] * (a.ndim - 2))

    def shift(p: NDArray, dy: int, dx: int) -> NDArray:
        return p[2 + dy : 2 + dy + h, 2 + dx : 2 + dx + w]

    for _ in range(rings):
        count = np.zeros((h, w))
        sums = {k: np.zeros_like(v) for k, v in arrays.items()}
        d_sum, d_count = np.zeros((h, w)), np.zeros((h, w))
        pads = {k: padded(v) for k, v in arrays.items()}
        pad_filled = padded(filled)
        for dy, dx in offsets:
            near, far = shift(pad_filled, dy, dx), shift(pad_filled, 2 * dy, 2 * dx)
            count += near
            for k in arrays:
                sums[k] += shift(pads[k], dy, dx)
            if "depth" in arrays:
                d1, d2 = shift(pads["depth"], dy, dx), shift(pads["depth"], 2 * dy, 2 * dx)
                step = np.clip(np.where(far, d1 - d2, 0.0), -max_step * d1, max_step * d1)
                d_sum += np.where(near, d1 + step, 0.0)
                d_count += near
        ring = ~filled & (count > 0)
        for k, v in arrays.items():
            total, n = (d_sum, d_count) if k == "depth" else (sums[k], count)
            v[ring] = total[ring] / (n[ring][:, None] if v.ndim == 3 else n[ring])
            if k == "normal":
                v[ring] /= np.maximum(np.linalg.norm(v[ring], axis=-1, keepdims=True), 1e-12)
        filled = filled | ring
    return {k: v.astype(np.float32) for k, v in arrays.items()}
