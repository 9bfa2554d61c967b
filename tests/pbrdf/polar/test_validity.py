"""Tests of pbrdf.polar.validity against physics (Jones calculus, the Stokes cone) and published fixtures."""

from functools import reduce

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from pbrdf.polar import validity
from pbrdf.polar.mueller import (
    depolarizer,
    jones_to_mueller,
    linear_diattenuator,
    linear_polarizer,
    qwp,
    retarder,
    rotate_element,
)
from pbrdf.polar.stokes import is_physical_stokes, stokes
from pbrdf.polar.validity import (
    cloude_filter,
    coherency_eigenvalues,
    coherency_matrix,
    is_cloude_physical,
    is_givens_kostinski,
    is_mueller_physical,
    mueller_from_coherency,
)
from tests.conftest import TOL

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

# Ossikovski, Opt. Lett. 37:578 (2012); also the fixture of pyCloude's tests.
OSSIKOVSKI = np.array(
    [
        [1.0, 0.0707, 0.0348, -0.0060],
        [0.0480, 0.4099, 0.0077, 0.0650],
        [0.0162, -0.0184, 0.2243, -0.3580],
        [0.0021, -0.0465, 0.3571, 0.1783],
    ]
)
OSSIKOVSKI_EIGENVALUES = np.array([0.5614, 0.1716, 0.1398, 0.1272])

# Mueller matrices of the four Pauli Jones systems (I, HWP at 0, HWP at 45 deg, circular HWP).
PAULI_DIAGONALS = np.array([[1, 1, 1, 1], [1, 1, -1, -1], [1, -1, 1, -1], [1, -1, -1, 1]], dtype=float)


def random_jones(rng, n):
    return rng.normal(size=(n, 2, 2)) + 1j * rng.normal(size=(n, 2, 2))


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="module")
def jones(rng):
    return random_jones(rng, 1000)


@pytest.fixture(scope="module")
def pure(jones):
    return jones_to_mueller(jones)


def physical_elements():
    return {
        "polarizer": linear_polarizer(0.3),
        "identity": np.eye(4),
        "depolarizer": depolarizer(0.0),
        "partial depolarizer": depolarizer(0.5),
        "qwp": qwp(0.2),
        "polarizer then depolarizer": depolarizer(0.0) @ linear_polarizer(0.0),
        "depolarizer then polarizer": linear_polarizer(0.0) @ depolarizer(0.0),
        "diattenuator": linear_diattenuator(0.9, 0.2, 1.1),
    }


# --------------------------------------------------------------------------- coherency matrix


def test_coherency_matches_explicit_table(rng):
    m = rng.normal(size=(4, 4))
    h4 = 4 * coherency_matrix(m)
    expected = {
        (0, 0): m[0, 0] + m[0, 1] + m[1, 0] + m[1, 1],
        (0, 1): m[0, 2] + m[1, 2] + 1j * (m[0, 3] + m[1, 3]),
        (0, 3): m[2, 2] + m[3, 3] + 1j * (m[2, 3] - m[3, 2]),
        (1, 2): m[2, 2] - m[3, 3] - 1j * (m[2, 3] + m[3, 2]),
        (2, 0): m[2, 0] + m[2, 1] + 1j * (m[3, 0] + m[3, 1]),
        (2, 3): m[0, 2] - m[1, 2] + 1j * (m[0, 3] - m[1, 3]),
        (3, 3): m[0, 0] - m[0, 1] - m[1, 0] + m[1, 1],
    }
    for (i, j), value in expected.items():
        assert h4[i, j] == pytest.approx(value, abs=TOL.f64), (i, j)


