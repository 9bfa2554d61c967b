"""Decode raw HDR brackets into Stokes images and the nine network input maps.

The same code serves synthetic captures (from :func:`pbrdf.sensor.camera.simulate_capture`) and real
ones (:mod:`pbrdf.data.capture`). Steps, all linear and in float32:

1. :func:`hdr_merge` on the raw mosaic: per pixel ``E = sum_j v_j z_j / sum_j v_j t_j`` (the
   maximum-likelihood estimate for a shot-noise-limited linear sensor), where ``v_j`` is true only
   if *all four analyzer pixels of the pixel's 2x2 block* are unsaturated in exposure ``j``: a
   saturated I0 next to an unsaturated I90 would bias s1 strongly.
2. :func:`demosaic`: bilinear interpolation of each of the 16 (colour, angle) lattices of the
   4x4 super-pixel to a common output grid, either ``"full"`` (every raw pixel) or ``"half"``
   (the centres of the 2x2 blocks; exactly the pixel centres of a half-resolution render).
   Float precision is kept (no uint16 rescaling) and affine signals are reproduced exactly.
3. :func:`stokes_from_intensities`: per colour channel, least squares through the calibrated
   measurement matrix of :func:`pbrdf.sensor.camera.measurement_matrix` (QWP retardance, extinction
   ratios). With the QWP at 0 degrees the camera's "s2" channel carries the incoming ``s3``; the
   incoming ``s2`` is not measured.
4. :func:`nine_maps`: ``LP = -s1``, ``unpol = s0 - LP = s0 + s1``, ``CP = s3 / (s0 + eps)``.

:func:`decode` runs steps 2 and 3 as one linear map per colour (small matrix products, one
horizontal strip of the image at a time, so that the intermediates stay in the cache) and step 4
on each strip as it is done; the separate functions give the same numbers up to float32 rounding.

Convention (decomposition): the display emits vertically polarized light, ``s1 = -s0``, so the
polarized (specular) part is ``LP = -s1 >= 0`` and the unpolarized part is ``unpol = s0 + s1``.
The paper prints ``unpol = s0 - s1``, which would give ``2 s0`` for pure display light; we use the
consistent form. Map order: ``[R_unpol, G_unpol, B_unpol, R_LP, G_LP, B_LP, R_CP, G_CP, B_CP]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.sensor.camera import CameraModel, SensorParams, measurement_matrix, mosaic, mosaic_indices
from pbrdf.sensor.imperfections import IDENTITY3, vignetting_map

__all__ = [
    "NINE_MAP_NAMES",
    "Decoded",
    "hdr_merge",
    "demosaic",
    "stokes_from_intensities",
    "nine_maps",
    "decode",
    "subtract_dark",
    "estimate_pattern_offset",
]

NINE_MAP_NAMES = (
    "R_unpol", "G_unpol", "B_unpol",
    "R_LP", "G_LP", "B_LP",
    "R_CP", "G_CP", "B_CP",
)  # fmt: skip


@dataclass
class Decoded:
    """Result of :func:`decode` on an output grid of size (H', W').

    Attributes:
        maps: the nine maps, ``(H', W', 9)`` float32, order :data:`NINE_MAP_NAMES`.
        mask: ``(H', W')`` bool, True where every input pixel was measured (some exposure with
            all four angles unsaturated), the result is finite and the total ``s0`` (summed
            over colours) exceeds ``min_signal``.
        stokes: measured Stokes ``(H', W', 3, 3)`` float32, per colour ``(s0, s1, s3)``.
    """

    maps: NDArray[np.float32]
    mask: NDArray[np.bool_]
    stokes: NDArray[np.float32]


def _check_raws(raws: NDArray, n_exposures: int) -> None:
    if raws.ndim != 3:
        raise ValueError(f"raws must have shape (E, H, W); got {raws.shape}")
    if raws.shape[0] != n_exposures:
        raise ValueError(f"got {raws.shape[0]} raw frames for {n_exposures} exposure times")
    h, w = raws.shape[1:]
    if h % 4 or w % 4 or h < 8 or w < 8:
        raise ValueError(f"raw size must be a multiple of 4 and at least 8x8; got {h}x{w}")


def _checked_bracket(raws: ArrayLike, exposures: ArrayLike) -> tuple[NDArray, NDArray[np.float64]]:
    r = np.asarray(raws)
    t = np.asarray(exposures, dtype=np.float64).reshape(-1)
    _check_raws(r, t.size)
    if np.any(t <= 0) or not np.all(np.isfinite(t)):
        raise ValueError(f"exposure times must be positive and finite; got {t}")
    if r.dtype.kind == "f" and not np.all(np.isfinite(r)):
        raise ValueError("raw frames contain NaN or Inf")
    return r, t


def _merge_into(r: NDArray, t: NDArray, sensor: SensorParams, out: NDArray) -> NDArray[np.bool_]:
    """The HDR merge of raws ``(E, H, W)`` whose 2x2 blocks start at even rows and columns into ``out`` ``(H, W)``.

    Works on pairs of rows with the block quantities repeated along the columns, so that every
    pass over the raws is contiguous; the arithmetic (and so the rounding) is that of the formula
    in :func:`hdr_merge`, summed over the exposures in order. Returns the ``(H/2, W/2)`` blocks
    with some unsaturated exposure.
    """
    e, h, w = r.shape
    rows = r.reshape(e, h // 2, 2, w)
    pair_max = np.maximum(rows[:, :, 0], rows[:, :, 1])  # (E, H/2, W)
    # v[j]: all four analyzer pixels of the block below the saturation threshold in exposure j.
    v = np.maximum(pair_max[..., 0::2], pair_max[..., 1::2]) < sensor.saturation * sensor.white_level
    den = np.zeros(v.shape[1:], dtype=np.float32)
    for j in range(e):
        den += np.float32(t[j]) * v[j]
    count = v.sum(axis=0, dtype=np.float32)
    valid_b = den > 0
    if not valid_b.all():  # blocks saturated in every exposure fall back to the shortest one (flagged)
        shortest = int(np.argmin(t))
        v[shortest] |= ~valid_b
        den[~valid_b] = np.float32(t[shortest])
        count[~valid_b] = 1.0
    rate = np.float32(1.0 / sensor.dn_per_unit_second) / den
    offset = np.float32(sensor.black_level) * count
    # Per-block quantities repeated to the pixel columns; the masked sum as a product with 0/1
    # (exact, and without the branches of a masked add, slow on ragged saturation borders).
    rate, offset = np.repeat(rate, 2, axis=1), np.repeat(offset, 2, axis=1)
    keep = (v.view(np.uint8).astype(np.uint16) * np.uint16(257)).view(np.bool_)  # (E, H/2, W)
    term = np.empty((h // 2, w), dtype=r.dtype)
    every, some = [bool(x.all()) for x in v], [bool(x.any()) for x in v]
    for di in (0, 1):
        num = out[di::2]
        num[...] = 0.0
        for j in range(e):
            if every[j]:
                np.add(num, r[j, di::2], out=num)
            elif some[j]:
                np.multiply(r[j, di::2], keep[j], out=term)
                np.add(num, term, out=num)
        num -= offset
        num *= rate
    return valid_b


def _merge_padded(r: NDArray, t: NDArray, sensor: SensorParams, pattern_offset: tuple[int, int], pad: int):
    """HDR merge into a buffer with ``pad`` edge-replicated rows and columns on each side.

    Returns ``(padded, valid_blocks)``: the ``(H + 2 pad, W + 2 pad)`` float32 mosaic and the
    validity of the 2x2 blocks of the pattern, ``(H/2 + pr, W/2 + pc)`` with ``pr, pc`` the
    parities of ``pattern_offset`` (an odd offset adds a block row or column in front).
    """
    e, h, w = r.shape
    padded = np.empty((h + 2 * pad, w + 2 * pad), dtype=np.float32)
    inner = padded[pad : pad + h, pad : pad + w]
    pr, pc = pattern_offset[0] % 2, pattern_offset[1] % 2
    if pr or pc:  # align the 2x2 blocks: one edge row/column in front (and behind)
        aligned = np.empty((h + 2 * pr, w + 2 * pc), dtype=np.float32)
        valid_b = _merge_into(np.pad(r, ((0, 0), (pr, pr), (pc, pc)), mode="edge"), t, sensor, aligned)
        inner[...] = aligned[pr : pr + h, pc : pc + w]
    else:
        valid_b = _merge_into(r, t, sensor, inner)
    _fill_pad(padded, pad)
    return padded, valid_b


def _fill_pad(padded: NDArray, pad: int) -> None:
    """Copy the first and last ``pad`` rows and columns of the interior into the border (in place).

    With ``pad = 4`` every lattice of the 4x4 pattern gets one copy of its edge sample outside.
    """
    if pad:
        padded[:pad] = padded[pad : 2 * pad]
        padded[-pad:] = padded[-2 * pad : -pad]
        padded[:, :pad] = padded[:, pad : 2 * pad]
        padded[:, -pad:] = padded[:, -2 * pad : -pad]


def hdr_merge(
    raws: ArrayLike,
    exposures: ArrayLike,
    sensor: SensorParams,
    *,
    pattern_offset: tuple[int, int] = (0, 0),
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Merge an exposure bracket of raw mosaics into one linear mosaic.

    Per pixel ``E = (sum_j v_j z_j - b sum_j v_j) / (g sum_j v_j t_j)`` (float32), where ``v_j``
    says that all four pixels of the pixel's 2x2 block are below the saturation threshold in
    exposure ``j``.

    Args:
        raws: ``(E, H, W)`` raw frames (uint16 or float DN, black level included).
        exposures: ``(E,)`` exposure times in seconds.
        sensor: sensor parameters (black and white level, saturation, radiometric scale).
        pattern_offset: position of raw pixel (0, 0) in the 4x4 IMX250MYR table; it decides
            which pixels form the 2x2 same-colour blocks.

    Returns:
        ``(radiance, valid)``: the analyzer intensity per raw pixel in radiance units
        (``(H, W)`` float32), and ``(H, W)`` bool, False where every exposure saturated (the
        shortest exposure is used there, clipped).
    """
    r, t = _checked_bracket(raws, exposures)
    h, w = r.shape[1:]
    merged, valid_b = _merge_padded(r, t, sensor, pattern_offset, 0)
    pr, pc = pattern_offset[0] % 2, pattern_offset[1] % 2
    valid = np.repeat(np.repeat(valid_b, 2, axis=0), 2, axis=1)[pr : pr + h, pc : pc + w]
    return merged, np.ascontiguousarray(valid)


