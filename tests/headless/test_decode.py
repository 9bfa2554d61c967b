"""headless/decode.py: a capture folder -> maps.npy, mask.npy (and preview.png); one-line errors.

The same tests as the CLI tests beside pbrdf.data.capture's, with the --input flag; plus the old
positional form, which still works for one release with one deprecation line.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pbrdf.data import capture as cap
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.decode import decode

ROOT = Path(__file__).resolve().parents[2]
H, W = 32, 48


@pytest.fixture
def synthetic(rng):
    """``(raws, model)``: a noisy 32 x 48 bracket of random valid Stokes images."""
    s0 = rng.uniform(0.02, 1.0, size=(H, W, 3))
    d = rng.normal(size=(H, W, 3, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    stokes = np.concatenate([s0[..., None], (rng.uniform(0, 1, (H, W, 3)) * s0)[..., None] * d], axis=-1)
    model = CameraModel()
    return simulate_capture(stokes, model, rng=rng, noise=True), model


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_script_with_preview(tmp_path, synthetic):
    raws, model = synthetic
    folder = cap.save_capture(tmp_path / "c", raws, model, file_format="png")
    out = tmp_path / "out" / "nested"
    res = _run("headless/decode.py", "--input", str(folder), "--out", str(out), "--preview", "--quiet")
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""
    assert sorted(p.name for p in out.iterdir()) == ["maps.npy", "mask.npy", "preview.png"]
    maps, mask = np.load(out / "maps.npy"), np.load(out / "mask.npy")
    assert maps.shape == (H // 2, W // 2, 9) and maps.dtype == np.float32
    assert mask.shape == (H // 2, W // 2) and mask.dtype == np.bool_
    expected = decode(raws, model)
    np.testing.assert_array_equal(maps, expected.maps)
    np.testing.assert_array_equal(mask, expected.mask)
    with Image.open(out / "preview.png") as img:
        assert img.format == "PNG"


def test_module_full_grid(tmp_path, synthetic):
    folder = cap.save_capture(tmp_path / "c", *synthetic, file_format="tiff")
    res = _run("-m", "headless.decode", "--input", str(folder), "--out", str(tmp_path / "out"), "--grid", "full")
    assert res.returncode == 0, res.stderr
    assert np.load(tmp_path / "out" / "maps.npy").shape == (H, W, 9)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["maps.npy", "mask.npy"]


def test_old_positional_form_still_works(tmp_path, synthetic):
    folder = cap.save_capture(tmp_path / "c", *synthetic, file_format="npy")
    res = _run("headless/decode.py", str(folder), "--out", str(tmp_path / "out"))
    assert res.returncode == 0, res.stderr
    assert res.stderr.splitlines() == [
        "decode.py: deprecated: the positional CAPTURE_DIR is now --input (the old form goes away in the next release)"
    ]
    assert (tmp_path / "out" / "maps.npy").is_file()


def _truncate_first_raw(folder: Path) -> None:
    raw = sorted(folder.glob("raw_*.png"))[0]
    raw.write_bytes(raw.read_bytes()[:200])


def _nan_exposure(folder: Path) -> None:
    meta = folder / "capture.json"
    meta.write_text(meta.read_text().replace("0.02,", "NaN,", 1))


@pytest.mark.parametrize("corrupt", [_truncate_first_raw, _nan_exposure], ids=["truncated PNG", "NaN exposure"])
def test_bad_input_exits_2(tmp_path, synthetic, corrupt):
    folder = cap.save_capture(tmp_path / "c", *synthetic, file_format="png")
    corrupt(folder)
    out = tmp_path / "out"
    res = _run("headless/decode.py", "--input", str(folder), "--out", str(out), "--preview")
    assert res.returncode == 2
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert str(folder) in lines[0]
    assert not out.exists()


def test_missing_input_is_a_usage_error(tmp_path):
    res = _run("headless/decode.py", "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and "required: --input" in res.stderr


def test_help_explains_format():
    res = _run("headless/decode.py", "--help")
    assert res.returncode == 0
    for word in ("capture.json", "exposures_s", "raw_files", "black_level", "white_level", "maps.npy", "--input"):
        assert word in res.stdout