def test_coherency_round_trip_trace_and_hermitian(rng):
    m = rng.normal(size=(500, 4, 4))
    h = coherency_matrix(m)
    assert h.dtype == np.complex128
    np.testing.assert_allclose(mueller_from_coherency(h), m, rtol=0, atol=TOL.f64)
    np.testing.assert_allclose(np.trace(h, axis1=-2, axis2=-1), m[:, 0, 0], rtol=0, atol=TOL.f64)
    np.testing.assert_allclose(h, np.conj(np.swapaxes(h, -1, -2)), rtol=0, atol=TOL.f64_exact)
    # Isometry up to scale: ||H||_F^2 = ||M||_F^2 / 4.
    np.testing.assert_allclose(np.sum(np.abs(h) ** 2, axis=(1, 2)), np.sum(m**2, axis=(1, 2)) / 4, rtol=1e-12)
    # Every Hermitian matrix comes from a real Mueller matrix.
    a = rng.normal(size=(100, 4, 4)) + 1j * rng.normal(size=(100, 4, 4))
    herm = a + np.conj(np.swapaxes(a, -1, -2))
    np.testing.assert_allclose(coherency_matrix(mueller_from_coherency(herm)), herm, rtol=0, atol=TOL.f64)


def test_coherency_of_jones_matrix_is_its_projector(jones, pure):
    # For M = A (J kron J*) A^-1 the coherency matrix is vec(J) vec(J)^H / 2: rank 1, trace m00.
    k = jones.reshape(-1, 4)
    expected = 0.5 * k[:, :, None] * np.conj(k[:, None, :])
    np.testing.assert_allclose(coherency_matrix(pure), expected, rtol=0, atol=TOL.f64)
    lam = coherency_eigenvalues(pure)
    np.testing.assert_allclose(lam[:, 0], pure[:, 0, 0], rtol=1e-12)
    np.testing.assert_allclose(lam[:, 1:], 0, atol=1e-12 * pure[:, :1, 0].max())


def test_ossikovski_coherency_eigenvalues():
    lam = coherency_eigenvalues(OSSIKOVSKI)
    np.testing.assert_allclose(lam, OSSIKOVSKI_EIGENVALUES, atol=1e-4)
    assert lam.sum() == pytest.approx(1.0, abs=TOL.f64)
    assert is_cloude_physical(OSSIKOVSKI)
    assert is_givens_kostinski(OSSIKOVSKI)
    # Nearest pure (rank-1) matrix keeps the dominant eigenvector; pyCloude's first row.
    h = coherency_matrix(OSSIKOVSKI)
    w, u = np.linalg.eigh(h)
    rank1 = mueller_from_coherency(w[-1] * np.outer(u[:, -1], np.conj(u[:, -1])))
    np.testing.assert_allclose(rank1[0], [0.5614, 0.0789, 0.0310, -0.0076], atol=1e-4)


def test_eigenvalues_descending_and_sum_to_m00(rng):
    m = rng.normal(size=(300, 4, 4))
    lam = coherency_eigenvalues(m)
    assert lam.shape == (300, 4)
    assert np.all(np.diff(lam, axis=-1) <= 0)
    np.testing.assert_allclose(lam.sum(axis=-1), m[:, 0, 0], atol=TOL.f64)


def test_pauli_weight_depolarizers():
    # diag(1, a1, a2, a3) built from Pauli weights w has coherency eigenvalues w (m00 = 1).
    w = np.array([0.4, 0.3, 0.2, 0.1])
    m = np.diag(w @ PAULI_DIAGONALS)
    np.testing.assert_allclose(coherency_eigenvalues(m), w, atol=TOL.f64)


# --------------------------------------------------------------------------- pure matrices


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_random_pure_matrices_pass_both(pure, dtype):
    m = pure.astype(dtype)
    assert is_givens_kostinski(m).all()
    assert is_cloude_physical(m).all()
    assert is_mueller_physical(m).all()
    lam = coherency_eigenvalues(m)
    assert np.all(lam >= -1e-6 * m[:, :1, 0])


def test_pure_matrices_have_degenerate_gk_spectrum(jones, pure):
    # The pitfall of a single-eigenvector GK test: G M^T G M = |det J|^2 I for a pure matrix,
    # so every vector is an eigenvector of the (four-fold) largest eigenvalue.
    g = np.diag([1.0, -1.0, -1.0, -1.0])
    n = g @ np.swapaxes(pure, -1, -2) @ g @ pure
    det2 = np.abs(np.linalg.det(jones)) ** 2
    np.testing.assert_allclose(n, det2[:, None, None] * np.eye(4), rtol=0, atol=1e-12 * det2.max())


# --------------------------------------------------------------------------- named matrices