# ---- demosaic, Stokes and maps: separable interpolation as small matrix products ----------------
#
# Every (colour, angle) lattice has period 4 and is interpolated linearly, with its edge samples
# repeated outside, to the output grid. Both grids repeat every 4 raw pixels (P = 4 outputs for
# "full", 2 for "half"), so output p of period n reads the lattice samples n - 1, n, n + 1 (one
# edge sample padded on each side) with fixed weights: a (P, 3) matrix per lattice offset.
# Columns first, on the quarter-height lattices, as one (Q, 3) @ (3, P) product per lattice row;
# then rows and the per-colour linear map (decoding matrix, or the identity for demosaic) as one
# (P, 3 L) @ (3 L, W') product per output period and component over the colour's L lattices.
# The image is processed in horizontal strips, so the intermediates stay in the cache.

_PAD = 4  # raw pixels of edge padding: one lattice sample on each side


def _grid_period(grid: str) -> tuple[float, ...]:
    """Positions of the outputs inside a 4-pixel period, in raw pixels."""
    if grid == "full":
        return (0.0, 1.0, 2.0, 3.0)
    if grid == "half":
        return (0.5, 2.5)  # the centres of the 2x2 blocks
    raise ValueError(f"grid must be 'full' or 'half'; got {grid!r}")


