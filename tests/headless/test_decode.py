"""headless/decode.py: a capture folder -> maps.npy, mask.npy (and preview.png); one-line errors.

The same tests as the CLI tests beside pbrdf.data.capture's, with the --input flag; a raw whose
header declares an absurd size is refused before anything is allocated.
"""

import json
import re
import struct
import subprocess
import sys
import zlib
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


def test_script_with_preview(tmp_path, disc_capture):
    raws, model = disc_capture  # an object on a dark background: nothing to warn about
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


def test_positional_capture_folder_is_a_usage_error(tmp_path, synthetic):
    folder = cap.save_capture(tmp_path / "c", *synthetic, file_format="npy")
    res = _run("headless/decode.py", str(folder), "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and "required: --input" in res.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("shape", "descr", "message"),
    [
        ((100_000, 100_000), "<u2", r"\.npy array too large to read: its header declares shape \(100000, 100000\)"),
        ((2**40,), "<u2", r"\.npy array too large to read"),
        ((32, 48), "<c8", r"raw dtype must be an integer type \(or float for \.npy\); got complex64"),
    ],
    ids=["10^10 pixels", "2^40 elements, 1-D", "complex dtype"],
)
def test_npy_header_is_checked_before_reading(tmp_path, synthetic, capsys, shape, descr, message):
    """A tiny .npy whose header declares 10^10 uint16 (18.6 GiB) fails on one line, not with a MemoryError."""
    from headless import decode as cli

    folder = cap.save_capture(tmp_path / "c", *synthetic, file_format="npy")
    raw = folder / json.loads((folder / "capture.json").read_text())["raw_files"][1]
    with open(raw, "wb") as f:
        np.lib.format.write_array_header_1_0(f, {"descr": descr, "fortran_order": False, "shape": shape})
        f.write(b"\0" * 64)
    out = tmp_path / "out"
    assert cli.main(["--input", str(folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {raw}: "), err
    assert re.search(message, err), err
    assert not out.exists()


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


# ----------------------------------------------------------------------------------------------------------
# Fuzzed captures: exactly one error line, exit 2, nothing written (they used to end in a traceback, in an error
# naming no field after RuntimeWarnings, or in exit 0 with all-zero maps).


def _json_token(folder: Path, where: tuple[str, ...], token: str) -> None:
    """Set the capture.json key at ``where`` to the literal JSON ``token`` (Infinity, 1e-320, 400 digits, ...)."""
    meta = json.loads((folder / "capture.json").read_text())
    target = meta
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = "__TOKEN__"
    (folder / "capture.json").write_text(json.dumps(meta).replace('"__TOKEN__"', token))


def _png_header(path: Path, width: int, height: int) -> None:
    """A 16-bit grey PNG that declares ``width x height`` pixels and holds almost no data."""

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def _fill(value):
    def fill(raws: np.ndarray) -> np.ndarray:
        return np.full_like(raws, value)

    return fill


def _dark_then_saturated(raws: np.ndarray) -> np.ndarray:
    return np.concatenate([np.full_like(raws[:2], 16), np.full_like(raws[2:], 4095)])


def _token(*where, token: str):
    return lambda folder: _json_token(folder, where, token)


GAIN = ("camera_model", "sensor", "gain")
BAD_MODEL = "/capture.json: invalid camera model"
BAD_CAPTURES = {
    # id: (raws -> raws, folder mutation, the message after "error: <folder>")
    "all dark": (_fill(16), None, ": nothing usable: every raw value is at or below black_level 16 DN"),
    "all saturated": (_fill(4095), None, ": nothing usable: every pixel is saturated"),
    "dark then saturated": (_dark_then_saturated, None, ": nothing usable: no pixel has signal above black_level"),
    "black level at the data": (
        _fill(900),
        _token("black_level", token="900.0"),
        ": nothing usable: every raw value is at or below black_level 900 DN",
    ),
    "gain 1e-320": (None, _token(*GAIN, token="1e-320"), f"{BAD_MODEL} (SensorParams.gain must be in [0.0001, 10000]"),
    "gain 1e308": (None, _token(*GAIN, token="1e308"), f"{BAD_MODEL} (SensorParams.gain must be in"),
    "gain inf": (None, _token(*GAIN, token="Infinity"), f"{BAD_MODEL} (SensorParams.gain must be in"),
    "exposure 1e-300": (
        None,
        _token("exposures_s", 0, token="1e-300"),
        "/capture.json: exposures_s entry 1e-300 s is outside the valid range [1e-07, 10000] s",
    ),
    "exposure 1e300": (
        None,
        _token("exposures_s", 3, token="1e300"),
        "/capture.json: exposures_s entry 1e+300 s is outside the valid range",
    ),
    "extinction ratio 1": (
        None,
        _token("camera_model", "extinction_ratio", token="[1, 1, 1]"),
        f"{BAD_MODEL} (extinction_ratio[R] must be in [2, inf]; got 1)",
    ),
    "transmittance 1e300": (
        None,
        _token("camera_model", "analyzer_transmittance", token="1e300"),
        f"{BAD_MODEL} (analyzer_transmittance must be in [0.001, 1]",
    ),
    "QWP angle inf": (
        None,
        _token("camera_model", "qwp_angle", token="Infinity"),
        f"{BAD_MODEL} (qwp_angle (radians) must be in",
    ),
    "integer too large for a float": (
        None,
        _token("black_level", token="1" + "0" * 400),
        "/capture.json: black_level 10000000000000000000... is too large",
    ),
    "nested 100000 levels": (
        None,
        lambda f: (f / "capture.json").write_text("[" * 100_000 + "]" * 100_000),
        "/capture.json: invalid JSON (nested too deeply)",
    ),
    "raw declaring 200 M pixels": (
        None,
        lambda f: _png_header(f / "raw_0010.0ms.png", 20000, 10000),
        "/raw_0010.0ms.png: raw image too large to read",
    ),
    "raw declaring 100 M pixels": (
        None,
        lambda f: _png_header(f / "raw_0010.0ms.png", 10000, 10000),
        "/raw_0010.0ms.png: cannot read image",
    ),
}


@pytest.mark.parametrize("case", list(BAD_CAPTURES), ids=list(BAD_CAPTURES))
def test_bad_capture_is_one_error_line(tmp_path, synthetic, case):
    fill, mutate, message = BAD_CAPTURES[case]
    raws, model = synthetic
    folder = cap.save_capture(tmp_path / "c", fill(raws) if fill else raws, model, file_format="png")
    if mutate:
        mutate(folder)
    out = tmp_path / "out"
    res = _run("headless/decode.py", "--input", str(folder), "--out", str(out), "--preview")
    assert res.returncode == 2, res.stderr
    assert res.stderr.splitlines() == [res.stderr.rstrip("\n")], res.stderr  # exactly one line: no warnings before
    assert res.stderr.startswith(f"error: {folder}{message}"), res.stderr
    assert not out.exists()


def test_capture_without_object_warns_once(tmp_path, rng):
    # Read noise only (lens cap on): decodable, but no object above the noise floor: written, with one warning line.
    model = CameraModel()
    folder = cap.save_capture(tmp_path / "c", simulate_capture(np.zeros((H, W, 3, 4)), model, rng=rng), model)
    out = tmp_path / "out"
    res = _run("headless/decode.py", "--input", str(folder), "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert res.stderr.splitlines() == [
        f"warning: {folder}: no object stands out from the background above the noise floor (the automatic "
        "foreground mask is empty); mark the object with mask.png"
    ]
    assert sorted(p.name for p in out.iterdir()) == ["maps.npy", "mask.npy"]


def test_room_lit_capture_without_dark_frames_warns_once(tmp_path, rng):
    # Room light at 1/1000 of the display's radiance on the background, no dark frames: the automatic mask takes
    # the whole frame; the maps are written, with one warning line saying what to do.
    from tests.helpers import disc_stokes

    model = CameraModel(ambient=(0.001,) * 3)
    folder = cap.save_capture(tmp_path / "c", simulate_capture(disc_stokes(H, W, 10.0), model, rng=rng), model)
    out = tmp_path / "out"
    res = _run("headless/decode.py", "--input", str(folder), "--out", str(out))
    assert res.returncode == 0, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"warning: {folder}: the automatic object mask covers 100% "), lines
    assert "dark_files" in lines[0] and "headless/dark_frames.py" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == ["maps.npy", "mask.npy"]