@pytest.mark.parametrize("name", list(physical_elements()))
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_named_physical_elements_pass_both(name, dtype):
    m = physical_elements()[name].astype(dtype)
    assert is_givens_kostinski(m)
    assert is_cloude_physical(m)
    assert is_mueller_physical(m)


def test_minus_identity_rejected():
    assert not is_givens_kostinski(-np.eye(4))
    assert not is_cloude_physical(-np.eye(4))


@pytest.mark.parametrize("diag", [(1, 1, 1, -1), (1, 0.9, 0.9, -0.9)])
def test_gk_is_weaker_than_cloude(diag):
    m = np.diag(np.array(diag, dtype=float))
    assert is_givens_kostinski(m)
    assert not is_cloude_physical(m)
    assert not is_mueller_physical(m)
    assert coherency_eigenvalues(m)[-1] < -0.4


def test_over_polarizing_and_amplifying_matrices_rejected():
    amplifier = np.diag([1.0, 1.1, 1.0, 1.0])  # turns fully polarized light into DOP 1.1
    negative = np.eye(4)
    negative[0, 1] = 1.2  # negative intensity for (1, -1, 0, 0)
    for m in (amplifier, negative):
        assert not is_givens_kostinski(m)
        assert not is_cloude_physical(m)


def test_gk_agrees_with_sampled_stokes_cone(rng):
    # Independent oracle: M is GK-physical iff it maps every fully polarized state (1, u) to a
    # physical Stokes vector. A sampled violation proves non-physicality.
    n = 3000
    u = rng.normal(size=(n, 3))
    states = np.concatenate([np.ones((n, 1)), u / np.linalg.norm(u, axis=1, keepdims=True)], axis=1)
    m = np.diag([1.0, 0.6, 0.6, 0.6]) + rng.normal(scale=0.15, size=(1500, 4, 4))
    out = np.einsum("kij,nj->kni", m, states)
    sampled_ok = np.all(is_physical_stokes(out, rtol=0), axis=1)
    gk = is_givens_kostinski(m)
    assert 0.1 < gk.mean() < 0.9  # both outcomes are exercised
    assert not np.any(gk & ~sampled_ok)
    # Matrices GK rejects although no sampled state violated must violate between the samples.
    assert np.mean(~gk & sampled_ok) < 0.02


# --------------------------------------------------------------------------- Cloude filter


@pytest.fixture(scope="module")
def noisy(pure, rng):
    return pure[:500] / pure[:500, :1, :1] + rng.normal(scale=0.05, size=(500, 4, 4))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("renormalize", [True, False])
def test_filtered_noisy_matrices_pass_both(noisy, dtype, renormalize):
    assert not is_cloude_physical(noisy).all()
    f = cloude_filter(noisy.astype(dtype), renormalize=renormalize)
    assert f.dtype == dtype
    assert is_cloude_physical(f).all()
    assert is_givens_kostinski(f).all()


def test_filter_keeps_physical_matrices(pure):
    mats = np.concatenate([pure[:200], np.stack(list(physical_elements().values())), OSSIKOVSKI[None]])
    for renormalize in (True, False):
        np.testing.assert_allclose(cloude_filter(mats, renormalize=renormalize), mats, rtol=0, atol=1e-10)


def test_filter_is_the_frobenius_projection(noisy, pure, rng):
    f = cloude_filter(noisy, renormalize=False)
    # Projection onto the convex cone of physical matrices: idempotent, and for every physical
    # P the angle at F between X and P is obtuse, <X - F, P - F> <= 0, so |X - F| <= |X - P|.
    np.testing.assert_allclose(cloude_filter(f, renormalize=False), f, atol=TOL.f64)
    w = rng.dirichlet(np.ones(4), size=200)
    candidates = np.concatenate(
        [
            pure[:500] / pure[:500, :1, :1],  # the noise-free pure part of each input
            np.broadcast_to(np.eye(4), (500, 4, 4)),
            np.broadcast_to(depolarizer(0.0), (500, 4, 4)),
            np.tile(w @ PAULI_DIAGONALS, (3, 1))[:500, :, None] * np.eye(4),
        ]
    ).reshape(4, 500, 4, 4)
    assert is_mueller_physical(candidates).all()
    dist_f = np.linalg.norm(noisy - f, axis=(-2, -1))
    for p in candidates:
        inner = np.sum((noisy - f) * (p - f), axis=(-2, -1))
        assert np.all(inner <= 1e-12)
        assert np.all(dist_f <= np.linalg.norm(noisy - p, axis=(-2, -1)) + 1e-12)
        for t in (1e-3, 0.1, 0.5, 1.0):
            mix = (1 - t) * f + t * p
            assert np.all(dist_f <= np.linalg.norm(noisy - mix, axis=(-2, -1)) + 1e-12)


