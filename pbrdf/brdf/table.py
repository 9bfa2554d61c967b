"""Measured pBRDF tables: the :class:`PBRDFTable` type, its files, resampling, evaluation and tabulation.

A pBRDF table samples the Mueller-matrix BRDF of an isotropic material on a regular grid of
Rusinkiewicz angles and wavelengths, as in the KAIST pBRDF dataset (Baek et al. 2020, ``.pbsdf``,
5 bands) and the hyperspectral hpBRDF dataset (Moon et al. 2025, ``.hpbrdf``, 68 bands). Both are
Mitsuba ``tensor_file`` files (:mod:`pbrdf.io.tensorfile`) with the same fields, read by
:func:`load_table`:

==========  ======================================  =======  ===========================
field       shape                                   dtype    meaning
==========  ======================================  =======  ===========================
``phi_d``   ``(1, Np)``                             float32  difference azimuth, radians
``theta_d`` ``(1, Nd)``                             float32  difference angle, radians
``theta_h`` ``(1, Nh)``                             float32  half-vector angle, radians
``wvls``    ``(W,)``                                uint16   wavelengths, nm
``M``       ``(Np, Nd, Nh, W, 4, 4)``               float32  Mueller BRDF (no cos factor)
==========  ======================================  =======  ===========================

Convention:
    Directions, Rusinkiewicz angles and the plane-of-reflection Stokes frames of ``M`` are those
    of Mitsuba's ``measured_polarized`` plugin, defined in :mod:`pbrdf.brdf.rusinkiewicz`
    (``wi`` towards the camera, ``wo`` towards the light, radiance mode).

    * :func:`evaluate` rotates the table's frames into Mitsuba's implicit bases
      ``stokes_basis(-wo)`` and ``stokes_basis(wi)`` with
      :func:`pbrdf.polar.mueller.rotate_mueller_basis`; :func:`tabulate` is its inverse.
    * ``M`` is the BRDF *without* the ``cos theta_o`` factor; :func:`evaluate` multiplies by
      ``cos theta_o = wo_z`` and clamps ``m00 >= 0`` as the plugin does.
    * Interpolation is multilinear in ``(phi_d, theta_d, theta_h, wavelength)`` with clamping at
      the ends of each axis (Mitsuba's ``Marginal2D``); :func:`resample` additionally treats
      ``phi_d`` as periodic.

NaN bins: raw measurements mark invalid or unmeasured bins with NaN. A table keeps them
(:attr:`PBRDFTable.nan_mask`); :func:`resample` skips them with renormalised weights;
:func:`evaluate` returns a zero matrix wherever a NaN bin takes part in the interpolation, like
the plugin; :func:`save_table` with ``for_mitsuba=True`` writes them as zeros.

The tensor-file codec lives in :mod:`pbrdf.io.tensorfile` and the Rusinkiewicz geometry in
:mod:`pbrdf.brdf.rusinkiewicz`; their public names are re-exported here.

References:
    S.-H. Baek, T. Zeltner, H. J. Ku, I. Hwang, X. Tong, W. Jakob, M. H. Kim, "Image-based
    acquisition and modeling of polarimetric reflectance", ACM TOG 39(4):139, 2020.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_unit_vectors
from pbrdf.brdf.rusinkiewicz import directions_from_rusinkiewicz, reflection_frame_x, rusinkiewicz_from_directions
from pbrdf.io.errors import one_line
from pbrdf.io.tensorfile import read_tensor_file, write_tensor_file
from pbrdf.polar.mueller import rotate_mueller_basis, stokes_basis

__all__ = [
    "MITSUBA_MAX_BANDS",
    "TABLE_FIELDS",
    "PBRDFTable",
    "save_table",
    "load_table",
    "resample",
    "to_mitsuba_bands",
    "evaluate",
    "tabulate",
    # re-exported from pbrdf.io.tensorfile and pbrdf.brdf.rusinkiewicz
    "write_tensor_file",
    "read_tensor_file",
    "rusinkiewicz_from_directions",
    "directions_from_rusinkiewicz",
]

#: The stock ``measured_polarized`` plugin copies the wavelengths into a fixed 5-element array.
MITSUBA_MAX_BANDS = 5
#: Field names of a pBRDF table in a tensor file (the ones ``measured_polarized`` reads).
TABLE_FIELDS = ("phi_d", "theta_d", "theta_h", "wvls", "M")
# Optional extra field with {"name": ..., "metadata": {...}} as UTF-8 JSON (uint8); the plugin ignores it.
_META_FIELD = "metadata_json"

# Axis ranges accept the float32 rounding of pi and pi/2 (8.7e-8) with a margin.
_ANGLE_TOL = 1e-5
_AXIS_NAMES = ("phi_d", "theta_d", "theta_h", "wavelengths")
_AXIS_RANGES = {
    "phi_d": (-np.pi - _ANGLE_TOL, np.pi + _ANGLE_TOL),
    "theta_d": (-_ANGLE_TOL, np.pi / 2 + _ANGLE_TOL),
    "theta_h": (-_ANGLE_TOL, np.pi / 2 + _ANGLE_TOL),
    "wavelengths": (np.finfo(np.float64).tiny, np.inf),
}

# Bytes reduced per step by nan_mask and resample.
_CHUNK_BYTES = 64 << 20


# --- the table type --------------------------------------------------------------------------------


def _axis(value: ArrayLike, name: str, lo: float, hi: float) -> NDArray[np.float64]:
    a = np.array(value, dtype=np.float64)  # a copy, made read-only below
    if a.ndim != 1 or a.size == 0:
        raise ValueError(f"PBRDFTable.{name} must be a non-empty 1-D array; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"PBRDFTable.{name} must be finite")
    if a.size > 1 and not np.all(np.diff(a) > 0):
        raise ValueError(f"PBRDFTable.{name} must be strictly increasing")
    if a[0] < lo or a[-1] > hi:
        raise ValueError(f"PBRDFTable.{name} must lie in [{lo:.6g}, {hi:.6g}]; got [{a[0]:.9g}, {a[-1]:.9g}]")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class PBRDFTable:
    """A tabulated isotropic Mueller-matrix BRDF on a Rusinkiewicz grid (see the module Convention).

    Attributes:
        phi_d: ``(Np,)`` difference azimuths, radians, strictly increasing in ``[-pi, pi]``.
        theta_d: ``(Nd,)`` difference angles, radians, strictly increasing in ``[0, pi/2]``.
        theta_h: ``(Nh,)`` half-vector angles, radians, strictly increasing in ``[0, pi/2]``.
        wavelengths: ``(W,)`` wavelengths in nm, strictly increasing, positive.
        M: ``(Np, Nd, Nh, W, 4, 4)`` float32 Mueller BRDF in 1/sr, *without* the ``cos theta_o``
            factor; NaN marks invalid bins. Kept as given when already float32 (a read-only
            memory map from :func:`load_table` stays one), converted otherwise.
        name: optional material name.
        metadata: free-form provenance (JSON-serialisable to be saved by :func:`save_table`).

    Raises:
        ValueError: an axis that is not 1-D, finite, strictly increasing and in range, or ``M`` of
            the wrong shape or a non-float dtype; the message names the field.

    Example:
        A Lambertian table with albedo 0.8 on a coarse grid:

        >>> t = PBRDFTable(np.linspace(-np.pi, np.pi, 5), np.linspace(0, np.pi / 2, 4),
        ...                np.linspace(0, np.pi / 2, 4), [450.0, 550.0, 650.0],
        ...                np.zeros((5, 4, 4, 3, 4, 4), np.float32) + np.diag([0.8 / np.pi, 0, 0, 0]))
        >>> t.shape
        (5, 4, 4, 3)
        >>> bool(t.nan_mask.any())
        False
    """

    phi_d: NDArray[np.float64]
    theta_d: NDArray[np.float64]
    theta_h: NDArray[np.float64]
    wavelengths: NDArray[np.float64]
    M: NDArray[np.float32]
    name: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in _AXIS_NAMES:
            set_(self, name, _axis(getattr(self, name), name, *_AXIS_RANGES[name]))
        m = self.M if isinstance(self.M, np.ndarray) else np.asarray(self.M)
        if m.dtype.kind not in "fiu":
            raise ValueError(f"PBRDFTable.M must be a real (float or integer) array; got dtype {m.dtype}")
        if m.dtype != np.float32:
            m = m.astype(np.float32)
        expected = (*self.shape, 4, 4)
        if m.shape != expected:
            raise ValueError(f"PBRDFTable.M must have shape (Np, Nd, Nh, W, 4, 4) = {expected}; got {m.shape}")
        set_(self, "M", m)
        if self.name is not None and not isinstance(self.name, str):
            raise ValueError(f"PBRDFTable.name must be a string or None; got {type(self.name).__name__}")
        if not isinstance(self.metadata, dict):
            raise ValueError(f"PBRDFTable.metadata must be a dict; got {type(self.metadata).__name__}")

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """Grid shape ``(Np, Nd, Nh, W)``."""
        return (self.phi_d.size, self.theta_d.size, self.theta_h.size, self.wavelengths.size)

    @property
    def nan_mask(self) -> NDArray[np.bool_]:
        """``(Np, Nd, Nh, W)`` bool, True for bins whose Mueller matrix has a NaN (or Inf) entry.

        Computed in chunks on each access (a memory-mapped table is read once).
        """
        out = np.empty(self.shape, dtype=bool)
        step = max(1, _CHUNK_BYTES // max(self.M[:1].nbytes, 1))
        for start in range(0, self.shape[0], step):
            block = np.asarray(self.M[start : start + step])
            out[start : start + step] = ~np.isfinite(block).all(axis=(-2, -1))
        return out

    def masked(self) -> np.ma.MaskedArray:
        """``M`` as a masked array ``(Np, Nd, Nh, W, 4, 4)`` with the NaN bins masked (loads ``M``).

        Example:
            >>> t = PBRDFTable([0.0], [0.0, 1.0], [0.0], [550.0], np.ones((1, 2, 1, 1, 4, 4)))
            >>> t.M[0, 1] = np.nan
            >>> float(t.masked()[..., 0, 0].mean())
            1.0
        """
        mask = np.broadcast_to(self.nan_mask[..., None, None], self.M.shape)
        return np.ma.MaskedArray(np.asarray(self.M), mask=mask)


# --- table files -----------------------------------------------------------------------------------


def _zero_nan_bins(block: NDArray) -> NDArray:
    bad = ~np.isfinite(block).all(axis=(-2, -1))
    return np.where(bad[..., None, None], np.float32(0), block) if bad.any() else block


def save_table(path: str | os.PathLike, table: PBRDFTable, *, for_mitsuba: bool = False) -> Path:
    """Save a table as a tensor file with the ``measured_polarized`` field names (atomic write).

    Fields: ``phi_d``, ``theta_d``, ``theta_h`` float32 ``(1, N)``; ``wvls`` uint16 ``(W,)``; ``M``
    float32 ``(Np, Nd, Nh, W, 4, 4)``; plus ``metadata_json`` (uint8, UTF-8 JSON of ``name`` and
    ``metadata``) when either is set. Mitsuba ignores the extra field.

    Args:
        path: target file (``.pbsdf`` by convention; the format does not depend on the suffix).
        table: the table; its wavelengths must be whole nanometres in [1, 65535] (``wvls`` is uint16).
        for_mitsuba: write NaN bins as zero matrices, and refuse more than
            :data:`MITSUBA_MAX_BANDS` bands (the stock plugin mishandles them; see
            :func:`to_mitsuba_bands`). With NaN bins kept, the plugin returns a zero matrix wherever
            one touches the interpolation; with zeros it blends towards zero instead.

    Returns:
        The path written.

    Raises:
        ValueError: non-integer wavelengths, too many bands with ``for_mitsuba``, or metadata
            that JSON cannot encode.
    """
    wl = table.wavelengths
    if np.any(wl != np.round(wl)) or wl[0] < 1 or wl[-1] > 0xFFFF:
        raise ValueError(f"wavelengths must be whole nanometres in [1, 65535] (stored as uint16 'wvls'); got {wl}")
    if for_mitsuba and wl.size > MITSUBA_MAX_BANDS:
        raise ValueError(
            f"table has {wl.size} bands; the stock measured_polarized plugin reads at most "
            f"{MITSUBA_MAX_BANDS}: use to_mitsuba_bands(table) first"
        )
    fields: dict[str, NDArray] = {
        "phi_d": table.phi_d.astype(np.float32)[None],
        "theta_d": table.theta_d.astype(np.float32)[None],
        "theta_h": table.theta_h.astype(np.float32)[None],
        "wvls": wl.astype(np.uint16),
        "M": table.M,
    }
    if table.name is not None or table.metadata:
        try:
            text = json.dumps({"name": table.name, "metadata": table.metadata}, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise ValueError(f"table metadata must be JSON-serialisable: {one_line(e)}") from None
        fields[_META_FIELD] = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    return write_tensor_file(path, fields, chunk_fns={"M": _zero_nan_bins} if for_mitsuba else None)


def _axis_field(fields: Mapping[str, NDArray], name: str, path: Path) -> NDArray:
    a = fields[name]
    if a.size == 0:
        raise ValueError(
            f"{path}: field {name!r} has shape {a.shape} and stores no axis values "
            "(like Mitsuba's spectralon_lowres.pbsdf test fixture); it is not a usable table"
        )
    if a.dtype.kind != "f" or a.ndim not in (1, 2) or (a.ndim == 2 and a.shape[0] != 1):
        raise ValueError(f"{path}: field {name!r} must be float (1, N) or (N,); got {a.dtype} {a.shape}")
    return np.asarray(a).reshape(-1)


def load_table(path: str | os.PathLike, *, mmap: bool = True) -> PBRDFTable:
    """Load a pBRDF table: KAIST ``.pbsdf`` (5 bands), hpBRDF ``.hpbrdf`` (68 bands) or :func:`save_table` output.

    Args:
        path: tensor file with the fields of :data:`TABLE_FIELDS`.
        mmap: memory-map ``M`` (read-only) instead of loading it; a multi-gigabyte hpBRDF file opens
            instantly and only the bins used are read.

    Returns:
        The table, NaN bins kept. ``name`` and ``metadata`` come from ``metadata_json`` when the
        file has it; otherwise ``name`` is the file name without suffix.

    Raises:
        ValueError: not a tensor file (see :func:`read_tensor_file`), a missing field, or fields
            of the wrong dtype or shape (the message names them).
    """
    p = Path(path)
    fields = read_tensor_file(p, mmap=mmap)
    missing = [k for k in TABLE_FIELDS if k not in fields]
    if missing:
        raise ValueError(
            f"{p}: not a pBRDF table: missing field(s) {', '.join(map(repr, missing))} (has {', '.join(fields)})"
        )
    axes = {k: _axis_field(fields, k, p) for k in ("phi_d", "theta_d", "theta_h")}
    wvls, m = fields["wvls"], fields["M"]
    if wvls.ndim != 1 or wvls.dtype.kind not in "uif":
        raise ValueError(f"{p}: field 'wvls' must be a 1-D numeric array; got {wvls.dtype} {wvls.shape}")
    if m.dtype != np.float32 or m.ndim != 6:
        raise ValueError(f"{p}: field 'M' must be float32 (Np, Nd, Nh, W, 4, 4); got {m.dtype} {m.shape}")
    name, metadata = p.stem, {}
    if _META_FIELD in fields:
        try:
            meta = json.loads(bytes(np.asarray(fields[_META_FIELD], dtype=np.uint8)).decode("utf-8"))
            name, metadata = meta.get("name"), dict(meta.get("metadata") or {})
        except (ValueError, AttributeError) as e:
            raise ValueError(f"{p}: field {_META_FIELD!r} is not a JSON object: {one_line(e)}") from None
    try:
        return PBRDFTable(axes["phi_d"], axes["theta_d"], axes["theta_h"], wvls, m, name=name, metadata=metadata)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None


# --- interpolation ---------------------------------------------------------------------------------


def _interval(grid: NDArray, q: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Mitsuba's ``Marginal2D`` lookup: ``(i0, i1, w1)`` with clamping at both ends.

    ``i0`` is the first index with ``grid[i0 + 1] >= q`` (so a query on a grid point ``k >= 1`` uses
    the interval ``[k - 1, k]`` with ``w1 = 1``); single-point axes give ``(0, 0, 0)``.
    """
    n = grid.size
    if n == 1:
        z = np.zeros(q.shape, dtype=np.intp)
        return z, z, np.zeros(q.shape)
    i0 = np.clip(np.searchsorted(grid, q, side="left") - 1, 0, n - 2)
    g0, g1 = grid[i0], grid[i0 + 1]
    w1 = np.clip((q - g0) / (g1 - g0), 0.0, 1.0)
    return i0, i0 + 1, w1


