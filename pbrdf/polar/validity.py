"""Physical validity of Mueller matrices: Cloude coherency test and filter, Givens-Kostinski test.

Convention:
    Mueller matrices have shape ``(..., 4, 4)`` (float32 or float64; everything is computed
    internally in float64 / complex128) and act on column Stokes vectors as in
    :mod:`pbrdf.polar.mueller`. Every function is vectorised over the leading axes and processes large
    batches in chunks, so millions of matrices fit in memory.

    The Cloude coherency matrix uses the Pauli basis ``sigma0 = I``, ``sigma1 = diag(1, -1)``,
    ``sigma2 = [[0, 1], [1, 0]]``, ``sigma3 = [[0, -i], [i, 0]]``:

    .. math::
        H = \\tfrac14 \\sum_{ij} m_{ij}\\, \\sigma_i \\otimes \\sigma_j^*,\\qquad
        m_{ij} = \\operatorname{tr}[(\\sigma_i \\otimes \\sigma_j^*) H],\\qquad \\operatorname{tr} H = m_{00}.

    ``M -> H`` is a bijection between real 4x4 matrices and Hermitian 4x4 matrices with
    ``||H||_F^2 = ||M||_F^2 / 4``. ``M`` is a convex sum of Jones-derived (pure) Mueller matrices
    iff ``H`` is positive semidefinite (*Cloude-physical*); a pure matrix has a rank-1 ``H``.

    Two tests of increasing strength:

    * :func:`is_givens_kostinski` -- the *Stokes criterion*: ``M`` maps every physical Stokes
      vector to a physical Stokes vector (no over-polarization, no negative intensity).
    * :func:`is_cloude_physical` -- ``H + rtol m00 I >= 0``: ``M`` is an ensemble of deterministic
      (Jones) systems. Cloude at ``rtol`` implies Givens-Kostinski at about ``4 rtol``, so
      :func:`is_mueller_physical` is decided by Cloude alone. The verdict comes from the four
      pivots of an ``LDL^H`` factorisation in closed form (Sylvester's criterion); only matrices
      whose verdict lies within round-off of the boundary go to ``eigvalsh`` (also available as
      ``method="eigh"``). Why pivots, and their agreement with the eigenvalue routes: the
      validity-filter section of docs/measurements/pbrdf.md.

    The spectral functions reject NaN and Inf entries with a ``ValueError``; mask invalid
    entries (e.g. the invalid geometry of measured pBRDF tables) before calling them.

Example:
    ``diag(1, 1, 1, -1)`` keeps every Stokes vector physical but is no ensemble of Jones
    systems (``H`` has the eigenvalue -1/2); the Cloude filter makes it one:

    >>> import numpy as np
    >>> flip = np.diag([1.0, 1.0, 1.0, -1.0])
    >>> bool(is_givens_kostinski(flip)), bool(is_cloude_physical(flip))
    (True, False)
    >>> float(coherency_eigenvalues(flip).min()), bool(is_cloude_physical(cloude_filter(flip)))
    (-0.5, True)

References:
    S. R. Cloude, "Group theory and polarisation algebra", Optik 75(1):26-36, 1986; S. R. Cloude,
    "Conditions for the physical realisability of matrix operators in polarimetry", Proc. SPIE 1166,
    1990. C. R. Givens and A. B. Kostinski, "A simple necessary and sufficient condition on
    physically realizable Mueller matrices", J. Mod. Opt. 40(3):471-481, 1993. J. Zander and
    J. Beyerer, "Comparison of filters for the physical realizability of Mueller matrices",
    OSA Continuum 3(6):1376, 2020 (the eigenvalue-clipping filter is the Frobenius projection).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf._checks import as_float_array, check_last_dims

__all__ = [
    "coherency_matrix",
    "mueller_from_coherency",
    "coherency_eigenvalues",
    "is_cloude_physical",
    "cloude_filter",
    "is_givens_kostinski",
    "is_mueller_physical",
]

# Matrices per chunk in the spectral functions (a few tens of MB of temporaries per chunk).
_CHUNK = 1 << 16
# Matrices per chunk of the closed-form Cloude test: its 16 rows of temporaries stay in cache.
_LDL_CHUNK = 1 << 13
# Pivots of 4 H / m00 (trace 4) within this of zero leave the verdict to the eigenvalues.
_PIVOT_TOL = 1e-10
# Where some m00 lies outside [1 / _HUGE, _HUGE], the pivots are computed on M / m00, so that
# products of entries neither underflow nor overflow.
_HUGE = 1e100

_PAULI = np.array([[[1, 0], [0, 1]], [[1, 0], [0, -1]], [[0, 1], [1, 0]], [[0, -1j], [1j, 0]]], dtype=np.complex128)
# _BASIS[i, j] = sigma_i kron conj(sigma_j); all 16 are Hermitian with tr(B_ij B_kl) = 4 delta_ik delta_jl.
_BASIS = np.einsum("iab,jcd->ijacbd", _PAULI, _PAULI.conj()).reshape(4, 4, 4, 4)
# As 16x16 maps on row-flattened arrays: vec(H) = vec(M) @ _M2H, vec(M) = Re(vec(H) @ _H2M).
_M2H = 0.25 * _BASIS.reshape(16, 16)
_H2M = np.ascontiguousarray(np.swapaxes(_BASIS, -1, -2).reshape(16, 16).T)
_G = np.array([1.0, -1.0, -1.0, -1.0])
# 4 H as 16 real rows of vec(M): the diagonal h00..h33, Re(h10, h20, h30), Im(h10, h20, h30),
# Re(h21, h31), Im(h21, h31), Re h32, Im h32 (entries 0 and +-1); then m00 itself.
_LOWER = ((1, 0), (2, 0), (3, 0), (2, 1), (3, 1), (3, 2))
_H_ROWS = np.array(
    [4 * _M2H[:, 5 * i].real for i in range(4)]
    + [4 * part(_M2H[:, 4 * i + j]) for pairs in (_LOWER[:3], _LOWER[3:5], _LOWER[5:]) for part in (np.real, np.imag)
       for i, j in pairs]
    + [np.eye(16)[0]]
)  # fmt: skip
_NONFINITE_MSG = "mueller contains NaN or Inf; mask invalid entries first"


def _checked(mueller: ArrayLike, *, finite: bool = True) -> NDArray[np.floating]:
    m = as_float_array(mueller)
    check_last_dims(m, (4, 4), "mueller")
    if finite and not np.all(np.isfinite(m)):
        raise ValueError(_NONFINITE_MSG)
    return m


def _chunked(
    fn: Callable[[NDArray[np.float64]], NDArray], m: NDArray, tail: tuple[int, ...], dtype: type, chunk: int = 0
) -> NDArray:
    """Apply ``fn`` to ``(n, 4, 4)`` float64 chunks of ``m`` and gather into ``(..., *tail)``.

    The chunks are views where ``m`` is float64 (``fn`` must not write to them); ``chunk``
    matrices each, ``_CHUNK`` by default.
    """
    chunk = chunk or _CHUNK
    batch = m.shape[:-2]
    flat = m.reshape(-1, 4, 4)
    out = np.empty((flat.shape[0], *tail), dtype=dtype)
    for start in range(0, flat.shape[0], chunk):
        out[start : start + chunk] = fn(np.asarray(flat[start : start + chunk], dtype=np.float64))
    return out.reshape(batch + tail)


def _scale(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest absolute entry per matrix (1 for the zero matrix); ``(n,)``."""
    s = np.max(np.abs(m), axis=(-2, -1))
    return np.where(s > 0, s, 1.0)