def test_filter_renormalize_keeps_m00(noisy):
    raw = cloude_filter(noisy, renormalize=False)
    f = cloude_filter(noisy, renormalize=True)
    np.testing.assert_allclose(f[:, 0, 0], noisy[:, 0, 0], rtol=1e-12)
    assert np.all(raw[:, 0, 0] >= noisy[:, 0, 0] - 1e-12)  # clipping raises the trace
    np.testing.assert_allclose(f, raw * (noisy[:, 0, 0] / raw[:, 0, 0])[:, None, None], rtol=1e-12)


def test_filter_of_impossible_intensity_is_zero():
    f = cloude_filter(np.stack([-np.eye(4), np.zeros((4, 4))]))
    assert np.array_equal(f, np.zeros((2, 4, 4)))
    # Without renormalization -I has no positive coherency eigenvalue: its projection is 0 too.
    assert np.allclose(cloude_filter(-np.eye(4), renormalize=False), 0, atol=TOL.f64_exact)


def test_filter_known_example():
    # diag(1,1,1,-1) = (I + HWP0 + HWP45 - circular HWP) / 2: Pauli weights (.5,.5,.5,-.5).
    # Clipping the negative weight and renormalizing gives weights (1/3, 1/3, 1/3, 0).
    f = cloude_filter(np.diag([1.0, 1.0, 1.0, -1.0]))
    np.testing.assert_allclose(f, np.diag(np.array([1, 1, 1, 0]) @ PAULI_DIAGONALS / 3), atol=TOL.f64)


# --------------------------------------------------------------------------- vectorisation


def test_batch_equals_loop(pure, noisy, rng):
    mix = np.concatenate([pure[:1000], noisy[:500], np.tile(noisy[:500], (7, 1, 1))])
    mix = mix + rng.normal(scale=0.02, size=mix.shape) * (rng.random(mix.shape[0]) < 0.5)[:, None, None]
    batch = mix[:5000].reshape(100, 50, 4, 4)
    gk = is_givens_kostinski(batch)
    cl = is_cloude_physical(batch)
    lam = coherency_eigenvalues(batch)
    filt = cloude_filter(batch)
    assert gk.shape == cl.shape == (100, 50) and lam.shape == (100, 50, 4) and filt.shape == batch.shape
    assert 0 < gk.mean() < 1 and 0 < cl.mean() < 1
    for i in range(0, 100, 3):
        for j in range(50):
            m = batch[i, j]
            assert is_givens_kostinski(m) == gk[i, j]
            assert is_cloude_physical(m) == cl[i, j]
            np.testing.assert_allclose(coherency_eigenvalues(m), lam[i, j], atol=1e-13)
            np.testing.assert_allclose(cloude_filter(m), filt[i, j], atol=1e-13)


def test_chunk_boundaries(monkeypatch, noisy):
    expected = (is_mueller_physical(noisy), coherency_eigenvalues(noisy), cloude_filter(noisy))
    monkeypatch.setattr(validity, "_CHUNK", 7)
    got = (is_mueller_physical(noisy), coherency_eigenvalues(noisy), cloude_filter(noisy))
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_allclose(got[1], expected[1], atol=1e-14)
    np.testing.assert_allclose(got[2], expected[2], atol=1e-14)


def test_large_batch(rng):
    m = np.broadcast_to(np.eye(4), (200_000, 4, 4)) + rng.normal(scale=0.05, size=(200_000, 4, 4))
    m = m.astype(np.float32)
    ok = is_mueller_physical(m)
    f = cloude_filter(m)
    assert ok.shape == (200_000,) and f.shape == m.shape and f.dtype == np.float32
    assert not ok.all()


def test_scalar_results_are_numpy_bools():
    for fn in (is_givens_kostinski, is_cloude_physical, is_mueller_physical):
        result = fn(np.eye(4))
        assert isinstance(result, np.bool_) and result


