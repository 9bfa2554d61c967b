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

Convention (decomposition): the display emits vertically polarized light, ``s1 = -s0``, so the
polarized (specular) part is ``LP = -s1 >= 0`` and the unpolarized part is ``unpol = s0 + s1``.
The paper prints ``unpol = s0 - s1``, which would give ``2 s0`` for pure display light; we use the
consistent form. Map order: ``[R_unpol, G_unpol, B_unpol, R_LP, G_LP, B_LP, R_CP, G_CP, B_CP]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from pbrdf.sensor.camera import CameraModel, SensorParams, measurement_matrix, mosaic, mosaic_indices

__all__ = [
    "NINE_MAP_NAMES",
    "Decoded",
    "hdr_merge",
    "demosaic",
    "stokes_from_intensities",
    "nine_maps",
    "decode",
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


def hdr_merge(
    raws: ArrayLike,
    exposures: ArrayLike,
    sensor: SensorParams,
    *,
    pattern_offset: tuple[int, int] = (0, 0),
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Merge an exposure bracket of raw mosaics into one linear mosaic.

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
    r = np.asarray(raws)
    t = np.asarray(exposures, dtype=np.float64).reshape(-1)
    _check_raws(r, t.size)
    if np.any(t <= 0) or not np.all(np.isfinite(t)):
        raise ValueError(f"exposure times must be positive and finite; got {t}")
    if r.dtype.kind == "f" and not np.all(np.isfinite(r)):
        raise ValueError("raw frames contain NaN or Inf")
    e, h, w = r.shape
    # Align 2x2 blocks: pad one row/column in front when the offset is odd.
    pr, pc = pattern_offset[0] % 2, pattern_offset[1] % 2
    if pr or pc:
        r = np.pad(r, ((0, 0), (pr, pr), (pc, pc)), mode="edge")
    # The four pixels of each 2x2 block as strided views (E, H/2, W/2): faster than a reshape
    # reduction over non-adjacent axes.
    phases = [r[:, di::2, dj::2] for di in (0, 1) for dj in (0, 1)]
    block_max = np.maximum(np.maximum(phases[0], phases[1]), np.maximum(phases[2], phases[3]))
    # v[j]: all four analyzer pixels of the block below the saturation threshold in exposure j.
    v = block_max < sensor.saturation * sensor.white_level
    den = np.zeros(v.shape[1:], dtype=np.float32)
    for j in range(e):
        den += np.float32(t[j]) * v[j]
    count = v.sum(axis=0, dtype=np.float32)
    valid_b = den > 0
    shortest = int(np.argmin(t))
    scale = np.float32(1.0 / sensor.dn_per_unit_second)
    # Pixels saturated in every exposure fall back to the shortest one (and are flagged).
    rate = np.where(valid_b, scale / np.where(valid_b, den, 1.0), scale / np.float32(t[shortest]))
    offset = np.float32(sensor.black_level) * np.where(valid_b, count, 1.0)
    merged = np.empty(r.shape[1:], dtype=np.float32)
    for k, (di, dj) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        num = np.where(valid_b, np.float32(0.0), phases[k][shortest].astype(np.float32))
        for j in range(e):
            np.add(num, phases[k][j], out=num, where=v[j])
        num -= offset
        num *= rate
        merged[di::2, dj::2] = num
    valid = np.repeat(np.repeat(valid_b, 2, axis=0), 2, axis=1)
    if pr or pc:
        merged = merged[pr : pr + h, pc : pc + w]
        valid = valid[pr : pr + h, pc : pc + w]
    return np.ascontiguousarray(merged), np.ascontiguousarray(valid)


def _grid_positions(n: int, grid: str) -> NDArray[np.float64]:
    if grid == "full":
        return np.arange(n, dtype=np.float64)
    if grid == "half":
        return 2.0 * np.arange(n // 2) + 0.5
    raise ValueError(f"grid must be 'full' or 'half'; got {grid!r}")


def _phases(n_src: int, offset: int, targets: NDArray) -> list[tuple[slice, int, float]]:
    """Linear interpolation from samples at ``offset + 4 m`` (``m < n_src``) to ``targets``.

    Both output grids advance by 4 raw pixels every ``period`` outputs (4 for "full", 2 for
    "half"), so the weights repeat: output ``p::period`` reads padded samples ``m_p + 1 + n`` and
    ``m_p + 2 + n`` with one weight ``w_p``. Samples are edge-padded by one on each side, which
    clamps to the nearest sample outside the sampled range.

    Returns:
        ``[(output slice, first padded index, weight of the second sample), ...]`` per phase.
    """
    period = 4 if np.all(np.diff(targets[:5]) == 1) else 2
    out = []
    for p in range(min(period, targets.size)):
        u = (targets[p] - offset) / 4.0
        m = int(np.floor(u))
        count = len(range(p, targets.size, period))
        start = min(max(m + 1, 0), n_src + 1)
        w = float(np.clip(u - m, 0.0, 1.0)) if 0 <= m + 1 <= n_src else 0.0
        if start + count + 1 > n_src + 2:  # beyond the last sample: clamp
            raise AssertionError("interpolation phase out of range")  # pragma: no cover
        out.append((slice(p, None, period), start, w))
    return out


def _resample_axis0(src: NDArray, phases: list, dst: NDArray, scale: float, accumulate: bool, scratch: NDArray) -> None:
    """``dst (+)= scale * interp(src)`` along axis 0 without temporaries (``scratch`` >= one phase)."""
    padded = np.concatenate([src[:1], src, src[-1:]], axis=0)
    for sl, start, w in phases:
        view = dst[sl]
        count = view.shape[0]
        tmp = scratch[:count]
        lo = padded[start : start + count]
        hi = padded[start + 1 : start + 1 + count]
        a, b = np.float32(scale * (1.0 - w)), np.float32(scale * w)
        if accumulate:
            np.multiply(lo, a, out=tmp)
            view += tmp
        else:
            np.multiply(lo, a, out=view)
        if w != 0.0:
            np.multiply(hi, b, out=tmp)
            view += tmp


def _column_weights(n_src: int, offset: int, targets: NDArray) -> tuple[NDArray, NDArray]:
    """Gather indices and weights for interpolation along columns (nearest sample outside)."""
    u = (targets - offset) / 4.0
    i0 = np.clip(np.floor(u), 0, n_src - 2).astype(np.intp)
    return i0, np.clip(u - i0, 0.0, 1.0).astype(np.float32)


def _demosaic_planar(img: NDArray, grid: str, pattern_offset: tuple[int, int]) -> NDArray[np.float32]:
    """Planar demosaic: ``(H, W)`` -> ``(3, 4, H', W')`` (colour, angle, rows, cols)."""
    h, w = img.shape
    ys, xs = _grid_positions(h, grid), _grid_positions(w, grid)
    color, angle = mosaic_indices(pattern_offset)
    out = np.empty((3, 4, ys.size, xs.size), dtype=np.float32)
    written = np.zeros((3, 4), dtype=bool)
    scratch = np.empty(((ys.size + 1) // 2, xs.size), dtype=np.float32)
    for i in range(4):
        row_phases = _phases(h // 4, i, ys)
        for j in range(4):
            c, a = color[i, j], angle[i, j]
            lattice = img[i::4, j::4]
            # Columns by gather on the small (H/4, W') array, rows by periodic slices of the
            # large one: every pass over the output is contiguous.
            ci, cw = _column_weights(w // 4, j, xs)
            cols = lattice[:, ci]
            cols += (lattice[:, ci + 1] - cols) * cw
            scale = 0.5 if c == 1 else 1.0  # two green lattices per angle: average them
            _resample_axis0(cols, row_phases, out[c, a], scale, bool(written[c, a]), scratch)
            written[c, a] = True
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
    return np.moveaxis(_demosaic_planar(img, grid, pattern_offset), (0, 1), (2, 3))


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


def nine_maps(stokes3: ArrayLike, *, eps: float = 1e-6, channel_axis: int = -1) -> NDArray:
    """The network's nine input maps from measured Stokes ``(s0, s1, s3)`` per colour.

    .. math:: LP = -s_1,\\quad unpol = s_0 - LP = s_0 + s_1,\\quad CP = s_3 / (s_0 + \\epsilon)

    ``CP`` is 0 where ``s0 + eps <= 0`` and clipped to [-1, 1] (|s3| <= s0 physically; noise can
    exceed it). ``unpol`` and ``LP`` are not clipped, so their noise stays unbiased.

    Args:
        stokes3: ``(..., 3, 3)`` colour x ``(s0, s1, s3)``.
        eps: regulariser of the CP denominator, in radiance units.
        channel_axis: where the nine maps go in the output (-1: ``(..., 9)``; 0: ``(9, ...)``,
            the faster planar layout).

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
    s0, s1, s3 = s[..., 0], s[..., 1], s[..., 2]  # each (..., 3 colours)
    out = np.empty((3, 3, *s.shape[:-2]), dtype=s.dtype)  # (kind, colour, ...)
    cm = np.moveaxis
    lp = np.negative(cm(s1, -1, 0), out=out[1])
    np.subtract(cm(s0, -1, 0), lp, out=out[0])
    den = cm(s0, -1, 0) + eps
    out[2] = 0.0
    with np.errstate(over="ignore"):  # a subnormal den (eps = 0) overflows to +-inf; the clip makes it +-1
        np.divide(cm(s3, -1, 0), den, out=out[2], where=den > 0)
    np.clip(out[2], -1.0, 1.0, out=out[2])
    out = out.reshape(9, *s.shape[:-2])
    return out if channel_axis == 0 else np.moveaxis(out, 0, channel_axis)


def decode(
    raws: ArrayLike,
    model: CameraModel,
    *,
    grid: str = "half",
    eps: float = 1e-6,
    min_signal: float = 0.0,
) -> Decoded:
    """Raw HDR bracket -> nine maps, measured Stokes and validity mask.

    Args:
        raws: ``(E, H, W)`` raw frames, one per exposure of ``model.exposures``.
        model: the calibrated camera model.
        grid: output grid, ``"half"`` (default, ``(H/2, W/2)``) or ``"full"`` (``(H, W)``).
        eps: CP regulariser (:func:`nine_maps`).
        min_signal: pixels whose total ``s0`` (summed over the colours) is not above this are
            masked out (background, all-dark pixels).

    Returns:
        :class:`Decoded` with ``maps`` ``(H', W', 9)``, ``mask`` ``(H', W')``, ``stokes``
        ``(H', W', 3, 3)``.
    """
    merged, valid = hdr_merge(raws, model.exposures, model.sensor, pattern_offset=model.pattern_offset)
    planar = _demosaic_planar(merged, grid, model.pattern_offset)  # (3, 4, H', W')
    hh, ww = planar.shape[2:]
    # Stokes per colour as one small matrix product over all pixels: (3,3,4) @ (3,4,N).
    dec = _decoding_matrix(model).astype(np.float32)
    st = np.matmul(dec, planar.reshape(3, 4, hh * ww)).reshape(3, 3, hh, ww)  # colour, (s0,s1,s3)
    maps_planar = nine_maps(np.moveaxis(st, (0, 1), (2, 3)), eps=eps, channel_axis=0)
    # A pixel is valid only if no input sample of its interpolation support (+-2 blocks) was
    # unmeasured.
    block_valid = valid[::2, ::2]
    if not block_valid.all():
        block_valid = ndimage.minimum_filter(block_valid, size=5, mode="nearest")
    mask = block_valid if grid == "half" else np.repeat(np.repeat(block_valid, 2, 0), 2, 1)
    mask = mask & (st[:, 0].sum(axis=0) > min_signal)
    finite = np.isfinite(maps_planar.sum(axis=0))
    if not finite.all():
        mask &= finite
    maps = np.ascontiguousarray(np.moveaxis(maps_planar, 0, -1))
    if not mask.all():
        maps[~mask] = 0.0
    return Decoded(maps=maps, mask=mask, stokes=np.moveaxis(st, (0, 1), (2, 3)))


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
