"""Expansion of a small set of pBRDF tables into many (the paper's Section 6).

Representation. Every table ``M (bins, W, 4, 4)`` (``bins`` = the flattened Rusinkiewicz grid,
``W`` wavelengths) is factored per bin and wavelength into intensity and polarization:
``M = m00 * M_pol`` with ``M_pol = M / m00`` (``M_pol[0, 0] = 1``; bins with ``m00 <= eps``
get ``M_pol = 0``). Both parts are compressed with an arctan,

.. math:: g_I = \\arctan(\\alpha_I\\, m_{00}), \\qquad g_P = \\arctan(\\alpha_P\\, M_{pol, ij}),

which squeezes specular peaks and keeps every value inside ``(-pi/2, pi/2)``; the mean over
samples is removed per term. One sample of the PCA is one (table, wavelength) pair, so the bases
are shared across wavelengths: ``k_I`` intensity components over ``bins`` features and ``k_P``
polarization components over ``bins * 15`` features (10 + 10 by default).

Scaling. The PCA never holds the data matrix ``X (N samples, D features)`` in memory: it
accumulates the ``N x N`` Gram matrix ``X X^T`` over chunks of features (streamed from the tables,
which may be memory-mapped 1 GB files), diagonalises it, and forms the components ``X^T U
Lambda^{-1/2}`` chunk by chunk in a second pass. Memory is ``O(N^2 + chunk * N + D * k)``.

Reconstruction inverts each step; the arctan inverse ``tan(clip(g, -g_max, g_max)) / alpha``
is clamped away from ``+-pi/2`` (:data:`G_MAX`), so a generated weight can never produce Inf.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pbrdf.brdf.disney_fit import FitResult
from pbrdf.polar import validity

__all__ = [
    "G_MAX",
    "PCAModel",
    "factor",
    "compress",
    "decompress",
    "fit_pca",
    "project",
    "reconstruct",
    "filter_tables",
    "TableVerdict",
    "RGB_WAVELENGTHS_NM",
    "sample_directions",
    "FIT_ERROR_MAX",
    "TableFit",
    "fit_table_disney",
]

#: Largest |g| handed to tan(): tan(G_MAX) = 1e6, far beyond any physical compressed value.
G_MAX = float(np.arctan(1e6))
#: m00 at or below this counts as zero (no polarization information in the bin).
M00_EPS = 1e-8


def factor(m: NDArray, *, eps: float = M00_EPS) -> tuple[NDArray, NDArray]:
    """Split Mueller matrices into intensity and normalised polarization.

    Args:
        m: ``(..., 4, 4)`` Mueller matrices (NaN entries are treated as 0).
        eps: intensity below which the polarization part is set to 0.

    Returns:
        ``(m00 (...), pol (..., 15))``: ``m00`` clamped to >= 0 and the other 15 entries of
        ``M / m00`` in row-major order (without the (0, 0) entry).
    """
    m = np.nan_to_num(np.asarray(m, dtype=np.float64))
    m00 = np.maximum(m[..., 0, 0], 0.0)
    flat = m.reshape(*m.shape[:-2], 16)[..., 1:]
    pol = np.zeros_like(flat)
    ok = m00 > eps
    np.divide(flat, m00[..., None], out=pol, where=ok[..., None])
    return m00, pol


def unfactor(m00: NDArray, pol: NDArray) -> NDArray:
    """Inverse of :func:`factor`: ``(...)``, ``(..., 15)`` -> ``(..., 4, 4)``."""
    flat = np.concatenate([np.ones_like(m00)[..., None], pol], axis=-1) * m00[..., None]
    return flat.reshape(*m00.shape, 4, 4)


def compress(x: NDArray, alpha: float) -> NDArray:
    """``arctan(alpha * x)``, in ``(-pi/2, pi/2)``."""
    return np.arctan(alpha * np.asarray(x, dtype=np.float64))


def decompress(g: NDArray, alpha: float) -> NDArray:
    """Inverse of :func:`compress` with a safe clamp: ``tan(clip(g, -G_MAX, G_MAX)) / alpha``."""
    return np.tan(np.clip(np.asarray(g, dtype=np.float64), -G_MAX, G_MAX)) / alpha


@dataclass
class PCAModel:
    """Intensity and polarization PCA bases shared across wavelengths.

    Attributes:
        alpha_i: arctan compression of m00.
        alpha_p: arctan compression of the normalised polarization terms.
        mean_i: ``(bins,)`` mean compressed intensity.
        mean_p: ``(bins * 15,)`` mean compressed polarization.
        basis_i: ``(k_I, bins)`` orthonormal intensity components.
        basis_p: ``(k_P, bins * 15)`` orthonormal polarization components.
        explained_i: ``(k_I,)`` fraction of variance explained by each intensity component.
        explained_p: ``(k_P,)`` same for polarization.
        grid_shape: the table grid the bins flatten, e.g. ``(Np, Nd, Nh)``.
        m00_max: largest intensity of the training tables; reconstructions are clamped to twice
            it, so a weight near the arctan pole cannot produce a runaway peak.
    """

    alpha_i: float
    alpha_p: float
    mean_i: NDArray
    mean_p: NDArray
    basis_i: NDArray
    basis_p: NDArray
    explained_i: NDArray
    explained_p: NDArray
    grid_shape: tuple[int, ...] = field(default=())
    m00_max: float = np.inf

    @property
    def n_weights(self) -> int:
        """Weights per (table, wavelength): ``k_I + k_P``."""
        return self.basis_i.shape[0] + self.basis_p.shape[0]

    def to_arrays(self) -> dict[str, NDArray]:
        """Arrays for ``np.savez`` (no pickled objects)."""
        return {
            "alpha": np.array([self.alpha_i, self.alpha_p]),
            "mean_i": self.mean_i,
            "mean_p": self.mean_p,
            "basis_i": self.basis_i,
            "basis_p": self.basis_p,
            "explained_i": self.explained_i,
            "explained_p": self.explained_p,
            "grid_shape": np.asarray(self.grid_shape, dtype=np.int64),
            "m00_max": np.array(self.m00_max),
        }

    @classmethod
    def from_arrays(cls, d: dict) -> PCAModel:
        """Inverse of :meth:`to_arrays`."""
        return cls(
            float(d["alpha"][0]), float(d["alpha"][1]), d["mean_i"], d["mean_p"], d["basis_i"], d["basis_p"],
            d["explained_i"], d["explained_p"], tuple(int(v) for v in d["grid_shape"]),
            float(d["m00_max"]) if "m00_max" in d else np.inf,
        )  # fmt: skip


# A table source: number of tables, wavelengths per table, bins, and a loader of a bin range
# returning M (n_tables, chunk_bins, W, 4, 4). Lets the PCA stream memory-mapped files.
TableSource = Callable[[slice], NDArray]


def _features(m_chunk: NDArray, alpha_i: float, alpha_p: float) -> tuple[NDArray, NDArray]:
    """Compressed features of a chunk: ``(N, bins_c)`` and ``(N, bins_c * 15)``, N = tables * W."""
    m00, pol = factor(m_chunk)  # (T, b, W), (T, b, W, 15)
    t, b, w = m00.shape
    gi = compress(m00, alpha_i).transpose(0, 2, 1).reshape(t * w, b)
    gp = compress(pol, alpha_p).transpose(0, 2, 1, 3).reshape(t * w, b * 15)
    return gi, gp


def _top_components(gram: NDArray, k: int) -> tuple[NDArray, NDArray]:
    lam, u = np.linalg.eigh((gram + gram.T) / 2)
    order = np.argsort(lam)[::-1]
    lam, u = np.maximum(lam[order], 0.0), u[:, order]
    return lam, u[:, :k]


def fit_pca(
    source: TableSource | NDArray,
    *,
    n_bins: int | None = None,
    k_intensity: int = 10,
    k_polarization: int = 10,
    alpha_i: float | None = None,
    alpha_p: float = 1.0,
    chunk_bins: int = 65536,
    grid_shape: Sequence[int] = (),
) -> PCAModel:
    """Streaming PCA of compressed intensity and polarization (see the module docs).

    Args:
        source: an array ``(T, bins, W, 4, 4)`` (may be a memmap) or a callable returning that
            array's rows for a slice of bins.
        n_bins: number of bins (required with a callable source).
        k_intensity: intensity components.
        k_polarization: polarization components.
        alpha_i: arctan compression of m00; None picks ``1 / max(m00)`` of the data, which maps
            the brightest bin to ``arctan(1) = pi/4`` and keeps the pole far away (with a fixed
            large alpha, specular peaks sit at the pole and tiny weight errors explode); the
            maximum, unlike a percentile, does not depend on the chunking.
        alpha_p: arctan compression of the polarization terms.
        chunk_bins: bins per streamed chunk (memory is about ``T * W * chunk_bins * 16 * 8`` bytes).
        grid_shape: the table grid, stored with the model.

    Returns:
        The fitted :class:`PCAModel`.
    """
    if isinstance(source, np.ndarray):
        arr = source
        n_bins = arr.shape[1]

        def load(s: slice) -> NDArray:
            return np.asarray(arr[:, s])

    else:
        if n_bins is None:
            raise ValueError("n_bins is required with a callable source")
        load = source
    chunks = [slice(i, min(i + chunk_bins, n_bins)) for i in range(0, n_bins, chunk_bins)]
    # Pass 0: intensity scale (alpha_i) and range.
    m00_max = 0.0
    for s in chunks:
        m00_max = max(m00_max, float(factor(load(s))[0].max(initial=0.0)))
    if alpha_i is None:
        alpha_i = 1.0 / max(m00_max, 1e-12)
    # Pass 1: means and Gram matrices of the centred features.
    sums_i, sums_p, n = [], [], None
    for s in chunks:
        gi, gp = _features(load(s), alpha_i, alpha_p)
        n = gi.shape[0]
        sums_i.append(gi.mean(axis=0))
        sums_p.append(gp.mean(axis=0))
    mean_i, mean_p = np.concatenate(sums_i), np.concatenate(sums_p)
    k_intensity, k_polarization = min(k_intensity, n), min(k_polarization, n)
    gram_i = np.zeros((n, n))
    gram_p = np.zeros((n, n))
    for s in chunks:
        gi, gp = _features(load(s), alpha_i, alpha_p)
        gi -= mean_i[s]
        gp -= mean_p[s.start * 15 : s.stop * 15]
        gram_i += gi @ gi.T
        gram_p += gp @ gp.T
    lam_i, u_i = _top_components(gram_i, k_intensity)
    lam_p, u_p = _top_components(gram_p, k_polarization)
    # Pass 2: components X^T U Lambda^-1/2, chunk by chunk.
    scale_i = 1.0 / np.sqrt(np.maximum(lam_i[:k_intensity], 1e-30))
    scale_p = 1.0 / np.sqrt(np.maximum(lam_p[:k_polarization], 1e-30))
    basis_i = np.zeros((k_intensity, n_bins))
    basis_p = np.zeros((k_polarization, n_bins * 15))
    for s in chunks:
        gi, gp = _features(load(s), alpha_i, alpha_p)
        gi -= mean_i[s]
        gp -= mean_p[s.start * 15 : s.stop * 15]
        basis_i[:, s] = (u_i.T @ gi) * scale_i[:, None]
        basis_p[:, s.start * 15 : s.stop * 15] = (u_p.T @ gp) * scale_p[:, None]
    total_i, total_p = max(lam_i.sum(), 1e-30), max(lam_p.sum(), 1e-30)
    return PCAModel(
        alpha_i, alpha_p, mean_i, mean_p, basis_i, basis_p,
        lam_i[:k_intensity] / total_i, lam_p[:k_polarization] / total_p, tuple(grid_shape), m00_max,
    )  # fmt: skip


def project(
    model: PCAModel, m: NDArray | TableSource, *, n_bins: int | None = None, chunk_bins: int = 65536
) -> NDArray:
    """PCA weights of tables: ``(T, bins, W, 4, 4)`` (or a chunk loader) -> ``(T, W, k_I + k_P)``.

    With a callable source (as for :func:`fit_pca`) the projection streams over chunks of bins.
    """
    if callable(m):
        if n_bins is None:
            raise ValueError("n_bins is required with a callable source")
        total = None
        for start in range(0, n_bins, chunk_bins):
            s = slice(start, min(start + chunk_bins, n_bins))
            part = m(s)
            gi, gp = _features(part, model.alpha_i, model.alpha_p)
            w = np.concatenate(
                [
                    (gi - model.mean_i[s]) @ model.basis_i[:, s].T,
                    (gp - model.mean_p[s.start * 15 : s.stop * 15]) @ model.basis_p[:, s.start * 15 : s.stop * 15].T,
                ],
                axis=-1,
            )
            total = w if total is None else total + w
            t, wl = part.shape[0], part.shape[2]
        return total.reshape(t, wl, -1)
    gi, gp = _features(np.asarray(m), model.alpha_i, model.alpha_p)
    t, w = m.shape[0], m.shape[2]
    wi = (gi - model.mean_i) @ model.basis_i.T
    wp = (gp - model.mean_p) @ model.basis_p.T
    return np.concatenate([wi, wp], axis=-1).reshape(t, w, -1)


def reconstruct(model: PCAModel, weights: NDArray) -> NDArray:
    """Tables from PCA weights: ``(T, W, k_I + k_P)`` -> ``(T, bins, W, 4, 4)`` (float64).

    Inverse arctan with the safe clamp (:func:`decompress`); m00 clamped to ``[0, 2 m00_max]``.
    """
    weights = np.asarray(weights, dtype=np.float64)
    t, w, _ = weights.shape
    ki = model.basis_i.shape[0]
    gi = weights[..., :ki] @ model.basis_i + model.mean_i  # (T, W, bins)
    gp = weights[..., ki:] @ model.basis_p + model.mean_p  # (T, W, bins * 15)
    m00 = np.clip(decompress(gi, model.alpha_i), 0.0, 2.0 * model.m00_max)
    pol = decompress(gp, model.alpha_p).reshape(t, w, -1, 15)
    m = unfactor(m00, pol)  # (T, W, bins, 4, 4)
    return m.transpose(0, 2, 1, 3, 4)


@dataclass(frozen=True)
class TableVerdict:
    """Validity of one table: fractions of physical Mueller matrices and the decision.

    ``gk_fraction`` counts every Cloude-physical matrix as Givens-Kostinski-physical (Cloude
    implies it, :mod:`pbrdf.polar.validity`) and tests only the others.
    """

    gk_fraction: float
    cloude_fraction: float
    accepted: bool


def filter_tables(
    m: NDArray,
    *,
    min_valid_fraction: float = 0.95,
    project_invalid: bool = True,
    rtol: float = 1e-5,
) -> tuple[NDArray, list[TableVerdict]]:
    """Physical-validity filter: per-matrix tests, a per-table acceptance rule, optional repair.

    Every Mueller matrix with ``m00 > 0`` is tested with the closed-form Cloude test
    (:func:`pbrdf.polar.validity.is_cloude_physical`), which decides: a Cloude-physical matrix
    is also Givens-Kostinski-physical, so Givens-Kostinski runs only on the Cloude failures, for
    ``gk_fraction``. A table is accepted when at least ``min_valid_fraction`` of its matrices
    pass; with ``project_invalid`` the few invalid matrices of an accepted table are replaced
    by their Cloude projection (the Frobenius-nearest physical matrix, intensity kept).

    Args:
        m: ``(T, bins, W, 4, 4)`` tables.
        min_valid_fraction: acceptance threshold per table.
        project_invalid: repair the invalid matrices of accepted tables.
        rtol: tolerance of the validity tests: a matrix passes if its smallest coherency
            eigenvalue is at least ``-rtol m00``.

    Returns:
        ``(tables, verdicts)``: the (repaired) tables, same shape, and one verdict per table.
    """
    out = np.array(m, dtype=np.float64, copy=True)
    verdicts = []
    for t in range(out.shape[0]):
        flat = out[t].reshape(-1, 4, 4)
        lit = flat[:, 0, 0] > M00_EPS
        mats = flat[lit]
        ok = validity.is_cloude_physical(mats, rtol=rtol)
        gk = ok.copy()
        if not ok.all():
            gk[~ok] = validity.is_givens_kostinski(mats[~ok], rtol=rtol)
        n = max(len(mats), 1)
        accepted = bool(ok.mean() >= min_valid_fraction) if len(mats) else False
        if accepted and project_invalid and not ok.all():
            fixed = validity.cloude_filter(mats[~ok], renormalize=True)
            idx = np.flatnonzero(lit)[~ok]
            flat[idx] = fixed
            out[t] = flat.reshape(out[t].shape)
        verdicts.append(TableVerdict(float(gk.sum() / n), float(ok.sum() / n), accepted))
    return out, verdicts


#: Wavelengths (nm) that stand for the display's R, G, B primaries when a table is reduced to RGB
#: (the renderer's per-channel wavelengths).
RGB_WAVELENGTHS_NM = (630.0, 532.0, 465.0)


def sample_directions(n: int, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
    """Direction pairs for fitting: half near the mirror direction, a tenth exactly on it.

    ``wi`` is cosine-distributed. The first ``n // 2`` ``wo`` are ``wi``'s mirror image jittered
    by a normal of 0.15 per component (the specular lobe's width), the last ``n // 10`` are the
    exact mirror image (the lobe's peak, ``theta_h = 0``) and the rest are cosine-distributed. The
    exact pairs make a lobe much sharper than the data visible to the fit: without them a Disney
    spike at roughness 0 (``D = 3e5``) fell between the samples of a Lambertian table and won.

    Args:
        n: number of pairs, ``>= 1``.
        rng: the random generator.

    Returns:
        ``(wi, wo)``, each ``(n, 3)`` unit vectors with ``z >= 1e-3`` in the local frame.
    """

    def cosine_dirs(k: int) -> NDArray:
        u1, u2 = rng.random(k), rng.random(k)
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1 - u1, 1e-6))], axis=-1)

    wi = cosine_dirs(n)
    wo = cosine_dirs(n)
    half = n // 2
    mirror = wi[:half] * np.array([-1.0, -1.0, 1.0])
    jitter = mirror + 0.15 * rng.normal(size=mirror.shape)
    jitter[:, 2] = np.abs(jitter[:, 2]) + 0.02
    wo[:half] = jitter / np.linalg.norm(jitter, axis=-1, keepdims=True)
    exact = n // 10
    if exact:
        wo[n - exact :] = wi[n - exact :] * np.array([-1.0, -1.0, 1.0])
    return wi, wo


#: Largest held-out fit error (:attr:`TableFit.fit_error`) of a usable Disney label. Good fits of
#: the seed set lie far below and a lobe that the table does not have far above; see
#: docs/measurements/pbrdf.md.
FIT_ERROR_MAX = 0.5


@dataclass(frozen=True)
class TableFit(FitResult):
    """:class:`pbrdf.brdf.disney_fit.FitResult` of a table, with a held-out check.

    Attributes:
        fit_error: RMS over fresh direction pairs (not those fitted, exact mirror pairs included)
            and the three channels of ``log1p(model / s_c) - log1p(table / s_c)``, ``s_c`` the
            channel's median of the table values (floored at 1e-3 of their peak): the compressed
            residual of the fit, dimensionless, about the relative error above the median.
            Finite, ``>= 0``.
        fit_ok: ``success`` and ``fit_error <= FIT_ERROR_MAX``; a label with ``fit_ok`` False
            does not describe its table and should be recorded as such (or dropped).
    """

    fit_error: float = 0.0
    fit_ok: bool = True


def _rgb_values(table, wi: NDArray, wo: NDArray) -> NDArray:
    from pbrdf.brdf.table import evaluate  # noqa: PLC0415

    return np.stack([evaluate(table, wi, wo, lam)[:, 0, 0] for lam in RGB_WAVELENGTHS_NM], axis=-1)


def fit_table_disney(table, *, n: int = 2000, seed: int = 0) -> TableFit:
    """Disney parameters (albedo RGB, roughness, metallic) of a table's m00, with a quality flag.

    The table is evaluated (cos-weighted, as Mitsuba renders it) at the renderer's R, G, B
    wavelengths on ``n`` direction pairs from :func:`sample_directions` and fitted by
    :func:`pbrdf.brdf.disney_fit.fit_disney` (analytic Jacobian, several starts, the best kept). The
    fit is then checked on ``n`` fresh pairs of another random stream (:attr:`TableFit.fit_error`)
    and flagged (:attr:`TableFit.fit_ok`) when that error exceeds :data:`FIT_ERROR_MAX`.

    Args:
        table: a :class:`pbrdf.brdf.table.PBRDFTable`.
        n: direction pairs for the fit and for the check, ``>= 5`` (the fit's minimum).
        seed: seed of both random streams (the fit uses ``default_rng(seed)``, the check
            ``default_rng([seed, 1])``); deterministic.

    Returns:
        A :class:`TableFit`.

    Raises:
        ValueError: if ``n < 5`` or the table's values are not finite.
    """
    from pbrdf.brdf import disney, disney_fit  # noqa: PLC0415

    if n < 5:
        raise ValueError(f"n must be >= 5 direction pairs; got {n}")
    wi, wo = sample_directions(n, np.random.default_rng(seed))
    fit = disney_fit.fit_disney(wi, wo, _rgb_values(table, wi, wo))
    wi, wo = sample_directions(n, np.random.default_rng([seed, 1]))
    values = np.maximum(_rgb_values(table, wi, wo), 0.0)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"table {getattr(table, 'name', '')!r}: values must be finite")
    fd, fs = disney.disney_brdf(wi, wo, fit.albedo, fit.roughness, fit.metallic)
    model = (fd + fs) * wo[:, 2:3]
    scale = np.maximum(np.median(values, axis=0), 1e-3 * max(float(values.max()), 1e-12))
    err = float(np.sqrt(np.mean((np.log1p(model / scale) - np.log1p(values / scale)) ** 2)))
    return TableFit(**vars(fit), fit_error=err, fit_ok=bool(fit.success and err <= FIT_ERROR_MAX))