# --------------------------------------------------------------------------- properties


finite = st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False)
angle = st.floats(0.0, np.pi, allow_nan=False)
unit_interval = st.floats(0.0, 1.0, allow_nan=False, allow_subnormal=False)


@st.composite
def physical_element(draw):
    kind = draw(st.sampled_from(["jones", "depolarizer", "pauli", "diattenuator", "retarder", "polarizer"]))
    if kind == "jones":
        j = np.array([draw(finite) for _ in range(8)])
        return jones_to_mueller((j[:4] + 1j * j[4:]).reshape(2, 2))
    if kind == "depolarizer":
        return rotate_element(depolarizer(draw(unit_interval)), draw(angle))
    if kind == "pauli":  # anisotropic depolarizer inside the physical tetrahedron
        w = np.array([draw(unit_interval) for _ in range(4)])
        assume(w.sum() > 1e-3)
        return np.diag(w / w.sum() @ PAULI_DIAGONALS)
    if kind == "diattenuator":
        return linear_diattenuator(draw(unit_interval), draw(unit_interval), draw(angle))
    if kind == "retarder":
        return retarder(draw(st.floats(-2 * np.pi, 2 * np.pi)), draw(angle))
    return linear_polarizer(draw(angle))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    elements=st.lists(physical_element(), min_size=1, max_size=4),
    s0=st.floats(0.0, 10.0),
    dop=unit_interval,
    aolp=angle,
    ellipticity=st.floats(-np.pi / 4, np.pi / 4),
)
@example(  # found by CI on 2026-11-28: rejected in float32 at rtol 1e-6 (a Jordan block of N)
    elements=[np.array([[1.14995862, 0.14995862, 0, 0], [-0.14995862, 0.85004138, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]])],
    s0=0.0, dop=0.0, aolp=0.0, ellipticity=0.0,
)  # fmt: skip
def test_products_of_physical_elements_are_physical(elements, s0, dop, aolp, ellipticity):
    m = reduce(np.matmul, elements)
    # A product can be (numerically) zero -- crossed polarizers -- which m00 > 0 rejects.
    assume(m[0, 0] > 1e-6)
    assert is_givens_kostinski(m)
    assert is_cloude_physical(m)
    # float32: a defective N (Jordan block, e.g. diattenuator x retarder products) splits its eigenvalues by
    # ~sqrt(eps32 |N|) = 3.5e-4 |N| (the function's docstring), so the tolerance is float32's, not float64's.
    assert is_givens_kostinski(m.astype(np.float32), rtol=1e-3)
    assert is_cloude_physical(m.astype(np.float32))
    s = stokes(s0, dop, aolp, ellipticity)
    assert is_physical_stokes(m @ s)
    # Unchanged by the filter.
    np.testing.assert_allclose(cloude_filter(m), m, atol=1e-10 * max(1.0, np.abs(m).max()))


# --------------------------------------------------------------------------- bad input, stress


@pytest.mark.parametrize(
    "fn",
    [
        coherency_matrix,
        coherency_eigenvalues,
        is_cloude_physical,
        cloude_filter,
        is_givens_kostinski,
        is_mueller_physical,
    ],
)
def test_bad_shape(fn):
    for shape in [(4,), (3, 4), (4, 3), (2, 4, 5)]:
        with pytest.raises(ValueError, match="4, 4"):
            fn(np.zeros(shape))


def test_bad_coherency_shape():
    with pytest.raises(ValueError, match="4, 4"):
        mueller_from_coherency(np.zeros((2, 3, 3)))


@pytest.mark.parametrize(
    "fn", [coherency_eigenvalues, is_cloude_physical, cloude_filter, is_givens_kostinski, is_mueller_physical]
)
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_raises(fn, bad):
    m = np.broadcast_to(np.eye(4), (3, 4, 4)).copy()
    m[1, 2, 3] = bad
    with pytest.raises(ValueError, match="NaN or Inf"):
        fn(m)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_extreme_scales(pure, dtype):
    p = pure[:200] / pure[:200, :1, :1]
    for scale in (1e-30, 1.0, 1e30):
        m = (scale * p).astype(dtype)
        assert is_givens_kostinski(m).all(), scale
        assert is_cloude_physical(m).all(), scale
        f = cloude_filter(m)
        assert np.all(np.isfinite(f))
        np.testing.assert_allclose(f / scale, m / scale, atol=TOL.f32_sum if dtype == np.float32 else 1e-10)
        lam = coherency_eigenvalues(m)
        assert np.all(np.isfinite(lam))