def _tap_weights(positions: tuple[float, ...], offset: int) -> NDArray[np.float64]:
    """``(P, 3)``: weights of lattice samples ``n - 1, n, n + 1`` for the outputs of period ``n``."""
    weights = np.zeros((len(positions), 3))
    for p, d in enumerate(positions):
        u = (d - offset) / 4.0
        m = int(np.floor(u))  # -1 or 0
        weights[p, m + 1] += 1.0 - (u - m)
        weights[p, m + 2] += u - m
    return weights


class _Interpolator:
    """The 16 lattices interpolated to a grid and mapped linearly per colour, as matrix products.

    Output ``[c, k]`` is ``sum_a coef[c, k, a] * interp(angle a of colour c)`` (green: the mean
    of its two lattices per angle); ``coef`` is ``(3, K, 4)``.
    """

    def __init__(self, shape: tuple[int, int], grid: str, pattern_offset: tuple[int, int], coef: NDArray) -> None:
        positions = _grid_period(grid)
        self.h, self.w = shape
        self.period = len(positions)
        self.q = self.w // 4
        self.out_h, self.out_w = self.period * (self.h // 4), self.period * self.q
        # Strips of about 128k output pixels: the intermediates stay in the cache, and the
        # per-strip overhead is small (docs/measurements/headless.md, decode speed).
        self.strip_periods = max(1, min(self.h // 4, (1 << 17) // (self.out_w * self.period)))
        self.strip_rows = self.period * self.strip_periods
        color, angle = mosaic_indices(pattern_offset)
        self.col_weights = [_tap_weights(positions, j).T.astype(np.float32) for j in range(4)]  # (3, P)
        row_weights = [_tap_weights(positions, i) for i in range(4)]
        self.slots: list[tuple[int, int]] = []  # (colour, slot in the colour's lattices) of lattice (i, j)
        members: list[list[tuple[int, int]]] = [[], [], []]
        for i in range(4):
            for j in range(4):
                c = int(color[i, j])
                self.slots.append((c, len(members[c])))
                members[c].append((i, j))
        n_out = coef.shape[1]
        self.rows: list[NDArray[np.float32]] = []  # per colour: (K, P, 3 L)
        for c, lattices in enumerate(members):
            n_lat = len(lattices)
            a = np.zeros((n_out, self.period, 3, n_lat))
            for s, (i, j) in enumerate(lattices):
                share = 4.0 / n_lat  # green: two lattices per angle, averaged
                a[:, :, :, s] = share * coef[c, :, angle[i, j], None, None] * row_weights[i][None]
            self.rows.append(a.reshape(n_out, self.period, 3 * n_lat).astype(np.float32))
        self.n_lat = [len(m) for m in members]

    def strips(self, padded: NDArray[np.float32], out: NDArray[np.float32]):
        """Fill ``out`` ``(3, K, H', W')`` (C-contiguous) from the mosaic padded by :data:`_PAD`.

        Yields ``(y0, y1)`` after writing output rows ``y0:y1``, strip by strip.
        """
        periods, strip_periods = self.h // 4, self.strip_periods
        nr_max = strip_periods + 2
        cols = np.empty((nr_max, self.q, 4, 3), dtype=np.float32)
        lat = [np.empty((nr_max, n, self.out_w), dtype=np.float32) for n in self.n_lat]
        for n0 in range(0, periods, strip_periods):
            n1 = min(n0 + strip_periods, periods)
            nr = n1 - n0 + 2
            for i in range(4):
                # cols[r, q, j, t] = padded[4 (n0 + r) + i, 4 (q + t) + j]: the three samples around
                # period q of lattice (i, j), for padded lattice rows n0 ... n1 + 1 (one copy per t:
                # contiguous runs).
                rows = padded[4 * n0 + i :: 4][:nr]
                for t in range(3):
                    np.copyto(cols[:nr, :, :, t], rows[:, 4 * t : 4 * t + self.w].reshape(nr, self.q, 4))
                for j in range(4):
                    c, s = self.slots[4 * i + j]
                    dst = lat[c][:nr, s].reshape(nr, self.q, self.period)
                    np.matmul(cols[:nr, :, j], self.col_weights[j], out=dst)
            y0, y1 = self.period * n0, self.period * n1
            for c in range(3):
                n_lat, buf = self.n_lat[c], lat[c]
                windows = np.lib.stride_tricks.as_strided(
                    buf,
                    shape=(n1 - n0, 3 * n_lat, self.out_w),
                    strides=(buf.strides[0], buf.strides[1], 4),
                    writeable=False,
                )
                for k in range(out.shape[1]):
                    np.matmul(self.rows[c][k], windows, out=out[c, k, y0:y1].reshape(n1 - n0, self.period, self.out_w))
            yield y0, y1


def _erode_blocks(ok: NDArray[np.bool_], radius: int = 2) -> NDArray[np.bool_]:
    """False within ``radius`` blocks of a False block (a separable minimum filter, edges repeated)."""
    out = ok.copy()
    for axis in (0, 1):
        src = out.copy()
        a, b = np.moveaxis(out, axis, 0), np.moveaxis(src, axis, 0)
        for s in range(1, radius + 1):
            a[s:] &= b[:-s]
            a[:-s] &= b[s:]
    return out


def demosaic(image: ArrayLike, *, grid: str = "half", pattern_offset: tuple[int, int] = (0, 0)) -> NDArray[np.float32]:
    """Bilinear demosaic of an IMX250MYR mosaic into every colour and analyzer angle.

    Each of the 16 pixels of the 4x4 super-pixel defines a lattice of period 4; every lattice
    is linearly interpolated to the output grid, and the two green lattices of each angle are
    averaged. The result is exact for signals that are affine in the image plane (away from the
    border, where the nearest sample is repeated).

    Args:
        image: ``(H, W)`` mosaic (e.g. the output of :func:`hdr_merge`), H and W multiples of 4.
        grid: ``"half"`` for ``(H/2, W/2)`` at the centres of the 2x2 blocks (raw coordinates
            ``2k + 0.5``), or ``"full"`` for ``(H, W)`` at every raw pixel.
        pattern_offset: position of raw pixel (0, 0) in the 4x4 IMX250MYR table.

    Returns:
        ``(H', W', 3, 4)`` float32: colour (R, G, B) and analyzer angle (0, 45, 90, 135).
    """
    img = _check_mosaic(image)
    interp = _Interpolator(img.shape, grid, pattern_offset, np.broadcast_to(np.eye(4), (3, 4, 4)))
    padded = np.empty((img.shape[0] + 2 * _PAD, img.shape[1] + 2 * _PAD), dtype=np.float32)
    padded[_PAD:-_PAD, _PAD:-_PAD] = img
    _fill_pad(padded, _PAD)
    out = np.empty((3, 4, interp.h * interp.period // 4, interp.out_w), dtype=np.float32)
    for _ in interp.strips(padded, out):
        pass
    return np.moveaxis(out, (0, 1), (2, 3))


def _check_mosaic(image: ArrayLike) -> NDArray[np.float32]:
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2 or img.shape[0] % 4 or img.shape[1] % 4 or min(img.shape) < 8:
        raise ValueError(f"mosaic must be (H, W) with H, W multiples of 4 and >= 8; got {img.shape}")
    return img


def _decoding_matrix(model: CameraModel) -> NDArray[np.float64]:
    """``(3, 3, 4)``: per colour, the pseudo-inverse mapping four analyzer intensities to (s0, s1, s3)."""
    a = measurement_matrix(model)[:, :, [0, 1, 3]]  # (3 colours, 4 angles, 3 components)
    return np.linalg.pinv(a)


def stokes_from_intensities(intensities: ArrayLike, model: CameraModel) -> NDArray:
    """Least-squares ``(s0, s1, s3)`` per colour from the four analyzer intensities.

    Args:
        intensities: ``(..., 3, 4)`` colour x analyzer angle (0, 45, 90, 135).
        model: camera model whose measurement matrix was used to record them.

    Returns:
        ``(..., 3, 3)`` measured Stokes ``(s0, s1, s3)`` per colour channel.

    .. warning::
        The incoming ``s2`` is assumed to be 0 in the fit. For a QWP retardance ``pi/2 + e`` the
        returned ``s3`` is ``s3 + s2 cot(pi/2 + e)``: about ``-e s2`` for small ``e``.
    """
    x = np.asarray(intensities)
    if x.shape[-2:] != (3, 4):
        raise ValueError(f"intensities must have shape (..., 3, 4); got {x.shape}")
    dec = _decoding_matrix(model).astype(x.dtype if x.dtype == np.float32 else np.float64)
    return np.einsum("cka,...ca->...ck", dec, x, optimize=True)


def _maps_planar(s0: NDArray, s1: NDArray, s3: NDArray, out: NDArray, eps: float) -> None:
    """The nine maps ``out[kind, colour, ...]`` (kinds unpol, LP, CP) from ``s0, s1, s3`` ``(colour, ...)``."""
    lp = np.negative(s1, out=out[1])
    np.subtract(s0, lp, out=out[0])
    den = s0 + eps
    with np.errstate(over="ignore"):  # a subnormal den (eps = 0) overflows to +-inf; the clip makes it +-1
        if den.size and den.min() > 0:
            np.divide(s3, den, out=out[2])
        else:
            out[2] = 0.0
            np.divide(s3, den, out=out[2], where=den > 0)
    np.clip(out[2], -1.0, 1.0, out=out[2])


def nine_maps(stokes3: ArrayLike, *, eps: float = 1e-6) -> NDArray:
    """The network's nine input maps from measured Stokes ``(s0, s1, s3)`` per colour.

    .. math:: LP = -s_1,\\quad unpol = s_0 - LP = s_0 + s_1,\\quad CP = s_3 / (s_0 + \\epsilon)

    ``CP`` is 0 where ``s0 + eps <= 0`` and clipped to [-1, 1] (|s3| <= s0 physically; noise can
    exceed it). ``unpol`` and ``LP`` are not clipped, so their noise stays unbiased.

    Args:
        stokes3: ``(..., 3, 3)`` colour x ``(s0, s1, s3)``.
        eps: regulariser of the CP denominator, in radiance units.

    Returns:
        ``(..., 9)`` maps in the order of :data:`NINE_MAP_NAMES`.

    Example:
        Pure display light (vertical, s1 = -s0) is all LP; unpolarized light is all unpol:

        >>> s = np.array([[[1.0, -1.0, 0.0]] * 3, [[1.0, 0.0, 0.0]] * 3])
        >>> nine_maps(s, eps=0.0)[:, :6] + 0.0  # + 0.0 turns -0.0 into 0.0
        array([[0., 0., 0., 1., 1., 1.],
               [1., 1., 1., 0., 0., 0.]])
    """
    s = np.asarray(stokes3)
    if s.shape[-2:] != (3, 3):
        raise ValueError(f"stokes must have shape (..., 3, 3) = colour x (s0, s1, s3); got {s.shape}")
    out = np.empty((3, 3, *s.shape[:-2]), dtype=s.dtype)  # (kind, colour, ...)
    s0, s1, s3 = (np.moveaxis(s[..., k], -1, 0) for k in range(3))  # each (colour, ...)
    _maps_planar(s0, s1, s3, out, eps)
    out = out.reshape(9, *s.shape[:-2])
    return np.moveaxis(out, 0, -1)


def _maps_surely_finite(r: NDArray, t: NDArray, sensor: SensorParams, dec: NDArray) -> bool:
    """True when the raws' range bounds every map and their sum far below float32 overflow.

    ``|merged| <= E (max|raw| + black) / (g min t)``; interpolation is convex and
    ``|s_k| <= sum_a |dec[k, a]| max|merged|``, so the nine maps sum to less than ``9 max|s| + 3``.
    """
    if r.dtype.kind in "iu":
        top = float(max(-int(np.iinfo(r.dtype).min), int(np.iinfo(r.dtype).max)))
    else:
        top = max(abs(float(r.max())), abs(float(r.min())))
    merged = r.shape[0] * (top + sensor.black_level) / (sensor.dn_per_unit_second * float(t.min()))
    return bool(18.0 * merged * float(np.abs(dec).sum(axis=-1).max()) + 3.0 < 1e37)


def decode(
    raws: ArrayLike,
    model: CameraModel,
    *,
    grid: str = "half",
    eps: float = 1e-6,
    min_signal: float = 0.0,
    dark: ArrayLike | None = None,
) -> Decoded:
    """Raw HDR bracket -> nine maps, measured Stokes and validity mask.

    Rig imperfections of ``model`` are inverted (:mod:`pbrdf.sensor.imperfections`): the dark
    frames are subtracted per exposure, vignetting is divided out of the merged mosaic and the
    channels are unmixed with the inverse cross-talk. ``model.ambient`` itself is not subtracted
    (only a dark frame measures it with the vignetting and sensor offset that go with it).

    Args:
        raws: ``(E, H, W)`` raw frames, one per exposure of ``model.exposures``.
        model: the calibrated camera model.
        dark: ``(E, H, W)`` dark frames (display off, same bracket), or None.
        grid: output grid, ``"half"`` (default, ``(H/2, W/2)``) or ``"full"`` (``(H, W)``).
        eps: CP regulariser (:func:`nine_maps`).
        min_signal: pixels whose total ``s0`` (summed over the colours) is not above this are
            masked out (background, all-dark pixels).

    Returns:
        :class:`Decoded` with ``maps`` ``(H', W', 9)``, ``mask`` ``(H', W')``, ``stokes``
        ``(H', W', 3, 3)``.
    """
    r, t = _checked_bracket(raws, model.exposures)
    if dark is not None:
        r = subtract_dark(r, dark, model.sensor)
    h, w = r.shape[1:]
    dec = _decoding_matrix(model)
    interp = _Interpolator((h, w), grid, model.pattern_offset, dec)
    padded, valid_b = _merge_padded(r, t, model.sensor, model.pattern_offset, _PAD)
    unmix = None if model.crosstalk == IDENTITY3 else np.linalg.inv(np.asarray(model.crosstalk)).astype(np.float32)
    if np.isfinite(model.vignetting_focal_px) or any(model.vignetting_poly):
        padded[_PAD:-_PAD, _PAD:-_PAD] /= vignetting_map((h, w), model.vignetting_focal_px, model.vignetting_poly)
        _fill_pad(padded, _PAD)
    hh, ww = interp.out_h, interp.out_w
    st = np.empty((3, 3, hh, ww), dtype=np.float32)  # colour, (s0, s1, s3)
    maps = np.empty((hh, ww, 9), dtype=np.float32)
    mask = np.empty((hh, ww), dtype=bool)
    # A pixel is valid only if no input sample of its interpolation support (+-2 blocks) was
    # unmeasured: the validity of the 2x2 blocks, eroded by 2 blocks.
    block_valid = valid_b[: h // 2, : w // 2]
    all_valid = bool(block_valid.all())
    if not all_valid:
        block_valid = _erode_blocks(block_valid)
    finite = _maps_surely_finite(r, t, model.sensor, dec) and model.nominal_rig
    planes = np.empty((3, 3, interp.strip_rows, ww), dtype=np.float32)  # kind, colour
    for y0, y1 in interp.strips(padded, st):
        s, m = st[:, :, y0:y1], planes[:, :, : y1 - y0]
        if unmix is not None:  # camera channel c = sum_r M[c, r] region r  ->  regions = M^-1 channels
            s[...] = np.einsum("rc,c...->r...", unmix, s)
        _maps_planar(s[:, 0], s[:, 1], s[:, 2], m, eps)
        ok = mask[y0:y1]
        np.greater(s[0, 0] + s[1, 0] + s[2, 0], min_signal, out=ok)
        if not all_valid:
            ok &= block_valid[y0:y1] if grid == "half" else _upsample2(block_valid[y0 // 2 : y1 // 2])
        if not finite:
            ok &= np.isfinite(m.reshape(9, y1 - y0, ww).sum(axis=0))
        if not ok.all():
            np.copyto(m, 0.0, where=~ok)
        np.copyto(maps[y0:y1], np.moveaxis(m.reshape(9, y1 - y0, ww), 0, -1))
    return Decoded(maps=maps, mask=mask, stokes=np.moveaxis(st, (0, 1), (2, 3)))


def subtract_dark(raws: ArrayLike, dark: ArrayLike, sensor: SensorParams) -> NDArray[np.float32]:
    """Raws minus their dark frames in DN, black level kept: ``raw - dark + black_level`` (float32).

    Pixels saturated in the raw stay at the white level, so the HDR merge still rejects them.

    Args:
        raws: ``(E, H, W)`` raw frames.
        dark: ``(E, H, W)`` dark frames of the same bracket (display off: ambient and sensor offset).
        sensor: the sensor (black and white level, saturation).

    Returns:
        ``(E, H, W)`` float32 raws for :func:`hdr_merge` / :func:`decode`.
    """
    r = np.asarray(raws)
    d = np.asarray(dark)
    if d.shape != r.shape:
        raise ValueError(f"dark frames must have the shape of the raws {r.shape}; got {d.shape}")
    if d.dtype.kind == "f" and not np.all(np.isfinite(d)):
        raise ValueError("dark frames contain NaN or Inf")
    out = r.astype(np.float32) - d.astype(np.float32) + np.float32(sensor.black_level)
    saturated = r >= sensor.saturation * sensor.white_level
    out[saturated] = sensor.white_level
    return out


def _upsample2(a: NDArray) -> NDArray:
    return np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)


def estimate_pattern_offset(raw: ArrayLike, stokes_rgb: ArrayLike, model: CameraModel) -> tuple[int, int]:
    """Find where raw pixel (0, 0) sits in the 4x4 table from a capture of a known scene.

    Tries all 16 offsets and returns the one whose simulated mosaic best explains the raw (least
    squares with a free gain and offset). Used to catch a 1-pixel ROI shift, which would
    silently swap analyzer angles and colours.

    Args:
        raw: ``(H, W)`` one linear raw frame (or an HDR merge).
        stokes_rgb: ``(H, W, 3, 4)`` the known Stokes images of the calibration scene.
        model: camera model (its ``pattern_offset`` is ignored).

    Returns:
        ``(row, col)`` offset in 0..3.
    """
    y = np.asarray(raw, dtype=np.float64).ravel()
    best, best_err = (0, 0), np.inf
    for r in range(4):
        for c in range(4):
            x = mosaic(stokes_rgb, model.replace(pattern_offset=(r, c))).astype(np.float64).ravel()
            design = np.stack([x, np.ones_like(x)], axis=1)
            coef, *_ = np.linalg.lstsq(design, y, rcond=None)
            err = float(np.sum((design @ coef - y) ** 2))
            if err < best_err:
                best, best_err = (r, c), err
    return best
