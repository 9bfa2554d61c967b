"""Tests of the decoder (pbrdf.sensor.decode) on captures of the camera model (pbrdf.sensor.camera).

Expected values come from physics and closed forms, never from earlier runs of the code:

- the IMX250MYR layout is written out literally in tests/helpers.py (checked against polanalyser 3.0.0) and compared
  with an independent implementation where it is installed;
- pixel intensities follow the closed forms written out in tests/pbrdf/sensor/test_camera.py: Malus' law behind
  a quarter-wave plate whose fast axis is horizontal, and micro-polarizers as diattenuators (extinction ratio ER);
- the HDR merge is the shot-noise maximum-likelihood estimate ``sum z / sum t`` over the exposures in which all
  four analyzer pixels of a 2x2 block are unsaturated;
- the raw noise is Poisson-Gaussian, ``Var(DN) = K (mean - black) + K^2 sigma_r^2 + 1/12`` (Foi et al., IEEE TIP
  2008; EMVA 1288), and the decoded variance follows from it by linear propagation.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pbrdf.polar.stokes import stokes
from pbrdf.sensor import camera, decode
from pbrdf.sensor.camera import CameraModel, SensorParams
from tests.helpers import IDEAL_OPTICS, IMX250MYR_LAYOUT, elliptical_states, parse_layout_entry

# A sensor whose raw numbers are the analyzer intensities (DN == intensity for exposure 1 s, no black level,
# 16-bit white level far above the values used): the noise-free float path through decode.
UNIT_SENSOR = SensorParams(gain=1.0, electrons_per_unit=1.0, black_level=0.0, bits=16)


def _unit_model(**changes) -> CameraModel:
    return CameraModel(exposures=(1.0,), sensor=UNIT_SENSOR, **changes)


def _float_raws(stokes_img: np.ndarray, model: CameraModel) -> np.ndarray:
    """One float 'raw' frame equal to the analyzer intensities (valid for models from _unit_model)."""
    return camera.mosaic(stokes_img, model)[None]


def _constant_image(svec: np.ndarray, h: int = 8, w: int = 8) -> np.ndarray:
    """(h, w, 3, 4) image of per-colour Stokes vectors svec (3, 4)."""
    return np.broadcast_to(np.asarray(svec, dtype=np.float64), (h, w, 3, 4)).copy()


def _measured(svec: np.ndarray) -> np.ndarray:
    """The components the camera measures, (s0, s1, s3), from (..., 4) Stokes."""
    return np.asarray(svec)[..., [0, 1, 3]]


def _closed_form_decoder(er: float, q: float = 1.0) -> np.ndarray:
    """(3, 4) pseudo-inverse of the analyzer rows a [1,1,1,1], b [1,0,-1,0], b [0,1,0,-1] (orthogonal columns):
    s0 = sum(I) / (4a), s1 = (I0 - I90) / (2b), s3 = (I45 - I135) / (2b) for an ideal QWP."""
    a, b = 0.5 * q * (1 + 1 / er), 0.5 * q * (1 - 1 / er)
    return np.array([[1, 1, 1, 1], [2, 0, -2, 0], [0, 2, 0, -2]]) / np.array([[4 * a], [4 * b], [4 * b]])


# ----------------------------------------------------------------------------------------------------------
# 1. Independent reference: polanalyser 3.0.0 (bench extra)
# ----------------------------------------------------------------------------------------------------------


def _raw_from_layout(value, h: int, w: int) -> np.ndarray:
    """uint16 raw whose pixel (y, x) holds value(colour, angle_index, y, x) for its literal-table entry."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    raw = np.zeros((h, w))
    for i in range(4):
        for j in range(4):
            c, theta = parse_layout_entry(IMX250MYR_LAYOUT[i][j])
            raw[i::4, j::4] = value(c, camera.ANGLES_DEG.index(theta), y[i::4, j::4], x[i::4, j::4])
    return np.rint(raw).astype(np.uint16)