def test_degenerate_matrices():
    zero = np.zeros((4, 4))
    assert not is_givens_kostinski(zero)
    assert not is_cloude_physical(zero)
    assert np.array_equal(cloude_filter(zero), zero)
    # m00 tiny against the other entries: rejected without overflow.
    lopsided = np.eye(4)
    lopsided[0, 0] = 1e-300
    assert not is_givens_kostinski(lopsided)
    assert not is_cloude_physical(lopsided)
    # Rank-1 (ideal polarizer) and nilpotent G M^T G M (polarizer then depolarizer).
    for m in (linear_polarizer(0.7), depolarizer(0.0) @ linear_polarizer(1.0)):
        assert is_givens_kostinski(m) and is_cloude_physical(m)


# --------------------------------------------------------------------------- closed-form Cloude test
# The pivot test (default) against the eigenvalue reference: the coherency eigenvalues by eigh,
# as is_cloude_physical computed them at commit a8e355c. Disagreements are allowed only where the
# smallest eigenvalue lies within BAND * m00 of the tolerance boundary -rtol * m00, where eigh and
# eigvalsh (the fallback) round differently; against eigvalsh there are none
# (docs/measurements/pbrdf.md).

BAND = 1e-12


def eigenvalue_reference(m, rtol):
    """``(verdict, distance)``: the eigh verdict and |lambda_min / m00 + rtol|."""
    m00 = np.asarray(m, dtype=np.float64)[..., 0, 0]
    lam = coherency_eigenvalues(m)[..., -1]
    verdict = (m00 > 0) & (lam >= -rtol * np.abs(m00))
    return verdict, np.abs(lam / np.where(m00 != 0, np.abs(m00), 1.0) + rtol)


def assert_agrees_with_eigenvalues(m, rtol):
    """Fast and eigenvalue verdicts agree outside the band; with ``method="eigh"`` (eigvalsh, the
    fallback of the uncertain matrices) they agree everywhere."""
    fast = is_cloude_physical(m, rtol=rtol)
    ref, dist = eigenvalue_reference(m, rtol)
    off = (fast != ref) & (dist > BAND)
    assert not off.any(), f"{off.sum()} disagreements, lambda_min/m00 + rtol = {dist[off][:5]}"
    assert np.array_equal(fast, is_cloude_physical(m, rtol=rtol, method="eigh"))
    return fast, ref


def boundary_matrices(rng, n, rtol):
    """Coherency matrices U diag(lam) U^H with trace 1 and lam_min = -rtol (1 + s) exactly at, or
    10^-16 .. 1 relatively inside or outside, the tolerance boundary; positive part of rank 1
    (near pure), 2 or 3; magnitudes 1e-30 .. 1e30."""
    q, _ = np.linalg.qr(rng.normal(size=(n, 4, 4)) + 1j * rng.normal(size=(n, 4, 4)))
    s = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-16, 0, n)
    s[rng.random(n) < 0.05] = 0.0
    lam_min = -rtol * (1 + s)
    w = rng.dirichlet(np.ones(3), n) * (np.arange(3) < rng.integers(1, 4, n)[:, None])
    lam = np.concatenate([w / w.sum(1, keepdims=True) * (1 - lam_min)[:, None], lam_min[:, None]], 1)
    h = (q * lam[:, None, :]) @ np.conj(np.swapaxes(q, -1, -2))
    return mueller_from_coherency(h) * 10.0 ** rng.uniform(-30, 30, (n, 1, 1))


def pure_depolarizer_mixtures(rng, n):
    """(1 - p) P + p D (eigenvalues p/4: tiny positive) and (1 + p) P - p D (-p/4: tiny negative)
    for random pure P, the ideal depolarizer D and p = 1e-14 .. 0.1."""
    pure = jones_to_mueller(random_jones(rng, n))
    pure /= pure[:, :1, :1]
    p = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-14, -1, n)
    return (1 - p)[:, None, None] * pure + p[:, None, None] * depolarizer(0.0)


