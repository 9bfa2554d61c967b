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

    Two tests of increasing strength are provided:

    * :func:`is_givens_kostinski` -- the *Stokes criterion*: ``M`` maps every physical Stokes
      vector to a physical Stokes vector (no over-polarization, no negative intensity).
    * :func:`is_cloude_physical` -- ``H >= 0``: ``M`` is an ensemble of deterministic
      (Jones) systems. Every Cloude-physical matrix passes Givens-Kostinski, not vice versa.

    The spectral functions reject NaN and Inf entries with a ``ValueError``; mask invalid
    entries (e.g. the invalid geometry of measured pBRDF tables) before calling them.

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

_PAULI = np.array([[[1, 0], [0, 1]], [[1, 0], [0, -1]], [[0, 1], [1, 0]], [[0, -1j], [1j, 0]]], dtype=np.complex128)
# _BASIS[i, j] = sigma_i kron conj(sigma_j); all 16 are Hermitian with tr(B_ij B_kl) = 4 delta_ik delta_jl.
_BASIS = np.einsum("iab,jcd->ijacbd", _PAULI, _PAULI.conj()).reshape(4, 4, 4, 4)
# As 16x16 maps on row-flattened arrays: vec(H) = vec(M) @ _M2H, vec(M) = Re(vec(H) @ _H2M).
_M2H = 0.25 * _BASIS.reshape(16, 16)
_H2M = np.ascontiguousarray(np.swapaxes(_BASIS, -1, -2).reshape(16, 16).T)
_G = np.array([1.0, -1.0, -1.0, -1.0])
_NONFINITE_MSG = "mueller contains NaN or Inf; mask invalid entries first"


def _checked(mueller: ArrayLike, *, finite: bool = True) -> NDArray[np.floating]:
    m = as_float_array(mueller)
    check_last_dims(m, (4, 4), "mueller")
    if finite and not np.all(np.isfinite(m)):
        raise ValueError(_NONFINITE_MSG)
    return m


def _chunked(fn: Callable[[NDArray[np.float64]], NDArray], m: NDArray, tail: tuple[int, ...], dtype: type) -> NDArray:
    """Apply ``fn`` to ``(n, 4, 4)`` float64 chunks of ``m`` and gather into ``(..., *tail)``."""
    batch = m.shape[:-2]
    flat = m.reshape(-1, 4, 4)
    out = np.empty((flat.shape[0], *tail), dtype=dtype)
    for start in range(0, flat.shape[0], _CHUNK):
        out[start : start + _CHUNK] = fn(flat[start : start + _CHUNK].astype(np.float64))
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


def is_cloude_physical(mueller: ArrayLike, *, rtol: float = 1e-6) -> NDArray[np.bool_]:
    """True where the coherency matrix is positive semidefinite and ``m00 > 0``.

    An eigenvalue counts as non-negative if it is ``>= -rtol * |tr H|``: a pure matrix stored in
    float32 has eigenvalues of about ``-1e-8 * m00`` and must pass.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.
        rtol: tolerance on the smallest eigenvalue, relative to ``|tr H| = |m00|``.

    Returns:
        Booleans, shape ``(...)`` (a numpy bool for a single matrix).

    Raises:
        ValueError: for a wrong shape or NaN/Inf entries.

    Example:
        A quarter-wave plate is physical; ``diag(1, 1, 1, -1)`` (a mirror-like sign flip of s3
        alone) is not -- it would need a negative weight in the Jones ensemble:

        >>> from pbrdf.polar.mueller import qwp
        >>> print(is_cloude_physical(qwp(0.3)), is_cloude_physical(np.diag([1.0, 1, 1, -1])))
        True False
    """
    m = _checked(mueller)

    def fn(c: NDArray[np.float64]) -> NDArray[np.bool_]:
        lam, _, scale = _eigh_coherency(c)
        trace = c[:, 0, 0] / scale
        return (c[:, 0, 0] > 0) & (lam[:, 0] >= -rtol * np.abs(trace))

    return _chunked(fn, m, (), np.bool_)[()]


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
    """True where a Mueller matrix passes both the Cloude and the Givens-Kostinski tests.

    Args:
        mueller: Mueller matrices, shape ``(..., 4, 4)``.
        rtol: relative tolerance passed to both tests.

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
    m = _checked(mueller)
    return is_cloude_physical(m, rtol=rtol) & is_givens_kostinski(m, rtol=rtol)