def _interval_periodic(grid: NDArray, q: NDArray, period: float = 2 * np.pi) -> tuple[NDArray, NDArray, NDArray]:
    """Like :func:`_interval`, but a query outside ``[grid[0], grid[-1]]`` wraps by ``period``.

    A wrapped query in the gap between ``grid[-1]`` and ``grid[0] + period`` interpolates between
    the last and the first sample.
    """
    n = grid.size
    if n == 1:
        return _interval(grid, q)
    outside = (q < grid[0]) | (q > grid[-1])
    qw = np.where(outside, grid[0] + np.mod(q - grid[0], period), q)
    i0, i1, w1 = _interval(grid, np.minimum(qw, grid[-1]))
    gap = grid[0] + period - grid[-1]
    in_gap = qw > grid[-1]
    if gap > 0 and np.any(in_gap):
        i0 = np.where(in_gap, n - 1, i0)
        i1 = np.where(in_gap, 0, i1)
        w1 = np.where(in_gap, np.clip((qw - grid[-1]) / gap, 0.0, 1.0), w1)
    return i0, i1, w1


def _lerp_axis(num: NDArray, den: NDArray, axis: int, i0: NDArray, i1: NDArray, w1: NDArray) -> tuple[NDArray, NDArray]:
    """One separable step of NaN-aware multilinear interpolation along ``axis`` of ``den``."""
    shape = [1] * den.ndim
    shape[axis] = -1
    wd1 = w1.reshape(shape)
    wd0 = 1.0 - wd1
    den = np.take(den, i0, axis=axis) * wd0 + np.take(den, i1, axis=axis) * wd1
    wn0, wn1 = wd0[..., None, None], wd1[..., None, None]
    num = np.take(num, i0, axis=axis) * wn0 + np.take(num, i1, axis=axis) * wn1
    return num, den