def generic_matrices(rng, n):
    """Identity, ideal depolarizer and pure matrices plus noise, and plain normal matrices."""
    k = n // 4
    return np.concatenate(
        [
            np.eye(4) + rng.normal(scale=0.1, size=(k, 4, 4)),
            depolarizer(0.0) + rng.normal(scale=0.02, size=(k, 4, 4)),
            rng.normal(size=(k, 4, 4)),
            jones_to_mueller(random_jones(rng, n - 3 * k)),
        ]
    )


@pytest.fixture(scope="module")
def seed_matrices():
    from pbrdf.brdf import seeds

    m = np.concatenate([np.asarray(t.M, dtype=np.float64).reshape(-1, 4, 4) for t in seeds.seed_tables()])
    return m[m[:, 0, 0] > 0]


@pytest.mark.slow
@pytest.mark.parametrize("rtol", [1e-6, 1e-5])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_closed_form_agrees_on_seed_tables(seed_matrices, rtol, dtype):
    fast, ref = assert_agrees_with_eigenvalues(seed_matrices.astype(dtype), rtol)
    assert np.array_equal(fast, ref) and fast.all()  # every lit seed matrix is physical
    # Non-physical relatives: s3 flipped at the output, and noise of 3 % of m00.
    rng = np.random.default_rng(11)
    m00 = seed_matrices[:, :1, :1]
    for m in (
        np.diag([1.0, 1, 1, -1]) @ seed_matrices,
        seed_matrices + rng.normal(scale=0.03, size=seed_matrices.shape) * m00,
    ):
        fast, ref = assert_agrees_with_eigenvalues(m.astype(dtype), rtol)
        assert np.array_equal(fast, ref) and 0.02 < fast.mean() < 0.98


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_closed_form_agrees_on_a_million_random_matrices(dtype):
    rng = np.random.default_rng(20261124)
    for rtol in (1e-6, 1e-5):
        sets = {
            "boundary": boundary_matrices(rng, 200_000, rtol),
            "mixtures": pure_depolarizer_mixtures(rng, 150_000),
            "generic": generic_matrices(rng, 150_000),
        }
        for name, m in sets.items():
            m = m.astype(dtype)
            fast, ref = assert_agrees_with_eigenvalues(m, rtol)
            assert 0.05 < ref.mean() < 0.95, name  # both verdicts are exercised
            # Only matrices near the boundary need the eigenvalues: nearly all within 1e-10 m00 of
            # it (a few near-pure ones with pivots of the size of rtol further out).
            physical, not_physical = validity._cloude_pivots(m.astype(np.float64), rtol)
            unsure = ~(physical | not_physical)
            _, dist = eigenvalue_reference(m, rtol)
            assert np.count_nonzero(unsure & (dist > 1e-10)) <= 1e-4 * len(m), name
            if name != "boundary":
                assert not unsure.any(), name
            elif dtype == np.float64:
                assert unsure.any()  # the fallback is exercised


def test_uncertain_matrices_fall_back_to_the_eigenvalues(monkeypatch):
    rng = np.random.default_rng(7)
    m = boundary_matrices(rng, 2000, 1e-6)
    physical, not_physical = validity._cloude_pivots(m / m[:, :1, :1], 1e-6)
    unsure = ~(physical | not_physical)
    assert 0 < unsure.sum() < len(m)
    ref = is_cloude_physical(m, method="eigh")  # eigvalsh: the fallback's own verdicts
    assert np.array_equal(is_cloude_physical(m), ref)
    # With every pivot "within rounding" everything goes to the eigenvalues: still the same verdicts.
    monkeypatch.setattr(validity, "_PIVOT_TOL", np.inf)
    assert np.array_equal(is_cloude_physical(m), ref)


