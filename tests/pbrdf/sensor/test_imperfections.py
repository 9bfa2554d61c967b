"""Rig imperfections: ambient light with dark frames, display cross-talk, lens vignetting (forward and inverse)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pbrdf.data.capture import load_capture, save_capture
from pbrdf.data.capture_decode import decode_capture
from pbrdf.data.raw_files import write_raw
from pbrdf.sensor.camera import CameraModel, expose, mosaic, simulate_capture
from pbrdf.sensor.decode import decode, hdr_merge
from pbrdf.sensor.imperfections import vignetting_map
from pbrdf.sensor.rig import Rig

H = W = 32
AMBIENT = (0.05, 0.08, 0.03)
MIX = ((0.9, 0.1, 0.0), (0.05, 0.85, 0.1), (0.0, 0.12, 0.95))


def _scene() -> np.ndarray:
    """Smooth (affine) per-region Stokes images, partly linearly and circularly polarized: ``(H, W, 3, 4)``."""
    yy, xx = np.mgrid[0:H, 0:W] / H
    s = np.zeros((H, W, 3, 4))
    s[..., 0] = (0.2 + 0.3 * yy + 0.1 * xx)[..., None] * np.array([1.0, 0.8, 0.6])
    s[..., 1] = -0.5 * s[..., 0]
    s[..., 3] = 0.1 * s[..., 0]
    return s


def _hand_maps(s: np.ndarray) -> np.ndarray:
    """The nine maps by hand, on the half grid (2x2 block means of an affine scene = block centres)."""
    b = s.reshape(H // 2, 2, W // 2, 2, 3, 4).mean(axis=(1, 3))
    return np.concatenate([b[..., 0] + b[..., 1], -b[..., 1], b[..., 3] / b[..., 0]], axis=-1)


def _inner(maps: np.ndarray) -> np.ndarray:
    """Away from the frame edge, where the demosaic repeats edge samples and is not exactly affine."""
    return maps[2:-2, 2:-2]


def _ideal(**kw) -> CameraModel:
    return CameraModel(extinction_ratio=math.inf, **kw)


# ---------------------------------------------------------------- ambient and dark frames


def test_dark_frame_removes_ambient_within_noise():
    s, m = _scene(), _ideal(ambient=AMBIENT)
    rng = np.random.default_rng(1)
    raws = simulate_capture(s, m, rng=rng)
    dark = simulate_capture(np.zeros_like(s), m, rng=rng)  # display off: ambient only
    got = decode(raws, m, dark=dark).maps
    want = _hand_maps(s)
    # Noise of a difference of two HDR estimates: a few 1e-3 in unpol / LP at these levels.
    np.testing.assert_allclose(got[..., :6].mean(axis=(0, 1)), want[..., :6].mean(axis=(0, 1)), atol=2e-3)
    assert np.abs(got[..., :6] - want[..., :6]).max() < 0.03
    assert np.all(np.isfinite(got))


def test_without_dark_frame_unpol_is_biased_by_exactly_the_ambient():
    s, m = _scene(), _ideal(ambient=AMBIENT)
    got = decode(simulate_capture(s, m, noise=False), m).maps
    want = _hand_maps(s)
    # Unpolarized ambient a adds (a, 0, 0, 0): unpol + a, LP unchanged, CP = s3 / (s0 + a).
    np.testing.assert_allclose(_inner(got[..., :3] - want[..., :3]), np.broadcast_to(AMBIENT, (12, 12, 3)), atol=5e-4)
    np.testing.assert_allclose(_inner(got[..., 3:6]), _inner(want[..., 3:6]), atol=5e-4)
    b = s.reshape(H // 2, 2, W // 2, 2, 3, 4).mean(axis=(1, 3))
    np.testing.assert_allclose(_inner(got[..., 6:]), _inner(b[..., 3] / (b[..., 0] + np.array(AMBIENT))), atol=5e-3)


def test_capture_folder_carries_dark_frames(tmp_path):
    s, m = _scene(), _ideal(ambient=AMBIENT)
    raws = simulate_capture(s, m, noise=False)
    dark = simulate_capture(np.zeros_like(s), m, noise=False)
    folder = save_capture(tmp_path / "cap", raws, m, dark=dark)
    doc = json.loads((folder / "capture.json").read_text())
    assert len(doc["dark_files"]) == len(doc["raw_files"])
    cap = load_capture(folder)
    np.testing.assert_array_equal(cap.dark, dark)
    got = decode_capture(cap).maps
    np.testing.assert_allclose(_inner(got[..., :6]), _inner(_hand_maps(s)[..., :6]), atol=2e-3)
    write_raw(folder / doc["dark_files"][1], dark[1, :16], "png")  # a dark frame of another size
    with pytest.raises(ValueError, match="differs from"):
        load_capture(folder)
    (folder / doc["dark_files"][1]).unlink()
    with pytest.raises(FileNotFoundError, match=doc["dark_files"][1]):
        load_capture(folder)
    doc["dark_files"] = doc["dark_files"][:2]
    (folder / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="dark_files must be a list of 4"):
        load_capture(folder)


def test_dark_frame_extremes_stay_finite():
    m = _ideal()
    raws = simulate_capture(_scene(), m, noise=False)
    white = np.full_like(raws, m.sensor.white_level)
    for r, d in ((raws, white), (white, np.zeros_like(raws)), (np.zeros_like(raws), white)):
        dec = decode(r, m, dark=d)
        assert np.all(np.isfinite(dec.maps)) and np.all(np.isfinite(dec.stokes))
    with pytest.raises(ValueError, match="dark frames must have the shape"):
        decode(raws, m, dark=raws[:2])


# ---------------------------------------------------------------- cross-talk


def test_crosstalk_forward_is_the_hand_mixture():
    s = _scene()
    mixed = np.zeros_like(s)
    for c in range(3):  # camera channel c sees every region r with weight MIX[c][r]
        for r in range(3):
            mixed[:, :, c, :] += MIX[c][r] * s[:, :, r, :]
    np.testing.assert_array_equal(
        simulate_capture(s, _ideal(crosstalk=MIX), noise=False), simulate_capture(mixed, _ideal(), noise=False)
    )


def test_crosstalk_decoder_unmixes_and_nominal_decoder_sees_the_mixture():
    s = _scene()
    m = _ideal(crosstalk=MIX)
    raws = simulate_capture(s, m, noise=False)
    want = _hand_maps(s)
    np.testing.assert_allclose(_inner(decode(raws, m).maps), _inner(want), atol=2e-3)
    nominal = decode(raws, _ideal()).maps
    unpol = want[..., :3] @ np.array(MIX).T  # channel c: sum_r MIX[c][r] unpol_r
    np.testing.assert_allclose(_inner(nominal[..., :3]), _inner(unpol), atol=1e-3)
    assert np.abs(nominal[..., :3] - want[..., :3]).max() > 0.01


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ([[1, -0.1, 0], [0, 1, 0], [0, 0, 1]], r"crosstalk entries must be in \[0, 1\]"),
        ([[1, 1, 0], [1, 1, 0], [0, 0, 1]], "crosstalk is singular or ill-conditioned"),
        ([[1, 0.99, 0], [0.99, 1, 0], [0, 0, 1]], "crosstalk is singular or ill-conditioned"),
        ([[1, 0], [0, 1]], "crosstalk must be a 3 x 3 matrix"),
        ("identity", "crosstalk must be a 3 x 3 matrix"),
    ],
)
def test_crosstalk_refused(value, message):
    with pytest.raises(ValueError, match=message):
        CameraModel(crosstalk=value)


# ---------------------------------------------------------------- vignetting


def test_vignetting_map_is_the_analytic_falloff():
    f, poly = 30.0, (-0.3, 0.1, -0.05)
    v = vignetting_map((H, W), f, poly)
    i, j = 3, 27
    dx, dy = (j + 0.5) - W / 2, (i + 0.5) - H / 2
    theta = math.atan(math.hypot(dx, dy) / f)
    rho = math.hypot(dx, dy) / math.hypot(W / 2, H / 2)
    want = math.cos(theta) ** 4 * (1 - 0.3 * rho**2 + 0.1 * rho**4 - 0.05 * rho**6)
    assert v[i, j] == pytest.approx(want, rel=1e-12)
    assert vignetting_map((H, W), f, poly, grid="half")[1, 13] == pytest.approx(
        math.cos(math.atan(math.hypot(27.0 - W / 2, 3.0 - H / 2) / f)) ** 4
        * np.polyval([-0.05, 0.1, -0.3, 1.0], math.hypot(27.0 - W / 2, 3.0 - H / 2) ** 2 / (H**2 / 2)),
        rel=1e-12,
    )


def test_vignetting_forward_and_inverse():
    m = _ideal(vignetting_focal_px=25.0, vignetting_poly=(-0.2, 0.0, 0.0))
    flat = np.zeros((H, W, 3, 4))
    flat[..., 0], flat[..., 1] = 0.5, -0.5  # vertically polarized display light
    raws = simulate_capture(flat, m, noise=False)
    merged, _ = hdr_merge(raws, m.exposures, m.sensor)
    nominal, _ = hdr_merge(simulate_capture(flat, _ideal(), noise=False), m.exposures, m.sensor)
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    d2 = (yy - H / 2) ** 2 + (xx - W / 2) ** 2
    falloff = (25.0**2 / (25.0**2 + d2)) ** 2 * (1 - 0.2 * d2 / (H**2 / 2))
    lit = nominal > 0.1  # the 90-degree analyzers see the vertical light
    np.testing.assert_allclose(merged[lit] / nominal[lit], falloff[lit], rtol=2e-3)
    got = decode(raws, m).maps
    np.testing.assert_allclose(got[..., 3:6], 0.5, atol=2e-3)
    np.testing.assert_allclose(got[..., :3], 0.0, atol=2e-3)


def test_vignetting_refused_and_extreme_stays_finite():
    with pytest.raises(ValueError, match="vignetting_poly"):
        CameraModel(vignetting_poly=(-0.99, 0.0, 0.0))
    with pytest.raises(ValueError, match="vignetting_focal_px"):
        CameraModel(vignetting_focal_px=0.5)
    with pytest.raises(ValueError, match=r"vignetting_poly\[1\]"):
        CameraModel(vignetting_poly=(0.0, float("nan"), 0.0))
    m = _ideal(vignetting_focal_px=1.0)  # corners at 1e-5 of the centre
    dec = decode(simulate_capture(_scene(), m, noise=False), m)
    assert np.all(np.isfinite(dec.maps))


# ---------------------------------------------------------------- nominal and JSON


def test_nominal_fields_are_bit_identical_to_the_ideal_chain():
    s = _scene()
    model = CameraModel.from_dict({"qwp_angle": 0.0})  # an old camera model without the new keys
    assert model == CameraModel() and model.nominal_rig
    got = simulate_capture(s, model, rng=np.random.default_rng(5))
    rng = np.random.default_rng(5)
    want = np.stack([expose(mosaic(s, model), t, model.sensor, rng=rng) for t in model.exposures])
    np.testing.assert_array_equal(got, want)
    a, b = decode(got, model), decode(got, model, dark=None)
    np.testing.assert_array_equal(a.maps, b.maps)


def test_json_round_trip_and_rig_override():
    m = CameraModel(ambient=AMBIENT, crosstalk=MIX, vignetting_focal_px=2000.0, vignetting_poly=(-0.1, 0.0, 0.0))
    assert CameraModel.from_dict(json.loads(json.dumps(m.to_dict(), allow_nan=False))) == m
    d = json.loads(json.dumps(CameraModel().to_dict(), allow_nan=False))
    assert d["vignetting_focal_px"] == "inf" and CameraModel.from_dict(d) == CameraModel()
    rig = Rig.from_dict({"camera": {"model": {"crosstalk": [list(r) for r in MIX], "ambient": 0.01}}})
    assert rig.camera.model.crosstalk == MIX and rig.camera.model.ambient == (0.01, 0.01, 0.01)
    with pytest.raises(ValueError, match=r"ambient\[G\] must be in \[0, 10000\]"):
        CameraModel(ambient=(0.0, -1.0, 0.0))