def coherency_matrix(mueller: ArrayLike) -> NDArray[np.complex128]:
    """Cloude coherency matrix ``H = 1/4 sum_ij m_ij (sigma_i kron conj(sigma_j))``.

    ``H`` is Hermitian with ``tr H = m00``; it is positive semidefinite iff the Mueller matrix is
    Cloude-physical, and has rank 1 iff it is pure (Jones-derived). This map is linear, so NaN
    entries simply propagate.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.

    Returns:
        Coherency matrices, complex128, shape ``(..., 4, 4)``.

    Raises:
        ValueError: if the shape is not ``(..., 4, 4)``.

    Example:
        An ideal horizontal polarizer is pure: its coherency matrix has a single nonzero entry.

        >>> from pbrdf.polar.mueller import linear_polarizer
        >>> coherency_matrix(linear_polarizer(0.0)).real.round(6) + 0.0
        array([[0.5, 0. , 0. , 0. ],
               [0. , 0. , 0. , 0. ],
               [0. , 0. , 0. , 0. ],
               [0. , 0. , 0. , 0. ]])
    """
    m = _checked(mueller, finite=False).astype(np.float64)
    return (m.reshape(*m.shape[:-2], 16) @ _M2H).reshape(m.shape)


def mueller_from_coherency(coherency: ArrayLike) -> NDArray[np.float64]:
    """Mueller matrix of a coherency matrix: ``m_ij = Re tr[(sigma_i kron conj(sigma_j)) H]``.

    Exact inverse of :func:`coherency_matrix`; for a non-Hermitian input only the Hermitian
    part contributes.

    Args:
        coherency: coherency matrices, shape ``(..., 4, 4)``, complex or real.

    Returns:
        Mueller matrices, float64, shape ``(..., 4, 4)``.

    Raises:
        ValueError: if the shape is not ``(..., 4, 4)``.

    Example:
        ``H = I / 4`` is the ideal depolarizer (equal mix of the four Pauli systems):

        >>> mueller_from_coherency(np.eye(4) / 4).round(6) + 0.0
        array([[1., 0., 0., 0.],
               [0., 0., 0., 0.],
               [0., 0., 0., 0.],
               [0., 0., 0., 0.]])
    """
    h = np.asarray(coherency, dtype=np.complex128)
    check_last_dims(h, (4, 4), "coherency")
    return np.real(h.reshape(*h.shape[:-2], 16) @ _H2M).reshape(h.shape)