def test_closed_form_pivots_are_the_ldl_pivots(rng):
    # The four pivots are ratios of leading principal minors of 4 (H + rtol m00 I).
    m = generic_matrices(rng, 400)
    m = m[m[:, 0, 0] > 0]
    rtol = 1e-3
    h = 4 * (coherency_matrix(m) + rtol * m[:, :1, :1] * np.eye(4))
    minors = np.stack([np.linalg.det(h[:, :k, :k]).real for k in range(1, 5)], axis=1)
    expected = minors / np.concatenate([np.ones((len(m), 1)), minors[:, :-1]], axis=1)
    physical, not_physical = validity._cloude_pivots(m, rtol)
    clear = np.all(np.abs(expected) > 1e-6, axis=1)
    sylvester = np.all(expected > 0, axis=1)
    assert np.array_equal(physical[clear], sylvester[clear])
    assert np.array_equal(not_physical[clear], ~sylvester[clear])


def test_closed_form_edge_cases():
    zero = np.zeros((4, 4))
    assert not is_cloude_physical(zero) and not is_cloude_physical(zero, method="eigh")
    assert not is_cloude_physical(-depolarizer(0.0))  # m00 < 0
    for fn in (is_cloude_physical, is_mueller_physical):
        for bad in (np.nan, np.inf, -np.inf):
            m = np.eye(4)
            m[3, 1] = bad
            with pytest.raises(ValueError, match="NaN or Inf"):
                fn(m)
            with pytest.raises(ValueError, match="NaN or Inf"):
                fn(m.astype(np.float32))
    with pytest.raises(ValueError, match="rtol"):
        is_cloude_physical(np.eye(4), rtol=-1e-6)
    with pytest.raises(ValueError, match="method"):
        is_cloude_physical(np.eye(4), method="cholesky")


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_closed_form_is_scale_invariant(dtype):
    # Verdicts at 1e-300 .. 1e300 (float32: 1e-30 .. 1e30) equal those at scale 1, where the
    # products of entries would underflow or overflow without the rescaling and the fallback.
    rng = np.random.default_rng(3)
    m = np.concatenate([generic_matrices(rng, 2000), pure_depolarizer_mixtures(rng, 2000)])
    base, _ = eigenvalue_reference(m, 1e-6)
    assert 0.2 < base.mean() < 0.8
    scales = (1e-30, 1e30) if dtype == np.float32 else (1e-300, 1e-160, 1e-30, 1e30, 1e160, 1e300)
    for scale in scales:
        scaled = (m * scale).astype(dtype)
        ok = is_cloude_physical(scaled)
        assert np.array_equal(ok, base), (scale, np.count_nonzero(ok != base))
    lopsided = np.eye(4)
    lopsided[0, 0] = 1e-300
    assert not is_cloude_physical(lopsided) and not is_cloude_physical(np.diag([1e-300, 1, 1, 1]))


def test_cloude_implies_givens_kostinski(seed_matrices, rng):
    # Exactly, a convex sum of Jones systems maps the Stokes cone into itself. Measured at the
    # same rtol: no exception on generic random matrices and the seed tables.
    rtol = 1e-6
    m = np.concatenate([generic_matrices(rng, 40_000), seed_matrices[::4]])
    cl = is_cloude_physical(m, rtol=rtol)
    assert 0.05 < cl.mean() < 0.95
    assert is_givens_kostinski(m[cl], rtol=rtol).all()
    # With the tolerance, H + rtol m00 I >= 0 makes M + 4 rtol m00 diag(1, 0, 0, 0) physical:
    # near-pure matrices with small negative eigenvalues pass Cloude at rtol and GK at 4 rtol.
    mix = pure_depolarizer_mixtures(rng, 20_000)
    cl = is_cloude_physical(mix, rtol=rtol)
    assert is_givens_kostinski(mix[cl], rtol=4 * rtol).all()
    # ... but not always GK at rtol: a polarizer with m01 = m10 = 1 + 1.5 rtol has
    # lambda_min(H) = -0.75 rtol and |m01| > m00 (1 + rtol).
    eps = 1.5 * rtol
    polarizer = linear_polarizer(0.0) * 2
    polarizer[0, 1] = polarizer[1, 0] = 1 + eps
    assert coherency_eigenvalues(polarizer)[-1] == pytest.approx(-eps / 2)
    assert is_cloude_physical(polarizer, rtol=rtol) and is_mueller_physical(polarizer, rtol=rtol)
    assert not is_givens_kostinski(polarizer, rtol=rtol) and is_givens_kostinski(polarizer, rtol=4 * rtol)
