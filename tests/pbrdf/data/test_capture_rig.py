"""pbrdf/data/capture_rig.py and the --rig flags: a capture decoded with a calibrated rig file."""

import math

import numpy as np
import pytest

from headless import decode as decode_cli
from network.infer import load_input
from pbrdf.data import capture as pcapture
from pbrdf.data.capture_rig import read_rig, with_rig
from pbrdf.sensor.camera import CameraModel, SensorParams, simulate_capture
from pbrdf.sensor.decode import decode
from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig

#: The optics of a rig the lab calibrated (far from nominal, so a decode that ignores them is visibly off).
OPTICS = {"qwp_angle": 0.05, "qwp_retardance": (1.40, 1.62, 1.75), "extinction_ratio": (20.0, 40.0, 25.0),
          "crosstalk": ((0.9, 0.15, 0.05), (0.12, 0.95, 0.1), (0.04, 0.18, 0.85)),
          "vignetting_poly": (-0.2, 0.0, 0.0)}  # fmt: skip


def _scene(rng, shape=(32, 32)):
    """Stokes ``(H, W, 3, 4)`` of a smooth partly polarized scene."""
    s = np.zeros((*shape, 3, 4))
    s[..., 0] = 0.05 + 0.05 * rng.random((*shape, 3))
    s[..., 1] = -0.3 * s[..., 0]
    s[..., 2] = 0.2 * s[..., 0]
    s[..., 3] = 0.1 * s[..., 0]
    return s


def _rig_file(tmp_path, optics=OPTICS):
    """A calibrated rig: its own bracket and sensor (which the capture overrides), a brighter display."""
    model = CameraModel(**optics, exposures=(1.0, 2.0), sensor=SensorParams(gain=0.5))
    rig = Rig(DisplaySpec(radiance=1.5, degree_of_polarization=0.97), CameraSpec(model=model))
    rig.save(tmp_path / "rig.json")
    return rig


def _capture_folder(tmp_path, rng, true_model):
    """A capture through ``true_model``, its capture.json with the nominal model (as the lab wrote it)."""
    nominal = CameraModel(ambient=(0.0, 0.0, 0.0))
    raws = simulate_capture(_scene(rng), true_model, rng=np.random.default_rng(3))
    return pcapture.save_capture(tmp_path / "cap", raws, nominal), raws


def test_with_rig_takes_the_optics_and_the_rig_and_keeps_the_bracket_and_sensor(tmp_path):
    rig = _rig_file(tmp_path)
    cap = pcapture.Capture(raws=np.zeros((2, 8, 8), np.uint16), model=CameraModel(exposures=(0.01, 0.1)))
    out = with_rig(cap, read_rig(tmp_path / "rig.json"))
    assert out.model.exposures == (0.01, 0.1) and out.model.sensor == CameraModel().sensor
    for k, v in OPTICS.items():
        np.testing.assert_allclose(getattr(out.model, k), v, err_msg=k)
    assert out.meta.rig == rig and out.meta.radiance == 1.5
    assert cap.model == CameraModel(exposures=(0.01, 0.1))  # the input is not changed


def test_decode_with_rig_equals_decoding_with_the_true_model(tmp_path, rng):
    rig = _rig_file(tmp_path)
    true = CameraModel(**OPTICS)
    folder, raws = _capture_folder(tmp_path, rng, true)
    want = decode(raws, true).maps  # the decoder given the true model directly
    paths = decode_cli.run(folder, tmp_path / "out", rig=tmp_path / "rig.json")
    got = np.load(paths[0])
    np.testing.assert_allclose(got, want, atol=1e-6)
    plain = np.load(decode_cli.run(folder, tmp_path / "plain")[0])  # capture.json's nominal model: visibly off
    assert np.abs(plain - want).mean() > 20 * np.abs(got - want).mean() + 1e-3
    inp = load_input(folder, rig=rig)  # infer.py's path
    assert inp.radiance == 1.5 and inp.rig == rig
    missing = ["--input", str(folder), "--out", str(tmp_path / "x"), "--rig", str(tmp_path / "no.json")]
    assert decode_cli.main(missing) == 2


def test_a_bad_rig_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "rig.json"
    bad.write_text('{"camera": {"model": {"qwp_retardance": [0.1, 1.5, 1.5]}}}')
    with pytest.raises(ValueError, match=r"rig.json: camera.model: .*qwp_retardance"):
        read_rig(bad)
    with pytest.raises(FileNotFoundError, match="rig file not found"):
        read_rig(tmp_path / "missing.json")
    assert math.isfinite(Rig().display.radiance)


def test_infer_reads_the_rig_file_it_is_given(tmp_path, rng, capsys):
    from headless import infer as infer_cli

    folder, _ = _capture_folder(tmp_path, rng, CameraModel(**OPTICS))
    args = ["--input", str(folder), "--out", str(tmp_path / "out"), "--quiet", "--rig", str(tmp_path / "none.json")]
    assert infer_cli.main(args) != 0
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"error: {tmp_path / 'none.json'}: rig file not found"
