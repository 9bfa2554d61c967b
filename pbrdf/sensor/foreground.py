"""The object (foreground) mask of a capture, from the capture alone.

A capture shows the object lit by the display in front of a dark background; the decoder's
validity mask (:attr:`pbrdf.sensor.decode.Decoded.mask`) keeps every measured pixel, and with the
default ``min_signal = 0`` about half of the pure-noise background passes it. This module finds
the object instead, without a ground-truth mask:

1. The signal is the HDR radiance ``unpol + LP = s0``, summed over the three colours
   (:func:`capture_signal`). On the dark background it is read noise around 0.
2. Its noise floor ``sigma`` follows from the camera model (:func:`noise_floor`: read noise,
   gain, quantisation and the exposure bracket, propagated exactly through the HDR merge, the
   bilinear demosaic and the Stokes fit). :func:`background_level` then measures the dark
   background of the capture itself: its level (a black-level error shifts it) and its spread,
   which raises ``sigma`` where the real sensor is noisier than its model.
3. :func:`foreground_mask`: seeds are the pixels above ``level + k_sigma * sigma``. The
   demosaic (and the lens) blur the object's silhouette by a few pixels, so a seed within
   ``edge_radius`` pixels of the seeds' outline also has to reach ``edge_fraction`` of the
   brightest signal around it (the blurred halo outside the silhouette does not; seeds deeper
   inside are kept, so highlights do not carve the object). A small opening removes spurs and
   one-pixel bridges, components smaller than ``min_area`` pixels or ``min_fraction`` of the
   largest one are dropped (hot pixels, noise blobs), and holes enclosed by the object are
   filled, so dark (metal, black paint) parts inside the silhouette stay in the mask.

Dark parts *on* the silhouette whose signal is under the noise floor cannot be told from the
background, and a highlight within a few pixels of the silhouette can trim the outline next to
it by up to ``edge_radius`` pixels; put a ``mask.png`` in the capture folder for such objects
(:mod:`pbrdf.data.capture`). Everything is vectorised numpy plus :func:`scipy.ndimage.label`,
deterministic, and works on either decode grid (:func:`capture_foreground` picks the grid's
defaults).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.decode import Decoded, demosaic, stokes_from_intensities

__all__ = [
    "GRID_DEFAULTS",
    "capture_signal",
    "noise_floor",
    "background_level",
    "foreground_mask",
    "capture_foreground",
]

#: :func:`foreground_mask` parameters that depend on the decode grid: lengths and areas in output
#: pixels (the ``"full"`` grid has twice the pixels per side of the ``"half"`` grid).
GRID_DEFAULTS = {
    "half": {"edge_radius": 2, "open_radius": 1, "min_area": 64},
    "full": {"edge_radius": 4, "open_radius": 2, "min_area": 256},
}

# 8-connected components for the object, 4-connected ones for the background (complementary).
_EIGHT = np.ones((3, 3), dtype=bool)


def capture_signal(stokes: ArrayLike) -> NDArray[np.float32]:
    """The radiance the mask is found on: ``unpol + LP = s0``, summed over the colours.

    Args:
        stokes: ``(H, W, 3, 3)`` measured Stokes per colour, ``(s0, s1, s3)``
            (:attr:`pbrdf.sensor.decode.Decoded.stokes`).

    Returns:
        ``(H, W)`` float32; non-finite pixels are 0.

    Example:
        >>> s = np.zeros((1, 2, 3, 3), np.float32)
        >>> s[0, 1, :, 0] = 0.5
        >>> capture_signal(s)
        array([[0. , 1.5]], dtype=float32)
    """
    s = np.asarray(stokes)
    if s.ndim != 4 or s.shape[-2:] != (3, 3):
        raise ValueError(f"stokes must have shape (H, W, 3, 3) = colour x (s0, s1, s3); got {s.shape}")
    s0 = s[..., 0]
    signal = (s0[..., 0] + s0[..., 1] + s0[..., 2]).astype(np.float32, copy=False)
    if not np.isfinite(signal).all():
        signal = np.where(np.isfinite(signal), signal, np.float32(0.0))
    return signal


def noise_floor(model: CameraModel, *, grid: str = "half") -> float:
    """Standard deviation of :func:`capture_signal` on a dark pixel, from the camera model.

    A dark raw pixel carries read noise and quantisation, ``K^2 sigma_r^2 + 1/12`` DN^2
    (:func:`pbrdf.sensor.camera.expose`). The HDR merge sums the ``E`` unsaturated exposures and
    divides by ``K * electrons_per_unit * sum(t)``; the demosaic and the Stokes fit are linear, so
    the variance of ``s0`` summed over colours is the merged variance times the sum of squared
    weights of that linear map, computed exactly from impulse responses (interior pixels; the
    four or sixteen output phases are averaged, they differ by a few percent).

    Args:
        model: the capture's camera model (sensor noise, exposures, optics, pattern offset).
        grid: the decode grid, ``"half"`` or ``"full"``.

    Returns:
        ``sigma`` in radiance units (the units of :attr:`pbrdf.sensor.decode.Decoded.stokes`).

    Example:
        >>> round(noise_floor(CameraModel()) * 1e5, 2)  # IMX250 at 12 bit, 10/20/100/200 ms
        2.37
    """
    if grid not in GRID_DEFAULTS:
        raise ValueError(f"grid must be 'half' or 'full'; got {grid!r}")
    return _noise_floor(model, grid)


@functools.lru_cache(maxsize=16)
def _noise_floor(model: CameraModel, grid: str) -> float:
    sensor = model.sensor
    dn_var = (sensor.gain * sensor.read_noise) ** 2 + 1.0 / 12.0
    t = np.asarray(model.exposures, dtype=np.float64)
    merged_var = t.size * dn_var / (float(t.sum()) * sensor.dn_per_unit_second) ** 2
    # One impulse per phase of the 4x4 super-pixel, far enough apart (24 px) that the responses
    # (+-4 raw pixels) do not overlap; the responses cover every output phase equally often.
    spacing, n = 24, 4 * 24 + 16
    img = np.zeros((n, n), dtype=np.float64)
    for i in range(4):
        for j in range(4):
            img[8 + i * spacing + i, 8 + j * spacing + j] = 1.0
    planes = demosaic(img, grid=grid, pattern_offset=model.pattern_offset).astype(np.float64)
    response = stokes_from_intensities(planes, model)[..., 0].sum(axis=-1)
    phases = 4 if grid == "half" else 16
    return math.sqrt(merged_var * float(np.sum(response**2)) / phases)


def background_level(
    signal: ArrayLike,
    sigma: float,
    *,
    window: float = 20.0,
    stride: int | None = None,
    min_count: int = 256,
) -> tuple[float, float]:
    """Level and noise of the dark background, measured on the capture itself.

    The candidates are the pixels (every ``stride``-th row and column) within ``window * sigma``
    of 0. Their median is the background level, and the spread of the candidates *below* it
    (signal only adds light, so the lower side is pure noise) is the measured noise:
    ``1.4826 * median(level - x | x < level)``, never taken below ``sigma``.

    Args:
        signal: ``(H, W)`` :func:`capture_signal`.
        sigma: the model's noise floor (:func:`noise_floor`), > 0.
        window: half-width of the candidate range, in ``sigma``.
        stride: subsampling of the estimate (speed; the result depends on it only
            statistically); None: the largest stride that keeps about 65 536 samples.
        min_count: with fewer candidates (no visible background) ``(0.0, sigma)`` is returned.

    Returns:
        ``(level, noise)`` in the units of ``signal``.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> level, noise = background_level(rng.normal(3.0, 2.0, (256, 256)), 1.0)
        >>> round(level), round(noise)
        (3, 2)
    """
    if not sigma > 0 or not math.isfinite(sigma):
        raise ValueError(f"sigma must be positive and finite; got {sigma}")
    x = np.asarray(signal)
    if stride is None:
        stride = max(1, math.isqrt(x.size // 65536))
    sub = x[::stride, ::stride].ravel()
    cand = sub[np.abs(sub) < window * sigma]
    if cand.size < min_count:
        return 0.0, float(sigma)
    level = float(np.median(cand))
    below = level - cand[cand < level]
    if below.size < min_count // 2:  # pragma: no cover - a median leaves half on each side
        return level, float(sigma)
    return level, max(float(sigma), 1.4826 * float(np.median(below)))


def _sliding(a: NDArray, radius: int, op, axis: int) -> NDArray:
    """Sliding ``op`` (maximum, logical and/or) over ``2 radius + 1`` samples along ``axis``.

    The window is cut at the array's ends. Forward windows grow by doubling (about
    ``log2(2 radius + 1)`` passes instead of ``2 radius``) and are then centred.
    """
    n = a.shape[axis]
    r = min(radius, n - 1)
    if r <= 0:
        return a.copy()
    length = 2 * r + 1

    def part(start: int, stop: int) -> tuple[slice, ...]:
        index = [slice(None)] * a.ndim
        index[axis] = slice(start, stop)
        return tuple(index)

    fwd = a.copy()  # fwd[i] = op(a[i : i + k]), cut at the end
    k = 1
    while 2 * k <= length:
        if k < n:
            op(fwd[part(0, n - k)], fwd[part(k, n)], out=fwd[part(0, n - k)])
        k *= 2
    rest = length - k  # the windows [i, i + k) and [i + rest, i + length) overlap
    if 0 < rest < n:
        op(fwd[part(0, n - rest)], fwd[part(rest, n)], out=fwd[part(0, n - rest)])
    out = np.empty_like(a)
    out[part(r, n)] = fwd[part(0, n - r)]
    # The first r outputs see the cut windows [0, i + r]: prefix reductions.
    head = op.accumulate(a[part(0, min(2 * r, n))], axis=axis)
    out[part(0, r)] = np.take(head, np.minimum(np.arange(r, 2 * r), n - 1), axis=axis)
    return out


def _square_filter(a: NDArray, radius: int, op) -> NDArray:
    """Separable ``op`` filter over a ``(2 radius + 1)^2`` square, cut at the border."""
    if radius <= 0:
        return a.copy()
    return _sliding(_sliding(a, radius, op, 0), radius, op, 1)


def _edge_test(above: NDArray[np.float32], band: NDArray[np.bool_], fraction: float, radius: int) -> NDArray[np.bool_]:
    """Where ``band``: ``above >= fraction * max(above over the (2 radius + 1)^2 square)``.

    The square is cut at the image border. A narrow band (the usual outline) gathers its
    neighbourhoods directly; a wide one (a textured or noisy frame) filters the whole image.
    Both give the same result.
    """
    ys, xs = np.nonzero(band)
    h, w = above.shape
    passed = np.zeros_like(band)
    if ys.size * (2 * radius + 1) ** 2 > above.size:
        ref = _square_filter(above, radius, np.maximum)
        passed[ys, xs] = above[ys, xs] >= np.float32(fraction) * ref[ys, xs]
        return passed
    ref = np.full(ys.shape, -np.inf, dtype=above.dtype)
    for dy in range(-radius, radius + 1):
        rows = np.clip(ys + dy, 0, h - 1)  # clipping repeats the border: the same maximum as a cut window
        for dx in range(-radius, radius + 1):
            np.maximum(ref, above[rows, np.clip(xs + dx, 0, w - 1)], out=ref)
    passed[ys, xs] = above[ys, xs] >= np.float32(fraction) * ref
    return passed


def _opening(mask: NDArray[np.bool_], radius: int) -> NDArray[np.bool_]:
    """Binary opening with a square; the outside counts as 'same as the border' (no erosion there)."""
    if radius <= 0:
        return mask
    return _square_filter(_square_filter(mask, radius, np.logical_and), radius, np.logical_or)


def _fill_holes(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Fill the background regions (4-connected) that do not touch the image border.

    Only the bounding box of the mask (plus a one-pixel ring) is labelled: everything outside it
    is background connected to the border.
    """
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return mask
    h, w = mask.shape
    y0, y1 = max(rows[0] - 1, 0), min(rows[-1] + 2, h)
    x0, x1 = max(cols[0] - 1, 0), min(cols[-1] + 2, w)
    labels, n = ndimage.label(~mask[y0:y1, x0:x1])
    if n == 0:
        return mask
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    hole = np.ones(n + 1, dtype=bool)
    hole[border] = False
    hole[0] = False
    if not hole.any():
        return mask
    out = mask.copy()
    out[y0:y1, x0:x1] |= hole[labels]
    return out