def _expected_planes(value, h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([np.stack([value(c, a, y, x) for a in range(4)], -1) for c in range(3)], -2)


def _polanalyser_rgb(raw: np.ndarray) -> np.ndarray:
    pa = pytest.importorskip("polanalyser", reason="polanalyser (bench extra) not installed")
    pytest.importorskip("cv2", reason="opencv (bench extra) not installed")
    planes = pa.demosaicing(raw, pa.COLOR_PolarRGB)  # [I0, I45, I90, I135], each (H, W, 3) in BGR order
    return np.stack(planes, axis=-1)[:, :, ::-1, :].astype(np.float64)  # (H, W, RGB, angle)


def test_demosaic_matches_polanalyser_on_constant_and_affine_fields():
    h, w, m = 64, 80, 8  # m: border excluded (the two implementations extrapolate differently)

    def const(c, a, y, x):
        return 4000.0 + 3000.0 * c + 700.0 * a + 0 * y

    def affine(c, a, y, x):
        return 4000.0 + 3000.0 * c + 700.0 * a + (13.3 + c) * y + (7.1 + 3 * a) * x

    inner = (slice(m, -m), slice(m, -m))
    for value, atol in ((const, 0.0), (affine, 1.0)):  # polanalyser rounds to integers: 1 DN on affine fields
        raw = _raw_from_layout(value, h, w)
        ours = decode.demosaic(raw, grid="full")
        ref = _polanalyser_rgb(raw)
        np.testing.assert_allclose(ours[inner], ref[inner], rtol=1e-3 if atol == 0 else 0, atol=atol)
        # Both are bilinear, hence exact for affine lattices; the uint16 input is exact up to 0.5 DN rounding.
        np.testing.assert_allclose(ours[inner], _expected_planes(value, h, w)[inner], rtol=0, atol=0.5 + 1e-3)


def test_demosaic_matches_polanalyser_loosely_on_smooth_field():
    h, w, m = 64, 80, 8
    amp = 600.0

    def smooth(c, a, y, x):
        return 4000.0 + 3000.0 * c + 700.0 * a + amp * np.sin(2 * np.pi * y / 48 + c) * np.cos(2 * np.pi * x / 64 + a)

    raw = _raw_from_layout(smooth, h, w)
    ours = decode.demosaic(raw, grid="full")
    ref = _polanalyser_rgb(raw)
    inner = (slice(m, -m), slice(m, -m))
    # Different interpolation paths (polanalyser: colour on each 2x2 sub-lattice, then angle): both have an
    # O(h^2 f'') error, measured 31 DN against the true field and 16 DN between the two (amplitude 600).
    np.testing.assert_allclose(ours[inner], ref[inner], rtol=0, atol=0.05 * amp)
    np.testing.assert_allclose(ours[inner], _expected_planes(smooth, h, w)[inner], rtol=0, atol=0.1 * amp)


# ----------------------------------------------------------------------------------------------------------
# 2. Quarter-wave plate: the camera's "s2" channel measures the incoming s3
# ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("svec", "expected"),
    [
        ([1.0, 0.0, 0.0, 1.0], [1.0, 0.0, 1.0]),  # right circular -> +45 linear behind the QWP -> s3 = +s0
        ([1.0, 0.0, 0.0, -1.0], [1.0, 0.0, -1.0]),  # left circular -> s3 = -s0
        ([1.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),  # +45 linear: s2 is not measured, decoded s3 = 0
        ([1.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0]),  # -45 linear: likewise
        ([1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 0.0]),  # horizontal linear passes the QWP unchanged
    ],
)
def test_qwp_circular_and_diagonal_states(svec, expected):
    gains = np.array([0.7, 1.0, 0.4])[:, None]  # per-colour intensities
    model = _unit_model(**IDEAL_OPTICS)
    dec = decode.decode(_float_raws(_constant_image(gains * np.array(svec)), model), model)
    np.testing.assert_allclose(dec.stokes, np.broadcast_to(gains * np.array(expected), dec.stokes.shape), atol=1e-6)
    assert dec.mask.all()


def test_qwp_retardance_error_leaks_s2_into_s3():
    # Behind a retarder pi/2 + e the analyzer's "s2" is s2 cos(d) + s3 sin(d); the decoder divides by sin(d) and
    # cannot see s2 (fit assumes s2 = 0), so s3_hat = s3 + s2 cot(d).
    e = np.array([0.05, -0.03, 0.1])
    model = _unit_model(extinction_ratio=np.inf, qwp_retardance=np.pi / 2 + e)
    s2 = np.array([1.0, 0.8, 0.5])
    plus45 = s2[:, None] * np.array([1.0, 0.0, 1.0, 0.0])
    dec = decode.decode(_float_raws(_constant_image(plus45), model), model)
    expected_s3 = s2 / np.tan(np.pi / 2 + e)  # = -s2 tan(e): about -0.05 s2 for e = 0.05
    np.testing.assert_allclose(dec.stokes[..., 2], np.broadcast_to(expected_s3, dec.stokes.shape[:-1]), atol=1e-6)
    np.testing.assert_allclose(dec.stokes[..., 0], np.broadcast_to(s2, dec.stokes.shape[:-1]), rtol=1e-6)


# ----------------------------------------------------------------------------------------------------------
# 3. Display light and the decomposition convention
# ----------------------------------------------------------------------------------------------------------

MAP = {name: k for k, name in enumerate(decode.NINE_MAP_NAMES)}


def _maps_by_kind(maps: np.ndarray) -> dict[str, np.ndarray]:
    """(..., 9) -> {'unpol': (..., 3), 'LP': (..., 3), 'CP': (..., 3)} in R, G, B order."""
    return {k: maps[..., [MAP[f"{c}_{k}"] for c in "RGB"]] for k in ("unpol", "LP", "CP")}


def test_nine_map_names_order():
    assert decode.NINE_MAP_NAMES == tuple(f"{c}_{k}" for k in ("unpol", "LP", "CP") for c in "RGB")


@pytest.mark.parametrize("er", [np.inf, 100.0])
def test_display_light_is_all_lp_and_unpolarized_is_all_unpol(er):
    s0 = np.array([0.6, 1.0, 0.3])
    model = _unit_model(extinction_ratio=er, qwp_retardance=np.pi / 2)
    display = s0[:, None] * np.array([1.0, -1.0, 0.0, 0.0])  # vertical linear: the LCD's light
    unpolarized = s0[:, None] * np.array([1.0, 0.0, 0.0, 0.0])
    for svec, lp, unpol in ((display, s0, 0 * s0), (unpolarized, 0 * s0, s0)):
        dec = decode.decode(_float_raws(_constant_image(svec), model), model)
        k = _maps_by_kind(dec.maps)
        np.testing.assert_allclose(k["LP"], np.broadcast_to(lp, k["LP"].shape), atol=1e-6)
        np.testing.assert_allclose(k["unpol"], np.broadcast_to(unpol, k["unpol"].shape), atol=1e-6)
        np.testing.assert_allclose(k["CP"], 0.0, atol=1e-6)


def test_convention_unpol_is_s0_plus_s1():
    # Convention (pbrdf.sensor.decode docstring): LP = -S1, unpol = S0 - LP = S0 + S1. The paper prints
    # unpol = S0 - S1, which would give 2*S0 for pure display light (S1 = -S0) instead of 0; we use S0 + S1.
    s = np.array([[2.0, -2.0, 0.0], [1.0, -0.25, 0.1], [3.0, 0.5, -1.0]])[None]  # (1, colour, (s0, s1, s3))
    k = _maps_by_kind(decode.nine_maps(s, eps=0.0))
    np.testing.assert_allclose(k["LP"][0], -s[0, :, 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(k["unpol"][0], s[0, :, 0] + s[0, :, 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(k["unpol"][0] + k["LP"][0], s[0, :, 0], rtol=0, atol=1e-15)  # the split sums to s0
    np.testing.assert_allclose(k["CP"][0], s[0, :, 2] / s[0, :, 0], rtol=1e-15)


@pytest.mark.xfail(strict=True, reason="the paper's printed unpol = S0 - S1 gives 2*S0 for display light, not 0")
def test_paper_printed_unpol_gives_zero_for_display_light():
    model = _unit_model(**IDEAL_OPTICS)
    dec = decode.decode(_float_raws(_constant_image(np.array([1.0, -1.0, 0.0, 0.0])[None].repeat(3, 0)), model), model)
    s0, s1 = dec.stokes[..., 0], dec.stokes[..., 1]
    np.testing.assert_allclose(s0 - s1, 0.0, atol=1e-3)  # the paper's form: fails (it is 2 s0)


# ----------------------------------------------------------------------------------------------------------
# 4. Noise-free round trips through the float path
# ----------------------------------------------------------------------------------------------------------

_per_colour = st.tuples
_er = st.one_of(st.floats(20.0, 1e4), st.just(np.inf))


@settings(max_examples=50, deadline=None)
@given(
    s0=_per_colour(*[st.floats(0.2, 2.0)] * 3),
    dop=_per_colour(*[st.floats(0.0, 1.0)] * 3),
    aolp=_per_colour(*[st.floats(0.0, np.pi)] * 3),
    chi=_per_colour(*[st.floats(-np.pi / 4, np.pi / 4)] * 3),
    er=_per_colour(_er, _er, _er),
    grid=st.sampled_from(["half", "full"]),
)
def test_round_trip_constant_field(s0, dop, aolp, chi, er, grid):
    svec = stokes(np.array(s0), np.array(dop), np.array(aolp), np.array(chi))  # (3, 4), physical by construction
    model = _unit_model(extinction_ratio=er, qwp_retardance=np.pi / 2)
    dec = decode.decode(_float_raws(_constant_image(svec), model), model, grid=grid)
    expected = decode.nine_maps(_measured(svec)[None].astype(np.float64))[0]
    assert dec.mask.all()
    # float32 decode of values <= 2: measured worst error about 4e-7.
    np.testing.assert_allclose(dec.maps, np.broadcast_to(expected, dec.maps.shape), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(dec.stokes, np.broadcast_to(_measured(svec), dec.stokes.shape), rtol=1e-5, atol=1e-6)


def _affine_scene(h: int, w: int) -> np.ndarray:
    """Per-colour Stokes fields affine in (y, x), physical everywhere on the image."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    base = np.array([[1.0, 0.3, -0.2, 0.4], [1.5, -0.6, 0.3, -0.5], [0.8, 0.1, 0.2, 0.3]])
    gy = np.array([[4e-3, -2e-3, 1e-3, 1e-3], [-3e-3, 1e-3, 0.0, 2e-3], [5e-3, 1e-3, -1e-3, -1e-3]])
    gx = np.array([[-2e-3, 1e-3, 0.0, -1e-3], [3e-3, 2e-3, 1e-3, -1e-3], [2e-3, -1e-3, 1e-3, 1e-3]])
    return base + y[..., None, None] * gy + x[..., None, None] * gx


def _block_mean(a: np.ndarray) -> np.ndarray:
    """Mean of each 2x2 block over the two leading axes."""
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


@pytest.mark.parametrize("grid", ["half", "full"])
@pytest.mark.parametrize("er", [np.inf, 60.0])
def test_round_trip_affine_field_interior(grid, er):
    # Bilinear interpolation of every (colour, angle) lattice reproduces affine fields exactly wherever the
    # target lies between samples: 4 raw pixels from the border.
    h, w, m = 40, 48, 4
    img = _affine_scene(h, w)
    model = _unit_model(extinction_ratio=er, qwp_retardance=np.pi / 2)
    dec = decode.decode(_float_raws(img, model), model, grid=grid)
    truth = _measured(img) if grid == "full" else _block_mean(_measured(img))  # half: block centres 2k + 0.5
    k = m if grid == "full" else m // 2
    inner = (slice(k, -k), slice(k, -k))
    np.testing.assert_allclose(dec.stokes[inner], truth[inner], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(dec.maps[inner], decode.nine_maps(truth)[inner], rtol=1e-5, atol=1e-5)


# ----------------------------------------------------------------------------------------------------------
# 5. Real uint16 quantisation, no noise
# ----------------------------------------------------------------------------------------------------------


def test_quantisation_error_within_bound():
    model = CameraModel()  # ER 100, QWP pi/2, 12 bit, bracket 10/20/100/200 ms
    sensor = model.sensor
    g = sensor.dn_per_unit_second
    t = np.asarray(model.exposures)
    threshold = sensor.saturation * sensor.white_level - sensor.black_level  # black-subtracted DN
    h, w = 48, 64
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    s0 = np.array([1.0, 0.25, 0.05])  # R valid at 10 ms only, G at 10 and 20 ms, B at all four
    shape = stokes(s0, [0.8, 0.5, 0.9], [0.3, 1.2, 2.5], [0.2, -0.3, 0.5])
    img = (1.0 + 1.5e-3 * y - 1.0e-3 * x)[..., None, None] * shape  # affine: demosaicing adds no error
    raws = camera.simulate_capture(img, model, noise=False)
    dec = decode.decode(raws, model, grid="half")

    a, b = 0.5 * (1 + 1 / 100.0), 0.5 * (1 - 1 / 100.0)
    dmat = _closed_form_decoder(100.0)
    delta = np.empty(3)
    for c in range(3):
        # Largest and smallest block maximum of the analyzer intensities (Malus with the QWP, closed form).
        ang = np.deg2rad(np.array(camera.ANGLES_DEG))
        inten = a * img[..., c, 0, None] + b * (
            img[..., c, 1, None] * np.cos(2 * ang) + img[..., c, 3, None] * np.sin(2 * ang)
        )
        hi, lo = inten.max(-1).max() * g * t, inten.max(-1).min() * g * t
        used = hi < threshold
        assert np.all(used | (lo > 1.02 * threshold)), "construction: every block in the same saturation regime"
        assert np.all(~used | (hi < 0.98 * threshold))
        # sum_j z_j / (g sum_j t_j) with |rounding_j| <= 0.5 DN: <= 0.5 n / (g sum t) <= 0.5 n / (g t_longest).
        delta[c] = 0.5 * used.sum() / (g * t[used].sum())
    assert np.all(delta <= 0.5 * np.array([1, 2, 4]) / (g * np.array([0.01, 0.02, 0.2])))
    # Demosaicing is a convex combination, so the bound carries over; then the (3, 4) decoder's absolute rows.
    bound = np.abs(dmat).sum(-1)[None, :] * delta[:, None]  # (colour, (s0, s1, s3))
    truth = _block_mean(_measured(img))
    inner = (slice(2, -2), slice(2, -2))
    err = np.abs(dec.stokes[inner] - truth[inner]).max(axis=(0, 1))
    assert np.all(err <= bound + 1e-6), (err, bound)  # 1e-6: float32 arithmetic on values ~1
    assert dec.mask.all()
    unpol_bound = np.abs(dmat[0] + dmat[1]).sum() * delta
    unpol_err = np.abs(_maps_by_kind(dec.maps)["unpol"] - _maps_by_kind(decode.nine_maps(truth))["unpol"])
    assert np.all(unpol_err[inner].max(axis=(0, 1)) <= unpol_bound + 1e-6)


# ----------------------------------------------------------------------------------------------------------
# 6. Noise propagation through decode
# ----------------------------------------------------------------------------------------------------------


def test_decoded_variance_matches_linear_propagation():
    # decode is linear in the raws for a fixed validity pattern (all exposures unsaturated here), so
    # Var(out_p) = sum_k w_pk^2 Var(raw_k), Var(raw_k) Poisson-Gaussian. Weights from unit impulses (linearity),
    # using the period-4 shift invariance: output pixels of one phase class (half grid: period 2) share them.
    rng = np.random.default_rng(1234)
    model = CameraModel()
    sensor = model.sensor
    svec = stokes(np.array([0.04, 0.06, 0.02]), 0.5, np.array([0.3, 1.0, 2.0]), np.array([0.2, -0.3, 0.1]))
    size = 512
    raws = camera.simulate_capture(_constant_image(svec, size, size), model, rng=rng)
    assert raws.max() < sensor.saturation * sensor.white_level  # all four exposures used everywhere
    emp_stokes = decode.decode(raws, model).stokes[4:-4, 4:-4]  # (H', W', colour, (s0, s1, s3))

    tile = camera.mosaic(_constant_image(svec, 4, 4), model)  # analyzer intensity of each of the 16 phases
    k = sensor.gain
    var_raw = [k * sensor.dn_per_unit_second * t * tile + k**2 * sensor.read_noise**2 + 1 / 12 for t in model.exposures]
    n = 32
    base = np.full((len(model.exposures), n, n), sensor.black_level)
    zero = decode.decode(base, model).stokes.astype(np.float64)
    pred = np.zeros((2, 2, 3, 3))
    for j in range(len(model.exposures)):
        for i in range(4):
            for q in range(4):
                r = base.copy()
                r[j, 16 + i, 16 + q] += 1.0
                wgt = decode.decode(r, model).stokes - zero
                for pr in range(2):
                    for pc in range(2):
                        pred[pr, pc] += var_raw[j][i, q] * np.sum(wgt[pr::2, pc::2] ** 2, axis=(0, 1))
    for pr in range(2):
        for pc in range(2):
            emp = emp_stokes[pr::2, pc::2].reshape(-1, 3, 3).var(axis=0)
            np.testing.assert_allclose(emp, pred[pr, pc], rtol=0.10)  # measured within 3 %
    # Unbiased: the mean over the image is the true Stokes vector (tolerance 3 x a conservative standard error).
    se = np.sqrt(pred.mean(axis=(0, 1)) * 16 / emp_stokes[..., 0, 0].size)
    assert np.all(np.abs(emp_stokes.mean(axis=(0, 1)) - _measured(svec)) < 3 * se)


# ----------------------------------------------------------------------------------------------------------
# 7. Orientation and ROI offset
# ----------------------------------------------------------------------------------------------------------


def _calibration_scene(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    s0 = 0.5 + 0.2 * np.sin(y / 5.0) + 0.15 * np.cos(x / 4.0)
    return (s0[..., None] * np.array([1.0, 0.7, 0.4]))[..., None] * elliptical_states()


def test_estimate_pattern_offset_recovers_every_offset():
    rng = np.random.default_rng(1234)
    img = _calibration_scene(32, 32)
    base = CameraModel()
    for r in range(4):
        for c in range(4):
            raws = camera.simulate_capture(img, base.replace(pattern_offset=(r, c)), rng=rng)
            assert decode.estimate_pattern_offset(raws[0], img, base) == (r, c)
    raws = camera.simulate_capture(img, base.replace(pattern_offset=(0, 1)), rng=rng)
    assert decode.estimate_pattern_offset(raws[0], img, base.replace(pattern_offset=(2, 2))) == (0, 1)  # ignored


def test_wrong_pattern_offset_gives_large_error():
    h, w = 48, 48
    img = 0.3 * _affine_scene(h, w)  # affine: the correct offset decodes exactly up to quantisation
    truth = _block_mean(_measured(img))[3:-3, 3:-3]
    model = CameraModel(pattern_offset=(0, 1))
    raws = camera.simulate_capture(img, model, noise=False)

    def err(offset):
        st_ = decode.decode(raws, model.replace(pattern_offset=offset)).stokes[3:-3, 3:-3]
        return np.sqrt(np.mean((st_ - truth) ** 2))

    good = err((0, 1))
    assert good < 1e-3
    for wrong in [(0, 0), (1, 1), (0, 2), (2, 3)]:
        assert err(wrong) > 10 * good, wrong


@pytest.mark.parametrize("grid", ["half", "full"])
def test_row_zero_stays_top_and_col_zero_stays_left(grid):
    h, w = 48, 48
    model = _unit_model(**IDEAL_OPTICS)
    f = 1 if grid == "full" else 2  # raw pixels per output pixel
    for axis in (0, 1):
        lum = np.full((h, w), 0.1)
        if axis == 0:
            lum[:8] = 1.0  # bright top rows
        else:
            lum[:, :8] = 1.0  # bright left columns
        img = lum[..., None, None] * elliptical_states()
        s0 = decode.decode(_float_raws(img, model), model, grid=grid).stokes[..., 0]
        s0 = s0 if axis == 0 else np.swapaxes(s0, 0, 1)  # the tested axis first
        np.testing.assert_allclose(s0[: 4 // f], 1.0, rtol=1e-5)  # raw 0..3: bright in every lattice
        np.testing.assert_allclose(s0[12 // f :], 0.1, rtol=1e-5)  # raw >= 12: dark in every lattice


# ----------------------------------------------------------------------------------------------------------
# 8. HDR merge
# ----------------------------------------------------------------------------------------------------------

BRACKET = (0.01, 0.02, 0.1, 0.2)


def _linear_raws(rate: np.ndarray, sensor: SensorParams) -> np.ndarray:
    """Noise-free float raws b + rate * t (rate in DN/s, per pixel), clipped at the white level."""
    t = np.asarray(BRACKET)[:, None, None]
    return np.minimum(sensor.black_level + rate[None] * t, sensor.white_level)


def test_hdr_saturated_long_exposures_use_short_ones():
    sensor = SensorParams()
    g = sensor.dn_per_unit_second
    rate = np.full((8, 8), 1.0e4)
    rate[2:4, 4:6] = 1.0e5  # this block reaches 10000 and 20000 DN at 100 and 200 ms: saturated, clipped
    raws = np.rint(_linear_raws(rate, sensor)).astype(np.uint16)
    merged, valid = decode.hdr_merge(raws, BRACKET, sensor)
    z = raws.astype(np.float64) - sensor.black_level
    ml_short = (z[0] + z[1]) / (g * (BRACKET[0] + BRACKET[1]))  # ML estimate over the unsaturated exposures
    ml_all = z.sum(0) / (g * sum(BRACKET))
    np.testing.assert_allclose(merged[2:4, 4:6], ml_short[2:4, 4:6], rtol=1e-6)
    np.testing.assert_allclose(merged[2:4, 4:6], 1.0e5 / g, rtol=1e-4)  # and it is right (rounding only)
    np.testing.assert_allclose(merged[:2], ml_all[:2], rtol=1e-6)
    assert valid.all()


@pytest.mark.parametrize("offset", [(0, 0), (1, 0), (0, 1), (1, 1)])
def test_hdr_one_saturated_analyzer_drops_the_exposure_for_its_block(offset):
    sensor = SensorParams()
    g = sensor.dn_per_unit_second
    rate = np.full((8, 8), 1.0e4)
    raws = _linear_raws(rate, sensor)
    raws[3] += 100.0  # 200 ms frame inconsistent by +100 DN: reveals whether it was used
    py, px = 3, 5
    raws[3, py, px] = sensor.white_level  # one analyzer pixel saturates at 200 ms only
    by, bx = py - (py + offset[0]) % 2, px - (px + offset[1]) % 2  # top-left of its 2x2 block for this offset
    merged, valid = decode.hdr_merge(raws, BRACKET, sensor, pattern_offset=offset)
    in_block = np.zeros((8, 8), dtype=bool)
    in_block[by : by + 2, bx : bx + 2] = True
    # All four pixels of the block: 200 ms dropped -> exactly rate / g from the three consistent exposures.
    np.testing.assert_allclose(merged[in_block], 1.0e4 / g, rtol=1e-6)
    # Every other pixel keeps all four exposures: (sum rate t + 100) / (g sum t).
    np.testing.assert_allclose(merged[~in_block], (1.0e4 * sum(BRACKET) + 100.0) / (g * sum(BRACKET)), rtol=1e-6)
    assert valid.all()


def test_hdr_block_merge_is_unbiased_where_per_pixel_merge_is_not():
    # State with I45 > I0 > I90: scaled so that I0 sits exactly at the saturation threshold at 200 ms while I45
    # is far beyond it (deterministically saturated). A per-pixel merge keeps I0's 200 ms frame only when its
    # noise is negative (truncation): biased low. Ours drops 200 ms for the whole block because I45 saturates,
    # independently of I0's noise: unbiased.
    rng = np.random.default_rng(1234)
    model = CameraModel()
    sensor = model.sensor
    g = sensor.dn_per_unit_second
    t = np.asarray(model.exposures)
    threshold = sensor.saturation * sensor.white_level
    a, b = 0.5 * (1 + 1 / 100.0), 0.5 * (1 - 1 / 100.0)
    shape = np.array([1.0, 0.3, 0.0, 0.9])
    i0, i90 = a + b * shape[1], a - b * shape[1]
    scale = (threshold - sensor.black_level) / (g * t[-1] * i0)
    svec = scale * shape
    raws = camera.simulate_capture(_constant_image(np.tile(svec, (3, 1)), 256, 256), model, rng=rng)
    merged, _ = decode.hdr_merge(raws, model.exposures, sensor)
    keep = raws < threshold
    naive = ((raws - sensor.black_level) * keep).sum(0) / (g * (keep * t[:, None, None]).sum(0))

    def rel_error(mosaic_img, k):
        s = decode.stokes_from_intensities(decode.demosaic(mosaic_img), model)[4:-4, 4:-4]
        return s[..., k].mean() / svec[(0, 1, 3)[k]] - 1.0  # relative error, averaged over colours and pixels

    # Predicted naive bias: the 200 ms frame is kept half the time, then low by sigma sqrt(2 / pi) DN.
    z0 = threshold - sensor.black_level
    sigma = np.sqrt(sensor.gain * z0 + sensor.gain**2 * sensor.read_noise**2 + 1 / 12)
    bias_i0 = 0.5 * (-sigma * np.sqrt(2 / np.pi)) / (g * t.sum()) / (z0 / (g * t[-1]))  # relative, about -0.24 %
    bias_s1 = bias_i0 * i0 / (i0 - i90)  # about -0.5 %
    assert rel_error(naive, 1) == pytest.approx(bias_s1, abs=0.0015)  # the construction biases a per-pixel merge
    assert abs(rel_error(merged, 1)) < 0.0015  # measured -4e-4; standard error about 2e-4
    # s0 and s3 too: a merge that kept the clipped 200 ms I45 frame would bias s3 by about -20 %.
    assert abs(rel_error(merged, 0)) < 0.0015 and abs(rel_error(merged, 2)) < 0.0015


def test_all_saturated_pixels_are_masked_with_finite_zero_maps():
    model = CameraModel()
    h, w = 64, 64
    lum = np.full((h, w), 0.05)
    lum[24:40, 24:40] = 20.0  # saturated even at 10 ms
    img = lum[..., None, None] * elliptical_states()
    raws = camera.simulate_capture(img, model, noise=False)
    _, valid = decode.hdr_merge(raws, model.exposures, model.sensor)
    assert not valid[24:40, 24:40].any() and valid[:16].all()
    for grid, f in (("half", 2), ("full", 1)):
        dec = decode.decode(raws, model, grid=grid)
        assert np.isfinite(dec.maps).all() and np.isfinite(dec.stokes).all()
        bad = slice(24 // f, 40 // f)
        assert not dec.mask[bad, bad].any()
        assert np.all(dec.maps[~dec.mask] == 0.0)
        assert dec.mask[: 12 // f].all() and dec.mask[:, 52 // f :].all()  # far from the patch: measured


def _blocks_to_pixels(blocks: np.ndarray) -> np.ndarray:
    """Per-2x2-block values (H/2, W/2) repeated to the pixels (H, W)."""
    return np.repeat(np.repeat(blocks, 2, axis=0), 2, axis=1)


@pytest.mark.parametrize("grid", ["half", "full"])
@pytest.mark.parametrize("offset", [(0, 0), (1, 0), (0, 1), (3, 3)])
def test_saturated_blocks_decode_as_if_their_saturated_exposure_were_dropped(grid, offset):
    # The block rule, physically: a 2x2 block saturated in the longest exposure is measured by the three shorter
    # ones only, every other block by all four. So decoding the bracket equals the plain ML merge sum z / sum t
    # (a 16-bit sensor that never saturates at these values) of the three shorter exposures on the saturated blocks
    # and of all four elsewhere, spliced block by block, then demosaiced and inverted.
    rng = np.random.default_rng(7)
    model = CameraModel(pattern_offset=offset)
    sensor, t = model.sensor, model.exposures
    threshold = sensor.saturation * sensor.white_level
    h, w = 48, 64
    # Brightness per 2x2 pixel patch around the longest exposure's threshold: saturated and unsaturated blocks
    # side by side everywhere, so every block edge tests which exposures its pixels use. The 100 ms frame stays
    # below the threshold (half the light of the 200 ms one).
    level = (threshold - sensor.black_level) / (sensor.dn_per_unit_second * t[-1])
    lum = _blocks_to_pixels(rng.uniform(0.5, 1.5, size=(h // 2, w // 2))) * level
    raws = camera.simulate_capture(lum[..., None, None] * elliptical_states(), model, rng=rng)
    assert raws[:-1].max() < threshold

    pr, pc = offset[0] % 2, offset[1] % 2  # an odd offset shifts the blocks: edge row/column in front
    longest = np.pad(raws[-1], ((pr, pr), (pc, pc)), mode="edge")
    hb, wb = longest.shape[0] // 2, longest.shape[1] // 2
    saturated = _blocks_to_pixels(longest.reshape(hb, 2, wb, 2).max(axis=(1, 3)) >= threshold)[pr : pr + h, pc : pc + w]
    assert 0.3 < saturated.mean() < 0.7

    never = SensorParams(bits=16)  # same gain, black level and scale; the threshold is far above 4095
    all_four, _ = decode.hdr_merge(raws, t, never, pattern_offset=offset)
    three, _ = decode.hdr_merge(raws[:-1], t[:-1], never, pattern_offset=offset)
    # Dropping matters on both sides: the clipped frame biases the saturated blocks, noise separates the others.
    assert np.median(np.abs(all_four / three - 1)[saturated]) > 5e-3
    assert np.median(np.abs(all_four / three - 1)[~saturated]) > 1e-3
    merged = np.where(saturated, three, all_four)
    expected = decode.nine_maps(
        decode.stokes_from_intensities(decode.demosaic(merged, grid=grid, pattern_offset=offset), model)
    )

    dec = decode.decode(raws, model, grid=grid)
    assert dec.mask.all()
    # float32 arithmetic in a different order: a few ulp of the intensities (about 0.06).
    np.testing.assert_allclose(dec.maps, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())


@pytest.mark.parametrize("grid", ["half", "full"])
def test_mask_is_the_block_validity_eroded_by_the_interpolation_support(grid):
    # Blocks saturated in every exposure are unmeasured; an output pixel reads lattice samples up to 4 raw pixels
    # (2 blocks) away, so it is valid only if every block within 2 blocks is measured: a 5x5 minimum filter on the
    # block grid (edges repeated), written here with scipy as the reference.
    from scipy import ndimage

    model = CameraModel()
    h, w = 64, 80
    rng = np.random.default_rng(3)
    hot = rng.random((h // 2, w // 2)) < 0.01  # about 13 isolated highlights
    lum = np.where(_blocks_to_pixels(hot), 20.0, 0.05)  # 20: saturated even at 10 ms; 0.05: never saturated
    raws = camera.simulate_capture(lum[..., None, None] * elliptical_states(), model, noise=False)
    measured = ndimage.minimum_filter(~hot, size=5, mode="nearest")
    dec = decode.decode(raws, model, grid=grid)
    np.testing.assert_array_equal(dec.mask, measured if grid == "half" else _blocks_to_pixels(measured))
    assert np.isfinite(dec.maps).all() and np.all(dec.maps[~dec.mask] == 0.0)
    assert 0.2 < dec.mask.mean() < 0.9


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning", "ignore:invalid value:RuntimeWarning")
def test_maps_that_overflow_float32_are_masked_even_where_the_signal_test_passes():
    # Finite float raws of -3e38 on the red 0 degree lattice (below the saturation threshold: measured). With an
    # analyzer transmittance of 0.5 the decoder doubles I0 - I90, so s1 and the maps overflow to -inf while s0 (and
    # the colours' sum, tested against min_signal = -inf) stays finite: only the finiteness check can mask them.
    model = _unit_model(**IDEAL_OPTICS, analyzer_transmittance=0.5)
    raws = _float_raws(_constant_image(elliptical_states(), 32, 32), model)
    color, angle = camera.mosaic_indices(model.pattern_offset)
    (i, j), *_ = zip(*np.nonzero((color == 0) & (angle == 0)), strict=True)
    raws[0, 12 + i : 20 : 4, 12 + j : 20 : 4] = -3e38
    dec = decode.decode(raws, model, grid="full", min_signal=-np.inf)
    assert np.isfinite(dec.maps).all() and np.all(dec.maps[~dec.mask] == 0.0)
    s0 = dec.stokes[..., 0].sum(axis=-1)
    assert (np.isfinite(s0) & ~dec.mask).any()  # masked for the overflow, not for the signal
    assert not dec.mask[14:18, 14:18].any() and dec.mask[:4].all() and dec.mask[:, -4:].all()


def test_dark_pixels_are_masked_and_finite():
    model = CameraModel()
    h, w = 48, 48
    lum = np.full((h, w), 0.05)
    lum[:, 24:] = 0.0  # s0 = 0
    img = lum[..., None, None] * elliptical_states()
    dec = decode.decode(camera.simulate_capture(img, model, noise=False), model)
    assert np.isfinite(dec.maps).all() and np.isfinite(dec.stokes).all()
    assert not dec.mask[:, 14:].any() and dec.mask[:, :10].all()
    # With noise the dark s0 scatters around 0 (std about 3e-5 here); min_signal masks it.
    rng = np.random.default_rng(1234)
    dec = decode.decode(camera.simulate_capture(img, model, rng=rng), model, min_signal=1e-3)
    assert np.isfinite(dec.maps).all()
    assert not dec.mask[:, 14:].any() and dec.mask[:, :10].all()
    assert np.all(dec.maps[~dec.mask] == 0.0)


def test_decode_rejects_bad_inputs_with_helpful_messages():
    model = CameraModel()
    good = np.full((4, 16, 16), 100, dtype=np.uint16)
    nan = good.astype(np.float64)
    nan[2, 3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        decode.decode(nan, model)
    with pytest.raises(ValueError, match=r"\(E, H, W\)"):
        decode.decode(good[0], model)
    with pytest.raises(ValueError, match="3 raw frames for 4 exposure"):
        decode.decode(good[:3], model)
    with pytest.raises(ValueError, match="multiples? of 4"):
        decode.decode(good[:, :14, :], model)
    with pytest.raises(ValueError, match="grid"):
        decode.decode(good, model, grid="quarter")
    with pytest.raises(ValueError, match="multiples? of 4"):
        camera.simulate_capture(np.zeros((10, 12, 3, 4)), model, noise=False)
    with pytest.raises(ValueError, match="multiples? of 4"):
        decode.demosaic(np.zeros((12, 10)))
    with pytest.raises(ValueError, match="NaN"):
        camera.simulate_capture(np.full((8, 8, 3, 4), np.nan), model, noise=False)


# ----------------------------------------------------------------------------------------------------------
# 9. Numerical stress
# ----------------------------------------------------------------------------------------------------------


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("eps", [1e-6, 0.0])
def test_nine_maps_near_zero_s0(dtype, eps):
    tiny = np.finfo(dtype).smallest_subnormal
    s0 = np.array([1e-30, 0.0, -1e-30, tiny, 1.0], dtype=dtype)
    s3 = np.array([1e-30, -1e-30, 0.0, 1.0, -1e-3, 1.0], dtype=dtype)
    grid = np.stack(np.broadcast_arrays(s0[:, None], -s0[:, None], s3[None, :]), -1)  # (5, 6, 3)
    s = np.repeat(grid[..., None, :], 3, axis=-2)  # (5, 6, colour, (s0, s1, s3))
    maps = decode.nine_maps(s, eps=eps)
    assert maps.dtype == dtype and np.isfinite(maps).all()
    cp = _maps_by_kind(maps)["CP"]
    assert np.all(np.abs(cp) <= 1.0)
    # CP = s3 / (s0 + eps) clipped to [-1, 1]; 0 without a positive denominator. Written without dividing
    # where |CP| >= 1, so the reference itself cannot overflow.
    for a in range(s0.size):
        for b in range(s3.size):
            den = float(s0[a] + dtype(eps))  # the sum in the working dtype, as decode forms it
            num = float(s3[b])
            expected = 0.0 if den <= 0 else (np.sign(num) if abs(num) >= den else num / den)
            np.testing.assert_allclose(cp[a, b], expected, rtol=1e-6, atol=0)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("value", [0.0, 1e-30, 1e-300])
def test_decode_near_zero_signal_is_finite(value):
    model = _unit_model(**IDEAL_OPTICS)
    img = _constant_image(value * elliptical_states(), 16, 16)
    dec = decode.decode(_float_raws(img, model), model)
    assert np.isfinite(dec.maps).all() and np.isfinite(dec.stokes).all()
    assert np.all(np.abs(_maps_by_kind(dec.maps)["CP"]) <= 1.0)
    # Raw zeros under a black level of 16: negative signal, masked, finite.
    dec = decode.decode(np.zeros((4, 16, 16), dtype=np.uint16), CameraModel())
    assert np.isfinite(dec.maps).all() and not dec.mask.any()


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("bits", [8, 16])
def test_decode_at_the_corners_of_the_calibration_ranges(bits):
    # Every corner of camera.SENSOR_RANGES x CAMERA_RANGES (gain, electrons per unit, exposure, transmittance,
    # saturation; extinction ratio and QWP angle alternate) decodes a mid-range capture to finite maps with a full
    # mask and the right s0, without a numpy warning. Outside these ranges the fuzzed captures decoded to all-zero
    # maps, an empty mask or NaN, so the model refuses them (test_camera.py).
    from itertools import product

    from pbrdf.sensor.foreground import capture_foreground, noise_floor

    sr, cr = camera.SENSOR_RANGES, camera.CAMERA_RANGES
    svec = np.array([1.0, -0.5, 0.0, 0.2])[None].repeat(3, 0)  # per colour: partly LP, some CP
    corners = product(
        sr["gain"], sr["electrons_per_unit"], cr["exposures"], cr["analyzer_transmittance"], sr["saturation"]
    )
    for k, (gain, epu, t, q, sat) in enumerate(corners):
        sensor = SensorParams(gain=gain, electrons_per_unit=epu, bits=bits, black_level=1.0, saturation=sat)
        model = CameraModel(
            exposures=(t / 2, t) if t > 1 else (t, 2 * t),
            analyzer_transmittance=q,
            extinction_ratio=cr["extinction_ratio"][k % 2],
            qwp_angle=cr["qwp_angle"][k % 2],
            sensor=sensor,
        )
        irr = camera.mosaic(_constant_image(svec, 16, 16), model)
        # Scale the scene so that the longest exposure reaches 30 % of the saturation threshold.
        scale = 0.3 * sat * (sensor.white_level - 1) / (irr.max() * sensor.dn_per_unit_second * max(model.exposures))
        raws = np.round([1.0 + irr * scale * sensor.dn_per_unit_second * tt for tt in model.exposures])
        dec = decode.decode(raws, model)
        where = (gain, epu, t, q, sat)
        assert dec.mask.all() and np.isfinite(dec.maps).all() and np.isfinite(dec.stokes).all(), where
        # 8-bit rounding of a 30 % signal: a few percent.
        np.testing.assert_allclose(dec.stokes[..., 0] / scale, svec[0, 0], rtol=0.05, err_msg=str(where))
        assert np.isfinite(noise_floor(model)) and noise_floor(model) > 0, where
        capture_foreground(dec, model)  # runs without warnings
