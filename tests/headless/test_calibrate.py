"""headless/calibrate.py: target capture folders -> rig.json; one-line errors, nothing written on bad input.

The written rig is what an object's capture.json takes: its camera model, put in as
``camera_model``, is the one the capture decodes with.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from headless import calibrate as cli
from pbrdf.data.calibration_captures import load_targets, save_targets
from pbrdf.data.capture import CAPTURE_JSON, load_capture, save_capture
from pbrdf.data.capture_decode import decode_capture
from pbrdf.sensor.calibration_targets import simulate_targets
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.decode import decode
from pbrdf.sensor.projection import pinhole_intrinsics
from pbrdf.sensor.rig import CameraSpec, DisplaySpec, Rig

ROOT = Path(__file__).resolve().parents[2]
SIZE = 96
TRUE = Rig(
    DisplaySpec(degree_of_polarization=0.95, polarization_angle=math.pi / 2 - 0.05),
    CameraSpec(model=CameraModel(
        qwp_angle=-0.02, qwp_retardance=(1.45, 1.6, 1.7), extinction_ratio=(60, 90, 150), ambient=(0.01, 0.02, 0.015),
        crosstalk=[[0.9, 0.1, 0.0], [0.1, 0.9, 0.1], [0.0, 0.1, 0.9]], vignetting_focal_px=0.94 * SIZE,
        vignetting_poly=(-0.2, 0.05, 0.0))),
)  # fmt: skip


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> Path:
    """A folder of synthetic target captures from :data:`TRUE`."""
    root = tmp_path_factory.mktemp("calibration") / "captures"
    k = pinhole_intrinsics(0.94 * SIZE, SIZE, SIZE)
    save_targets(root, simulate_targets(TRUE, (SIZE, SIZE), rng=np.random.default_rng(1), intrinsics=k))
    return root


def _copy(captures: Path, tmp_path: Path, drop: str | None = None) -> Path:
    out = tmp_path / "captures"
    shutil.copytree(captures, out)
    if drop:
        shutil.rmtree(out / drop)
    return out


def test_writes_a_rig_the_decoder_reads(captures, tmp_path, capsys):
    out = tmp_path / "rig.json"
    assert cli.main(["--input", str(captures), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.strip().splitlines()[-1] == str(out)
    assert "qwp_retardance:" in printed and "not identifiable" in printed
    assert "display.emission_exponent: 0.0 (estimated" in printed and "display.tone_gamma[B]: " in printed
    assert sorted({t.level for t in load_targets(captures)}) == [0.25, 0.5, 1.0]  # the levels round-trip
    rig = Rig.load(out)
    est = rig.camera.model
    np.testing.assert_allclose(est.qwp_retardance, TRUE.camera.model.qwp_retardance, atol=0.01)
    np.testing.assert_allclose(est.crosstalk, TRUE.camera.model.crosstalk, atol=0.01)
    assert abs(rig.display.degree_of_polarization - 0.95) < 0.01

    # An object capture whose capture.json takes the calibrated camera model decodes with it.
    yy, xx = np.mgrid[0:32, 0:32] / 32
    s = np.zeros((32, 32, 3, 4))
    s[..., 0] = (0.2 + 0.2 * yy + 0.1 * xx)[..., None]
    s[..., 1] = -0.5 * s[..., 0]
    rng = np.random.default_rng(2)
    raws = simulate_capture(s, TRUE.camera.model, rng=rng)
    dark = simulate_capture(np.zeros_like(s), TRUE.camera.model, rng=rng)
    calibrated = json.loads(out.read_text())["camera"]["model"]
    folder = save_capture(tmp_path / "object", raws, CameraModel(), dark=dark)
    meta = json.loads((folder / CAPTURE_JSON).read_text())
    meta["camera_model"] = calibrated
    (folder / CAPTURE_JSON).write_text(json.dumps(meta))
    cap = load_capture(folder)
    assert cap.model.crosstalk == est.crosstalk and cap.model.qwp_retardance == est.qwp_retardance
    got = decode_capture(folder).maps
    np.testing.assert_array_equal(got, decode(raws, est.replace(exposures=cap.model.exposures), dark=dark).maps)
    want = decode(raws, TRUE.camera.model, dark=dark).maps
    assert np.abs(got - want)[2:-2, 2:-2].max() < 0.02 * np.abs(want).max()


@pytest.mark.parametrize(
    ("drop", "message"),
    [
        ("dark", "missing dark frame"),
        ("white_g", "missing white target for display channel G"),
        ("polarizer_030.0", None),  # five angles remain: still calibrates
    ],
)
def test_missing_targets_get_one_line_and_nothing_is_written(captures, tmp_path, capsys, drop, message):
    folder = _copy(captures, tmp_path, drop)
    out = tmp_path / "rig.json"
    code = cli.main(["--input", str(folder), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    if message is None:
        assert code == 0 and out.is_file()
        return
    assert code == 2 and not out.exists()
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err


def test_failed_calibration_leaves_an_existing_rig_untouched(captures, tmp_path, capsys):
    folder = _copy(captures, tmp_path)
    for name in ("polarizer_000.0", "polarizer_030.0", "polarizer_060.0", "polarizer_090.0"):
        shutil.rmtree(folder / name)
    out = tmp_path / "rig.json"
    out.write_text("previous")
    assert cli.main(["--input", str(folder), "--out", str(out)]) == 2
    assert "need polarizer targets at >= 3 distinct angles" in capsys.readouterr().err
    assert out.read_text() == "previous"


def test_bad_target_keys_name_the_file(captures, tmp_path, capsys):
    folder = _copy(captures, tmp_path)
    meta_path = folder / "white_r" / CAPTURE_JSON
    meta = json.loads(meta_path.read_text())
    meta["display_channel"] = "X"
    meta_path.write_text(json.dumps(meta))
    assert cli.main(["--input", str(folder), "--out", str(tmp_path / "rig.json")]) == 2
    err = capsys.readouterr().err
    assert "white_r" in err and "display_channel must be one of" in err
    meta_path = folder / "white_g_050" / CAPTURE_JSON
    meta = json.loads(meta_path.read_text())
    meta["level"] = 1.5
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"white_g_050/capture.json: level must be in \(0, 1\]"):
        load_targets(folder)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no calibration captures"):
        load_targets(tmp_path / "empty")


def test_runs_as_a_script(captures, tmp_path):
    out = tmp_path / "rig.json"
    proc = subprocess.run([sys.executable, str(ROOT / "headless" / "calibrate.py"), "--input", str(captures), "--out",
                           str(out), "--quiet"], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == str(out) and Rig.load(out).camera.model.crosstalk != Rig().camera.model.crosstalk


def test_the_synthetic_capture_tool_writes_what_calibrate_reads(tmp_path):
    out = tmp_path / "captures"
    tool = subprocess.run([sys.executable, str(ROOT / "tools" / "make_calibration_captures.py"), "--out", str(out),
                           "--size", "64", "--seed", "3"], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert tool.returncode == 0, tool.stderr
    assert len([p for p in out.iterdir() if p.is_dir()]) == 19 and (out / "true_rig.json").is_file()
    assert cli.main(["--input", str(out), "--out", str(tmp_path / "rig.json"), "--quiet"]) == 0
    est, true = Rig.load(tmp_path / "rig.json"), Rig.load(out / "true_rig.json")
    np.testing.assert_allclose(est.camera.model.qwp_retardance, true.camera.model.qwp_retardance, atol=0.01)
    np.testing.assert_allclose(est.camera.model.crosstalk, true.camera.model.crosstalk, atol=0.02)
    assert abs(est.display.emission_exponent - true.display.emission_exponent) < 0.05 < true.display.emission_exponent
    np.testing.assert_allclose(est.display.tone_gamma, true.display.tone_gamma, atol=0.03)