def _target_axis(current: NDArray, target: ArrayLike | None) -> NDArray | None:
    if target is None:
        return None
    t = np.asarray(target, dtype=np.float64).reshape(-1)
    if t.shape == current.shape and np.array_equal(t, current):
        return None  # identity: no interpolation, values copied exactly
    return t


def resample(
    table: PBRDFTable,
    *,
    phi_d: ArrayLike | None = None,
    theta_d: ArrayLike | None = None,
    theta_h: ArrayLike | None = None,
    wavelengths: ArrayLike | None = None,
) -> PBRDFTable:
    """Resample a table onto new axes: multilinear in the angles and linear in wavelength.

    ``phi_d`` is periodic (a target outside the source range wraps by ``2 pi``; one in the gap
    between the last and first source samples interpolates between them); the other axes clamp
    to their end values, like Mitsuba's lookup. Interpolation is NaN-aware: each result bin uses
    only the neighbouring bins whose Mueller matrices are finite, with their weights
    renormalised, and is NaN if none is. A target equal to a source sample copies it exactly.
    Runs in float64, in chunks of ``phi_d`` (a memory-mapped table is streamed).

    Args:
        table: the source table.
        phi_d: ``(Np',)`` new difference azimuths in radians, or None to keep them.
        theta_d: ``(Nd',)`` new difference angles in radians, or None.
        theta_h: ``(Nh',)`` new half angles in radians, or None.
        wavelengths: ``(W',)`` new wavelengths in nm, or None.

    Returns:
        A new in-memory table (float32 ``M``) with the same ``name`` and a copy of ``metadata``.

    Raises:
        ValueError: a target axis that is not valid for :class:`PBRDFTable`.

    Example:
        >>> t = PBRDFTable([0.0], [0.0, 1.0], [0.0], [500.0, 600.0],
        ...                np.arange(4, dtype=np.float32).reshape(1, 2, 1, 2, 1, 1) * np.ones((4, 4)))
        >>> resample(t, theta_d=[0.5], wavelengths=[550.0]).M[0, 0, 0, 0, 0, 0]
        1.5
    """
    src_axes = (table.phi_d, table.theta_d, table.theta_h, table.wavelengths)
    targets = [_target_axis(a, t) for a, t in zip(src_axes, (phi_d, theta_d, theta_h, wavelengths), strict=True)]
    new_axes = [a if t is None else t for a, t in zip(src_axes, targets, strict=True)]
    for name, a in zip(_AXIS_NAMES, new_axes, strict=True):
        _axis(a, name, *_AXIS_RANGES[name])  # validate the targets before the work

    lookups: list[tuple[NDArray, NDArray, NDArray] | None] = [None] * 4
    for k, t in enumerate(targets):
        if t is not None:
            lookups[k] = (_interval_periodic if k == 0 else _interval)(src_axes[k], t)

    out_shape = (*(a.size for a in new_axes), 4, 4)
    out = np.empty(out_shape, dtype=np.float32)
    slab_bytes = math.prod(table.M.shape[1:]) * 8 * 3  # float64 values + temporaries
    step = max(1, _CHUNK_BYTES * 4 // max(slab_bytes, 1))
    n_out_phi = out_shape[0]
    for start in range(0, n_out_phi, step):
        rows = np.arange(start, min(start + step, n_out_phi))
        phi_lookup = None
        src_rows = rows
        if lookups[0] is not None:
            i0, i1, w1 = (x[rows] for x in lookups[0])
            src_rows = np.unique(np.concatenate([i0, i1[w1 > 0]]))  # a weight-0 neighbour is not read
            phi_lookup = (np.searchsorted(src_rows, i0), np.searchsorted(src_rows, np.where(w1 > 0, i1, i0)), w1)
        block = np.asarray(table.M[src_rows], dtype=np.float64)
        den = np.isfinite(block).all(axis=(-2, -1)).astype(np.float64)
        num = np.where(den[..., None, None] > 0, block, 0.0)
        del block
        if phi_lookup is not None:
            num, den = _lerp_axis(num, den, 0, *phi_lookup)
        for k in (3, 1, 2):  # wavelength first: it shrinks a hyperspectral table the most
            if lookups[k] is not None:
                num, den = _lerp_axis(num, den, k, *lookups[k])
        res = np.full(num.shape, np.nan)
        np.divide(num, den[..., None, None], out=res, where=den[..., None, None] > 0)
        out[start : start + rows.size] = res
    return PBRDFTable(*new_axes, out, name=table.name, metadata=dict(table.metadata))


def to_mitsuba_bands(table: PBRDFTable, max_bands: int = MITSUBA_MAX_BANDS) -> PBRDFTable:
    """Resample a table to at most ``max_bands`` wavelengths for the stock ``measured_polarized`` plugin.

    The new bands are evenly spaced over the table's wavelength range, both ends included, and
    rounded to whole nanometres (68 hpBRDF bands 414..950 nm become 414, 548, 682, 816, 950 nm). The
    table is point-sampled there by :func:`resample` (no band averaging): spectral features
    between the new bands are lost, and Mitsuba interpolates linearly between them again. A table
    with at most ``max_bands`` bands is returned unchanged.

    .. warning::
        Mitsuba 3.9.1's ``measured_polarized`` copies the ``wvls`` field into a fixed
        ``ScalarFloat wavelengths[5]`` array and then reads as many entries as the table has
        bands: with more than 5 bands it interpolates with garbage wavelengths (see
        ``docs/measurements/pbrdf.md`` for a 7-band example). 68-band hpBRDF tables need this
        resampling, the patched plugin of ``yunseong0518/hpBRDF``, or :func:`evaluate`.

    Args:
        table: the source table.
        max_bands: at most this many bands (>= 1); 5 for the stock plugin.

    Returns:
        The resampled table (or ``table`` itself).

    Raises:
        ValueError: ``max_bands < 1``.
    """
    if int(max_bands) != max_bands or max_bands < 1:
        raise ValueError(f"max_bands must be an integer >= 1; got {max_bands!r}")
    wl = table.wavelengths
    if wl.size <= max_bands:
        return table
    if max_bands == 1:
        bands = np.array([np.round(0.5 * (wl[0] + wl[-1]))])
    else:
        bands = np.unique(np.round(np.linspace(wl[0], wl[-1], int(max_bands))))
    return resample(table, wavelengths=bands)


# --- evaluation ----------------------------------------------------------------------------------------


def _lookup(table: PBRDFTable, phi_d: NDArray, theta_d: NDArray, theta_h: NDArray, lam: NDArray) -> NDArray:
    """Multilinear lookup ``(n, 4, 4)`` float64, clamped like Mitsuba; a NaN corner (even of weight 0) gives NaN."""
    parts = [
        _interval(g, q)
        for g, q in zip(
            (table.phi_d, table.theta_d, table.theta_h, table.wavelengths), (phi_d, theta_d, theta_h, lam), strict=True
        )
    ]
    out = np.zeros((phi_d.size, 4, 4))
    for corner in range(16):
        idx, w = [], np.ones(phi_d.size)
        for k, (i0, i1, w1) in enumerate(parts):
            upper = (corner >> k) & 1
            idx.append(i1 if upper else i0)
            w = w * (w1 if upper else 1.0 - w1)
        out += w[:, None, None] * table.M[tuple(idx)]
    return out


def evaluate(
    table: PBRDFTable, wi: ArrayLike, wo: ArrayLike, wavelength: ArrayLike, *, mode: str = "radiance"
) -> NDArray[np.float64]:
    """Evaluate a table like Mitsuba's ``measured_polarized`` ``bsdf.eval(ctx, si, wo)`` (polarized variants).

    The pipeline of the plugin, in float64: Rusinkiewicz angles (:func:`rusinkiewicz_from_directions`),
    multilinear lookup in ``(phi_d, theta_d, theta_h, wavelength)`` clamped at the ends of each axis,
    zero matrix where a NaN bin enters the lookup, ``m00 := max(m00, 0)``, rotation from the
    plane-of-reflection Stokes frames into Mitsuba's implicit bases (input beam along ``-wo_light``
    with ``stokes_basis(-wo_light)``, output along ``wi_camera`` with ``stokes_basis(wi_camera)``),
    times ``cos theta_o = wo_z``. Zero unless both directions are strictly above the surface.

    Differences from the plugin, all at measure-zero geometry or float32 round-off: the plugin
    works in float32 (its ``acos`` of ``theta_d`` and ``theta_h`` loses digits near 0); it
    returns NaN where ``h = n`` exactly or ``wi == wo`` (undefined frames), where this function
    uses the limits of :mod:`pbrdf.brdf.rusinkiewicz`; it zeroes a matrix only where the
    interpolated ``m00`` is NaN, this function wherever any entry is.

    Args:
        table: the table.
        wi: ``(..., 3)`` unit direction of ``si.wi`` in the local frame (the camera side in radiance mode).
        wo: ``(..., 3)`` unit direction passed as ``wo`` (the light side in radiance mode).
        wavelength: wavelength in nm, shape broadcastable with the batch (the plugin's
            ``wavelength`` parameter, or ``si.wavelengths`` in spectral variants).
        mode: ``"radiance"`` (Mitsuba's default ``TransportMode.Radiance``) or ``"importance"``
            (the roles of ``wi`` and ``wo`` swap; the cos factor stays ``wo_z``).

    Returns:
        ``(..., 4, 4)`` float64 Mueller matrices in 1/sr times ``cos theta_o``, acting on Stokes
        vectors of the light arriving along ``-wo`` (radiance mode) and producing the Stokes vector
        leaving along ``wi``, in Mitsuba's implicit bases.

    Raises:
        ValueError: directions that are not ``(..., 3)`` unit vectors, or an unknown ``mode``.

    Example:
        Lambertian albedo 0.8 seen at any angle, light at 60 degrees: ``0.8 / pi * cos 60deg``.

        >>> t = PBRDFTable([-np.pi, np.pi], [0, np.pi / 2], [0, np.pi / 2], [550.0],
        ...                np.zeros((2, 2, 2, 1, 4, 4)) + np.diag([0.8 / np.pi, 0, 0, 0]))
        >>> m = evaluate(t, [0.0, 0.6, 0.8], [np.sin(np.pi / 3), 0.0, 0.5], 550.0)
        >>> round(float(m[0, 0] * np.pi / 0.8), 6), float(np.abs(m).sum() - m[0, 0])
        (0.5, 0.0)
    """
    if mode not in ("radiance", "importance"):
        raise ValueError(f"mode must be 'radiance' or 'importance'; got {mode!r}")
    wi_a, wo_a = as_unit_vectors(wi, "wi"), as_unit_vectors(wo, "wo")
    lam = np.asarray(wavelength, dtype=np.float64)
    batch = np.broadcast_shapes(wi_a.shape[:-1], wo_a.shape[:-1], lam.shape)
    wi_f = np.broadcast_to(wi_a, (*batch, 3)).reshape(-1, 3)
    wo_f = np.broadcast_to(wo_a, (*batch, 3)).reshape(-1, 3)
    lam_f = np.broadcast_to(lam, batch).reshape(-1)
    out = np.zeros((wi_f.shape[0], 4, 4))
    active = (wi_f[:, 2] > 0) & (wo_f[:, 2] > 0)
    if np.any(active):
        camera, light = (wi_f, wo_f) if mode == "radiance" else (wo_f, wi_f)
        camera, light = camera[active], light[active]
        theta_h, theta_d, phi_d = rusinkiewicz_from_directions(camera, light)
        m = _lookup(table, phi_d, theta_d, theta_h, lam_f[active])
        m[~np.isfinite(m).all(axis=(-2, -1))] = 0.0
        m[:, 0, 0] = np.maximum(m[:, 0, 0], 0.0)
        x = reflection_frame_x(camera, light)
        m = rotate_mueller_basis(m, -light, x, stokes_basis(-light), camera, x, stokes_basis(camera))
        out[active] = m * wo_f[active, 2][:, None, None]
    return out.reshape(*batch, 4, 4)


def tabulate(
    brdf: Callable[[NDArray, NDArray, int], NDArray],
    phi_d: ArrayLike,
    theta_d: ArrayLike,
    theta_h: ArrayLike,
    wavelengths: ArrayLike,
    *,
    name: str = "",
    metadata: dict | None = None,
) -> PBRDFTable:
    """Sample a pBRDF given in Mitsuba's conventions onto a Rusinkiewicz table (inverse of :func:`evaluate`).

    Args:
        brdf: ``brdf(wi, wo, band) -> (..., 4, 4)``: the Mueller matrix as Mitsuba's ``bsdf.eval``
            returns it (camera side ``wi``, light side ``wo``, implicit Stokes bases, times
            ``cos theta_o``), e.g. :func:`pbrdf.brdf.microfacet.dielectric_pbrdf`; ``band`` indexes
            ``wavelengths``.
        phi_d: difference azimuths, radians.
        theta_d: difference angles, radians.
        theta_h: half-vector angles, radians.
        wavelengths: nm.
        name: table name.
        metadata: stored with the table.

    Returns:
        A table without the cos factor, in the plane-of-reflection frames; bins whose directions
        fall below the horizon are 0.
    """
    pd, td, th = (np.asarray(a, dtype=np.float64) for a in (phi_d, theta_d, theta_h))
    wl = np.asarray(wavelengths, dtype=np.float64)
    g_pd, g_td, g_th = np.meshgrid(pd, td, th, indexing="ij")
    wi, wo = directions_from_rusinkiewicz(g_th, g_td, g_pd)
    active = (wi[..., 2] > 1e-6) & (wo[..., 2] > 1e-6)
    cam, light = wi[active], wo[active]
    x = reflection_frame_x(cam, light)
    out = np.zeros((*g_pd.shape, wl.size, 4, 4), dtype=np.float32)
    for band in range(wl.size):
        m = np.asarray(brdf(cam, light, band), dtype=np.float64) / light[:, 2, None, None]
        # Inverse of evaluate's rotation: implicit bases -> plane-of-reflection frames.
        m = rotate_mueller_basis(m, -light, stokes_basis(-light), x, cam, stokes_basis(cam), x)
        out[active, band] = m
    return PBRDFTable(pd, td, th, wl, out, name=name, metadata=dict(metadata or {}))