def _blocks(mask: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], NDArray[np.uint8]]:
    """2x2 blocks of a mask (odd sizes padded with False): ``(any pixel set, pixels set)``."""
    h, w = mask.shape
    m = mask if not (h % 2 or w % 2) else np.pad(mask, ((0, h % 2), (0, w % 2)))
    q = [m[i::2, j::2] for i in (0, 1) for j in (0, 1)]
    count = q[0].astype(np.uint8)
    for part in q[1:]:
        count += part
    return count > 0, count


def _large_components(mask: NDArray[np.bool_], min_area: int, min_fraction: float) -> NDArray[np.bool_]:
    """Drop components under ``min_area`` pixels or ``min_fraction`` of the largest one.

    Components are the 8-connected components of the 2x2 blocks that hold a mask pixel (so
    parts less than about two pixels apart belong together); their areas count mask pixels.
    Working on blocks makes the labelling about four times cheaper.
    """
    occupied, count = _blocks(mask)
    labels, n = ndimage.label(occupied, structure=_EIGHT)
    if n == 0:
        return mask
    area = np.bincount(labels.ravel(), weights=count.ravel(), minlength=n + 1)
    area[0] = 0.0
    keep = area >= max(min_area, min_fraction * area.max())
    keep[0] = False
    if keep[1:].all():
        return mask
    h, w = mask.shape
    hb, wb = labels.shape
    kept = np.broadcast_to(keep[labels][:, None, :, None], (hb, 2, wb, 2)).reshape(2 * hb, 2 * wb)[:h, :w]
    return mask & kept