def _eigh_coherency(m: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
    """Ascending eigenvalues and eigenvectors of the hermitised H of ``m / scale``; and scale."""
    scale = _scale(m)
    h = coherency_matrix(m / scale[:, None, None])
    h = 0.5 * (h + np.conj(np.swapaxes(h, -1, -2)))
    lam, vec = np.linalg.eigh(h)
    return lam, vec, scale


def coherency_eigenvalues(mueller: ArrayLike) -> NDArray[np.float64]:
    """Eigenvalues of the coherency matrix in descending order; they sum to ``m00``.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.

    Returns:
        Real eigenvalues (``eigh`` of ``(H + H^H) / 2``), float64, shape ``(..., 4)``.

    Raises:
        ValueError: for a wrong shape or NaN/Inf entries.

    Example:
        The ideal depolarizer ``diag(1, 0, 0, 0)`` has four equal eigenvalues ``m00 / 4``:

        >>> coherency_eigenvalues(np.diag([1.0, 0.0, 0.0, 0.0])).round(6)
        array([0.25, 0.25, 0.25, 0.25])
    """
    m = _checked(mueller)

    def fn(c: NDArray[np.float64]) -> NDArray[np.float64]:
        lam, _, scale = _eigh_coherency(c)
        return lam[:, ::-1] * scale[:, None]

    return _chunked(fn, m, (4,), np.float64)


def _cloude_eigh(c: NDArray[np.float64], rtol: float) -> NDArray[np.bool_]:
    """The eigenvalue route: ``m00 > 0`` and ``lambda_min(H) >= -rtol |m00|`` (``eigvalsh``)."""
    scale = _scale(c)
    h = coherency_matrix(c / scale[:, None, None])
    lam = np.linalg.eigvalsh(0.5 * (h + np.conj(np.swapaxes(h, -1, -2))))
    return (c[:, 0, 0] > 0) & (lam[:, 0] >= -rtol * np.abs(c[:, 0, 0] / scale))


def _cloude_pivots(c: NDArray[np.float64], rtol: float) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Certain verdicts of the closed-form Cloude test on ``(n, 4, 4)`` float64 matrices.

    Returns ``(physical, not_physical)``; a matrix in neither is uncertain (within rounding of
    the tolerance boundary, or a pivot overflowed) and needs the eigenvalues. The pivots of
    ``LDL^H = 4 (H + rtol m00 I)`` are computed on 16 real rows of ``n`` entries each.
    """
    n = len(c)
    a = _H_ROWS @ c.reshape(n, 16).T  # 4 H and m00: rows as in _H_ROWS; tr(4 H) = 4 m00
    unit = a[16]  # the scale of the pivots: m00
    lit = None  # every m00 in [1 / _HUGE, _HUGE] (checked by the chunk's extremes)
    if n and not 1.0 / _HUGE <= unit.min() <= unit.max() <= _HUGE:
        lit = unit > 0
        unit = np.where(lit, unit, 1.0)
        if np.any((unit < 1.0 / _HUGE) | (unit > _HUGE)):
            a /= unit
            unit = np.ones(n)
    a[:4] += (4.0 * rtol) * unit
    tmp, tmp2 = np.empty(n), np.empty(n)

    def sub_products(dst: NDArray, x1: NDArray, y1: NDArray, x2: NDArray, y2: NDArray, sign: float) -> None:
        """``dst -= x1 y1 + sign x2 y2`` in place."""
        np.multiply(x1, y1, out=tmp)
        np.multiply(x2, y2, out=tmp2)
        if sign > 0:
            np.add(tmp, tmp2, out=tmp)
        else:
            np.subtract(tmp, tmp2, out=tmp)
        np.subtract(dst, tmp, out=dst)

    # A zero, negative or non-finite pivot only spoils the pivots after it, which the verdict
    # below ignores.
    with np.errstate(all="ignore"):
        # Step 1: eliminate column 0; b = (h10, h20, h30) / d0 as Re rows 0-2, Im rows 3-5.
        b = a[4:10] * (1.0 / a[0])
        a[1:4] -= a[4:7] * b[:3] + a[7:10] * b[3:]
        r10, r20, i10, i20 = a[4], a[5], a[7], a[8]
        sub_products(a[10], b[1], r10, b[4], i10, 1.0)  # h21 -= b2 conj(h10)
        sub_products(a[12], b[4], r10, b[1], i10, -1.0)
        sub_products(a[11], b[2], r10, b[5], i10, 1.0)  # h31 -= b3 conj(h10)
        sub_products(a[13], b[5], r10, b[2], i10, -1.0)
        sub_products(a[14], b[2], r20, b[5], i20, 1.0)  # h32 -= b3 conj(h20)
        sub_products(a[15], b[5], r20, b[2], i20, -1.0)
        # Step 2: eliminate column 1; e = (h21, h31) / d1 as Re rows 0-1, Im rows 2-3.
        e = a[10:14] * (1.0 / a[1])
        sub_products(a[2], e[0], a[10], e[2], a[12], 1.0)  # h22 -= |h21|^2 / d1
        sub_products(a[3], e[1], a[11], e[3], a[13], 1.0)  # h33 -= |h31|^2 / d1
        sub_products(a[14], e[1], a[10], e[3], a[12], 1.0)  # h32 -= e3 conj(h21)
        sub_products(a[15], e[3], a[10], e[1], a[12], -1.0)
        # Step 3: h33 -= |h32|^2 / d2.
        np.multiply(a[14], a[14], out=tmp)
        np.multiply(a[15], a[15], out=tmp2)
        tmp += tmp2
        tmp /= a[2]
        a[3] -= tmp
        # Verdict: every pivot in [tol, top], or the first pivot outside that interval finite and
        # clearly negative or above top (the pivots of a PSD H' lie in [0, tr(4 H')], and
        # top = 2 tr(4 H') is far beyond their rounding errors). An overflow (+-Inf, NaN) leaves
        # the verdict to the eigenvalues.
        pivots = a[:4]
        top = (8.0 + 32.0 * rtol) * unit
        good = (pivots >= _PIVOT_TOL * unit) & (pivots <= top)
        bad = ((pivots <= -_PIVOT_TOL * unit) | (pivots > top)) & np.isfinite(pivots)
    physical, not_physical = good[0], bad[0]
    if lit is not None:
        physical &= lit
        not_physical |= ~lit
    for k in range(1, 4):
        not_physical |= physical & bad[k]
        physical &= good[k]
    return physical, not_physical


def _cloude_chunk(c: NDArray[np.float64], rtol: float) -> NDArray[np.bool_]:
    """Closed-form Cloude test with the eigenvalue route for the uncertain matrices."""
    physical, not_physical = _cloude_pivots(c, rtol)
    unsure = ~(physical | not_physical)
    if np.any(unsure):
        physical[unsure] = _cloude_eigh(c[unsure], rtol)
    return physical


def is_cloude_physical(
    mueller: ArrayLike, *, rtol: float = 1e-6, method: Literal["pivots", "eigh"] = "pivots"
) -> NDArray[np.bool_]:
    """True where the coherency matrix is positive semidefinite and ``m00 > 0``.

    An eigenvalue counts as non-negative if it is ``>= -rtol * |tr H|``: a pure matrix stored in
    float32 has eigenvalues of about ``-1e-8 * m00`` and must pass. Equivalently, the test is
    ``H + rtol m00 I >= 0``.

    ``method="pivots"`` (default) decides this from the pivots of ``4 (H + rtol m00 I) =
    L D L^H``, in closed form (see the module notes); the few matrices whose first
    non-positive pivot lies within rounding of zero get the eigenvalue verdict. ``"eigh"``
    computes the eigenvalues of every matrix (the reference; slower).

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.
        rtol: tolerance on the smallest eigenvalue, relative to ``|tr H| = |m00|``; ``>= 0``.
        method: ``"pivots"`` or ``"eigh"``.

    Returns:
        Booleans, shape ``(...)`` (a numpy bool for a single matrix).

    Raises:
        ValueError: for a wrong shape, NaN/Inf entries, a negative ``rtol`` or an unknown method.

    Example:
        A quarter-wave plate is physical; ``diag(1, 1, 1, -1)`` (a mirror-like sign flip of s3
        alone) is not -- it would need a negative weight in the Jones ensemble:

        >>> from pbrdf.polar.mueller import qwp
        >>> print(is_cloude_physical(qwp(0.3)), is_cloude_physical(np.diag([1.0, 1, 1, -1])))
        True False
    """
    if not rtol >= 0:
        raise ValueError(f"rtol must be >= 0, got {rtol!r}")
    if method not in ("pivots", "eigh"):
        raise ValueError(f"method must be 'pivots' or 'eigh', got {method!r}")
    m = _checked(mueller)
    if method == "eigh":
        return _chunked(lambda c: _cloude_eigh(c, rtol), m, (), np.bool_)[()]
    return _chunked(lambda c: _cloude_chunk(c, rtol), m, (), np.bool_, _LDL_CHUNK)[()]


def cloude_filter(mueller: ArrayLike, *, renormalize: bool = True) -> NDArray[np.floating]:
    """Nearest Cloude-physical Mueller matrix: clip the negative coherency eigenvalues to zero.

    ``H <- (H + H^H) / 2``; ``(lambda, U) = eigh(H)``; ``H' = U diag(max(lambda, 0)) U^H``; back to
    ``M'``. Since ``M -> H`` is an isometry up to the factor 1/2, ``M'`` (without renormalization)
    is the Frobenius-nearest Cloude-physical matrix to ``M``, and physical matrices are returned
    unchanged (up to round-off).

    Clipping raises the trace: ``m00' = sum(max(lambda, 0)) >= m00``. With ``renormalize=True`` the
    result is rescaled so that ``m00'`` equals the input ``m00`` (a positive rescaling keeps it
    physical but it is then no longer the Frobenius-nearest matrix). Where that is impossible --
    the input ``m00 <= 0`` or the filtered matrix is zero -- the result is the zero matrix.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.
        renormalize: keep the input intensity transmittance ``m00``.

    Returns:
        Filtered Mueller matrices, same shape and (float) dtype as the input.

    Raises:
        ValueError: for a wrong shape or NaN/Inf entries (mask invalid entries first).

    Example:
        ``diag(1, 1, 1, -1)`` is the Pauli mixture ``(I + HWP_0 + HWP_45 - circular HWP) / 2``;
        filtering drops the negative circular half-wave term and keeps ``m00 = 1``:

        >>> m = cloude_filter(np.diag([1.0, 1, 1, -1]))
        >>> print(is_cloude_physical(m), np.diag(m).round(4).tolist())
        True [1.0, 0.3333, 0.3333, -0.3333]
    """
    m = _checked(mueller)

    def fn(c: NDArray[np.float64]) -> NDArray[np.float64]:
        lam, vec, scale = _eigh_coherency(c)
        lam = np.maximum(lam, 0.0)
        h = (vec * lam[:, None, :]) @ np.conj(np.swapaxes(vec, -1, -2))
        out = mueller_from_coherency(h)
        if renormalize:
            m00_in, m00_out = c[:, 0, 0] / scale, out[:, 0, 0]
            ok = (m00_in > 0) & (m00_out > 0)
            factor = np.zeros_like(m00_in)
            np.divide(m00_in, m00_out, out=factor, where=ok)
            out = out * factor[:, None, None]
        return out * scale[:, None, None]

    return _chunked(fn, m, (4, 4), m.dtype)


def _gk_chunk(c: NDArray[np.float64], rtol: float, atol: float) -> NDArray[np.bool_]:
    """Robust Givens-Kostinski test on ``(n, 4, 4)`` float64 matrices."""
    m00 = c[:, 0, 0]
    bound = m00 * (1 + rtol)
    # (a) non-negative output intensity, m00 >= |(m01, m02, m03)| (rejects -I), and the necessary
    # |m_ij| <= m00 (outputs of (1, +-e_j) physical), which also keeps M / m00 bounded below.
    ok = (m00 > 0) & (np.linalg.norm(c[:, 0, 1:], axis=-1) <= bound) & (np.max(np.abs(c), axis=(-2, -1)) <= bound)
    # The criterion is invariant under positive scaling: normalise to m00 = 1 (identity for
    # rejected matrices, so that nothing overflows).
    mt = np.where(ok[:, None, None], c / np.where(ok, m00, 1.0)[:, None, None], np.eye(4))
    n_mat = (_G[:, None] * np.swapaxes(mt, -1, -2) * _G) @ mt  # G M^T G M
    lam = np.linalg.eigvals(n_mat).astype(np.complex128)
    # Eigenvalue tolerance on the scale of N (|N| <= |M|^2), not of lambda_max: pure matrices
    # near a polarizer have N = |det J|^2 I with a tiny |det J|.
    tol = rtol * np.sum(mt * mt, axis=(-2, -1)) + atol
    # (b) real spectrum.
    ok &= np.all(np.abs(lam.imag) <= tol[:, None], axis=-1)
    # (c) the eigenspace of the largest eigenvalue, ker(N - lambda_max I), contains a Stokes vector.
    # Its basis comes from an SVD, not from eig's eigenvectors: for a pure matrix N = c I and eig
    # returns an arbitrary, possibly rank-deficient basis of the degenerate eigenspace.
    shifted = n_mat - np.max(lam.real, axis=-1)[:, None, None] * np.eye(4)
    _, sv, vt = np.linalg.svd(shifted)
    null = sv <= tol[:, None]  # (n, 4): rows of vt spanning the eigenspace
    q = vt @ (_G[:, None] * np.swapaxes(vt, -1, -2))  # v^T G v on the orthonormal rows of vt
    q = q * (null[:, :, None] & null[:, None, :]) - np.eye(4) * ~null[:, None, :]
    ok &= np.linalg.eigvalsh(q)[:, -1] >= -rtol
    return ok


def is_givens_kostinski(mueller: ArrayLike, *, rtol: float = 1e-6, atol: float = 1e-9) -> NDArray[np.bool_]:
    """Givens-Kostinski (Stokes) criterion: ``M`` maps physical Stokes vectors to physical ones.

    Method: with ``G = diag(1, -1, -1, -1)`` and ``N = G M^T G M`` of ``M / m00`` (the test is
    scale invariant), accept iff

    (a) ``m00 > 0``, ``|(m01, m02, m03)| <= m00 (1 + rtol)`` (non-negative output intensity;
        without it ``-I`` would pass) and ``|m_ij| <= m00 (1 + rtol)`` (necessary: the images
        of ``(1, +-e_j)`` must be physical);
    (b) the spectrum of ``N`` is real: ``|Im lambda| <= tol``;
    (c) the eigenspace of the largest eigenvalue contains a time- or light-like vector ``v``
        (``v^T G v >= 0``, so ``v`` or ``-v`` is a physical Stokes vector). The eigenspace is
        ``ker(N - lambda_max I)``, spanned by the right singular vectors of ``N - lambda_max I``
        with singular values ``<= tol``; the largest eigenvalue of ``G`` restricted to that
        orthonormal basis must be ``>= -rtol``. Unused basis vectors are masked out, so the
        variable dimension is vectorised.

    Here ``tol = rtol * ||M / m00||_F^2 + atol`` is on the scale of ``N``, not of
    ``lambda_max``: a pure matrix near a polarizer has ``N = |det J|^2 I`` with a tiny
    ``|det J|``. Taking the whole eigenspace matters: for a pure matrix the eigenvalue is
    four-fold and ``np.linalg.eig`` returns an arbitrary, possibly complex or even
    rank-deficient basis, so testing one eigenvector (as a naive implementation does) rejects
    most pure matrices. If ``N`` has a non-trivial Jordan block at ``lambda_max`` (the van der
    Mee case), its eigenvalues split by about ``sqrt(eps |N|)``: fine in float64, but such
    matrices stored in float32 may be rejected by (b).

    .. warning::
        The Givens-Kostinski criterion is weaker than Cloude's: ``diag(1, 1, 1, -1)`` maps the
        Stokes cone onto itself and passes, yet it is no ensemble of Jones systems (negative
        coherency eigenvalue). Use :func:`is_cloude_physical` or :func:`is_mueller_physical` to
        decide physical realizability; after :func:`cloude_filter` this test is only a
        consistency check.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.
        rtol: relative tolerance of every comparison: (a), the eigenvalue tolerance on the scale
            of ``N`` in (b) and (c), and the light-cone test in (c). The default accepts pure
            matrices stored in float32 with a tenfold margin.
        atol: absolute term added to the eigenvalue tolerance (on ``N`` of ``M / m00``).

    Returns:
        Booleans, shape ``(...)`` (a numpy bool for a single matrix).

    Raises:
        ValueError: for a wrong shape or NaN/Inf entries.

    References:
        C. R. Givens and A. B. Kostinski, J. Mod. Opt. 40(3):471-481, 1993. C. V. M. van der Mee,
        "An eigenvalue criterion for matrices transforming Stokes parameters", J. Math. Phys.
        34(11):5072, 1993 (non-diagonalisable case).

    Example:
        ``-I`` has a physical eigenvector but flips the sign of the intensity, so it fails;
        ``diag(1, 1, 1, -1)`` passes Givens-Kostinski although it is not Cloude-physical:

        >>> print(is_givens_kostinski(-np.eye(4)), is_givens_kostinski(np.diag([1.0, 1, 1, -1])))
        False True
    """
    m = _checked(mueller)
    return _chunked(lambda c: _gk_chunk(c, rtol, atol), m, (), np.bool_)[()]


def is_mueller_physical(mueller: ArrayLike, *, rtol: float = 1e-6) -> NDArray[np.bool_]:
    """True where a Mueller matrix is physically realizable: Cloude-physical, hence also Givens-Kostinski.

    Givens-Kostinski is implied and not evaluated: a convex sum of Jones systems maps the Stokes
    cone into itself. Within the tolerance, ``H + rtol m00 I >= 0`` makes ``M + 4 rtol m00
    diag(1, 0, 0, 0)`` exactly physical, so a matrix that passes here passes
    :func:`is_givens_kostinski` at about ``4 rtol``, not always at ``rtol``: near-pure matrices
    with ``lambda_min(H)`` in ``[-rtol m00, 0)`` can exceed ``|m_0j| <= m00 (1 + rtol)``.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.
        rtol: relative tolerance of the Cloude test.

    Returns:
        Booleans, shape ``(...)`` (a numpy bool for a single matrix).

    Raises:
        ValueError: for a wrong shape or NaN/Inf entries.

    Example:
        An ideal polarizer and a half depolarizer are physical, ``diag(1, .9, .9, -.9)`` is not:

        >>> from pbrdf.polar.mueller import depolarizer, linear_polarizer
        >>> m = np.stack([linear_polarizer(0.4), depolarizer(0.5), np.diag([1, 0.9, 0.9, -0.9])])
        >>> is_mueller_physical(m)
        array([ True,  True, False])
    """
    return is_cloude_physical(mueller, rtol=rtol)