def foreground_mask(
    signal: ArrayLike,
    sigma: float,
    *,
    level: float = 0.0,
    k_sigma: float = 5.0,
    edge_fraction: float = 0.25,
    edge_radius: int = 2,
    open_radius: int = 1,
    min_area: int = 64,
    min_fraction: float = 0.05,
    fill_holes: bool = True,
) -> NDArray[np.bool_]:
    """The object mask of a dark-background image: noise threshold, edge test, morphology.

    Args:
        signal: ``(H, W)`` radiance (:func:`capture_signal`); non-finite pixels count as dark.
        sigma: noise standard deviation of ``signal`` on the background, > 0
            (:func:`noise_floor`, :func:`background_level`).
        level: signal of the empty background (:func:`background_level`).
        k_sigma: seeds are the pixels above ``level + k_sigma * sigma`` (5: about one pure-noise
            pixel in 3.5 million passes, before the area test).
        edge_fraction: a seed within ``edge_radius`` pixels of the seeds' outline must also
            reach this fraction of the brightest signal around it (both above ``level``): the
            blurred halo around the silhouette does not (a sharp edge decodes to about 3 %,
            28 %, 72 %, 97 % of its plateau on the half grid); 0 turns the test off.
        edge_radius: width of that band and radius of "around" (the ``(2 r + 1)^2`` square),
            in pixels: about the blur of the silhouette (the demosaic spreads it by 2 half-grid
            pixels).
        open_radius: radius of the square opening (removes spurs and bridges thinner than
            ``2 open_radius + 1`` pixels); 0 turns it off.
        min_area: components (8-connected) with fewer pixels are dropped.
        min_fraction: components smaller than this fraction of the largest one are dropped.
        fill_holes: fill background regions enclosed by the object (dark parts of the object;
            also a real hole through it, e.g. a handle).

    Returns:
        ``(H, W)`` bool, True on the object; all False when nothing rises above the noise.

    Example:
        A bright square with a dark patch inside, on a noisy black background:

        >>> rng = np.random.default_rng(0)
        >>> img = rng.normal(0.0, 1.0, (64, 64))
        >>> img[16:48, 16:48] += 100.0
        >>> img[28:36, 28:36] = 0.0
        >>> mask = foreground_mask(img, 1.0)
        >>> int(mask.sum()), bool(mask[32, 32]), bool(mask[8, 8])
        (1024, True, False)
    """
    x = np.asarray(signal)
    if x.ndim != 2:
        raise ValueError(f"signal must be a 2-D (H, W) image; got shape {x.shape}")
    if not sigma > 0 or not math.isfinite(sigma):
        raise ValueError(f"sigma must be positive and finite; got {sigma}")
    if not 0.0 <= edge_fraction < 1.0:
        raise ValueError(f"edge_fraction must be in [0, 1); got {edge_fraction}")
    if min(edge_radius, open_radius, min_area) < 0 or not 0.0 <= min_fraction <= 1.0:
        raise ValueError("edge_radius, open_radius and min_area must be >= 0 and min_fraction in [0, 1]")
    x = x.astype(np.float32, copy=False)
    if not np.isfinite(x).all():
        x = np.where(np.isfinite(x), x, np.float32(level))
    above = x - np.float32(level)
    mask = above > np.float32(k_sigma * sigma)
    if not mask.any():
        return mask
    if edge_fraction > 0.0 and edge_radius > 0:
        # Only the band within edge_radius of the seeds' outline is tested: the blur is there,
        # and a highlight inside the object must not carve its neighbours.
        band = mask & ~_square_filter(mask, edge_radius, np.logical_and)
        mask &= ~band | _edge_test(above, band, edge_fraction, edge_radius)
    mask = _large_components(_opening(mask, open_radius), min_area, min_fraction)
    if fill_holes:
        mask = _fill_holes(mask)
    return mask


def capture_foreground(decoded: Decoded, model: CameraModel, *, grid: str = "half", **kwargs) -> NDArray[np.bool_]:
    """The automatic object mask of a decoded capture (the module's steps 1-3).

    Args:
        decoded: the decoder's output for the capture (:func:`pbrdf.sensor.decode.decode`);
            only its ``stokes`` are used.
        model: the camera model it was decoded with (its noise floor sets the threshold).
        grid: the grid it was decoded on, ``"half"`` or ``"full"``; picks
            :data:`GRID_DEFAULTS`.
        **kwargs: overrides of :func:`foreground_mask`'s keyword arguments (``level`` and the
            noise come from :func:`background_level`).

    Returns:
        ``(H', W')`` bool object mask on the decode grid.
    """
    if grid not in GRID_DEFAULTS:
        raise ValueError(f"grid must be 'half' or 'full'; got {grid!r}")
    signal = capture_signal(decoded.stokes)
    level, sigma = background_level(signal, noise_floor(model, grid=grid))
    params = {**GRID_DEFAULTS[grid], "level": level, **kwargs}
    return foreground_mask(signal, sigma, **params)
