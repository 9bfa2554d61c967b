"""Tests for pbrdf.data.capture (capture folders on disk) and the headless/decode.py CLI."""

from __future__ import annotations

import json
import re
import shutil
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pbrdf.data import capture as cap
from pbrdf.data import capture_decode as capdec
from pbrdf.sensor.camera import CameraModel, SensorParams, simulate_capture
from pbrdf.sensor.decode import decode

REPO = Path(__file__).resolve().parents[3]
H, W = 32, 48


def _stokes_scene(rng: np.random.Generator, h: int = H, w: int = W) -> np.ndarray:
    """Physically valid Stokes images ``(h, w, 3, 4)``: random s0, DoP and polarization state."""
    s0 = rng.uniform(0.02, 1.0, size=(h, w, 3))
    dop = rng.uniform(0.0, 1.0, size=(h, w, 3))
    d = rng.normal(size=(h, w, 3, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    s = np.empty((h, w, 3, 4))
    s[..., 0] = s0
    s[..., 1:] = (dop * s0)[..., None] * d
    return s


def _calibrated_model(**changes) -> CameraModel:
    """A non-default model, so a round trip has something to lose."""
    model = CameraModel(
        qwp_angle=0.0125,
        qwp_retardance=(1.50, 1.55, 1.62),
        extinction_ratio=(80.0, 120.0, np.inf),
        analyzer_transmittance=0.93,
        exposures=(0.01, 0.02, 0.1, 0.2),
        sensor=SensorParams(gain=0.41, read_noise=3.1, black_level=64.0, bits=12, saturation=0.9),
        pattern_offset=(1, 2),
    )
    return model.replace(**changes)


@pytest.fixture
def synthetic(rng):
    """``(raws, model)``: a noisy synthetic 32x48 bracket from camera.simulate_capture."""
    model = _calibrated_model()
    raws = simulate_capture(_stokes_scene(rng), model, rng=rng, noise=True)
    return raws, model


def _write_json(folder: Path, meta) -> None:
    (folder / "capture.json").write_text(json.dumps(meta) if not isinstance(meta, str) else meta)


def _read_json(folder: Path) -> dict:
    return json.loads((folder / "capture.json").read_text())


def _edit_json(folder: Path, **changes) -> None:
    meta = _read_json(folder)
    meta.update(changes)
    _write_json(folder, meta)


# --------------------------------------------------------------------------------------------
# Round trips


class TestRoundTrip:
    @pytest.mark.parametrize("file_format", ["png", "tiff", "npy"])
    def test_exact(self, tmp_path, synthetic, file_format):
        raws, model = synthetic
        raws = raws.copy()
        raws[0, 0, 0], raws[-1, -1, -1] = 0, model.sensor.white_level  # both ends of the range
        extra = {"object": "bunny", "notes": {"lens": "8 mm", "temps_c": [21.5, 22.0]}}
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format=file_format, extra=extra)
        loaded = cap.load_capture(folder)
        assert loaded.raws.dtype == np.uint16
        np.testing.assert_allclose(loaded.raws, raws, rtol=0, atol=0)
        assert loaded.model == model
        assert loaded.metadata == extra
        assert loaded.folder == folder
        assert loaded.raw_files == tuple(f"raw_{t:06.1f}ms.{file_format}" for t in (10.0, 20.0, 100.0, 200.0))
        assert sorted(p.name for p in folder.iterdir()) == sorted([*loaded.raw_files, "capture.json"])

    @pytest.mark.parametrize("file_format", ["png", "tiff"])
    def test_full_16_bit_range_through_pillow(self, tmp_path, rng, file_format):
        # 16-bit PNG/TIFF must keep every bit: values from 0 to 65535, odd and even.
        model = CameraModel(exposures=(0.01,), sensor=SensorParams(bits=16, black_level=0.0))
        raws = rng.integers(0, 65536, size=(1, 8, 12), dtype=np.uint16)
        raws[0, 0, :3] = (0, 1, 65535)
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format=file_format)
        with Image.open(folder / cap.load_capture(folder).raw_files[0]) as img:
            assert img.mode == "I;16"
            assert img.format == file_format.upper()
        np.testing.assert_allclose(cap.load_capture(folder).raws, raws, rtol=0, atol=0)

    def test_json_layout(self, tmp_path, synthetic):
        raws, model = synthetic
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy", extra={"object": "x"})
        meta = _read_json(folder)
        assert meta["format"] == cap.CAPTURE_FORMAT == "pdir-capture/1"
        assert meta["exposures_s"] == [0.01, 0.02, 0.1, 0.2]
        assert meta["raw_files"] == ["raw_0010.0ms.npy", "raw_0020.0ms.npy", "raw_0100.0ms.npy", "raw_0200.0ms.npy"]
        assert (meta["black_level"], meta["white_level"], meta["bits"]) == (64.0, 4095, 12)
        assert meta["pattern_offset"] == [1, 2]
        assert meta["camera_model"]["extinction_ratio"] == [80.0, 120.0, "inf"]
        assert meta["object"] == "x"

    def test_save_sorts_exposures_with_raws(self, tmp_path, synthetic):
        raws, model = synthetic
        perm = [2, 0, 3, 1]
        shuffled = model.replace(exposures=tuple(model.exposures[k] for k in perm))
        folder = cap.save_capture(tmp_path / "c", raws[perm], shuffled, file_format="npy")
        loaded = cap.load_capture(folder)
        assert loaded.model == model
        np.testing.assert_array_equal(loaded.raws, raws)

    def test_load_sorts_exposures_with_files(self, tmp_path, synthetic):
        raws, model = synthetic
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        meta = _read_json(folder)
        perm = [3, 1, 0, 2]
        _edit_json(
            folder,
            exposures_s=[meta["exposures_s"][k] for k in perm],
            raw_files=[meta["raw_files"][k] for k in perm],
        )
        loaded = cap.load_capture(folder)
        assert loaded.model.exposures == model.exposures
        assert loaded.raw_files == tuple(meta["raw_files"])
        np.testing.assert_array_equal(loaded.raws, raws)

    def test_top_level_keys_override_camera_model(self, tmp_path, synthetic):
        raws, model = synthetic
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        _edit_json(folder, black_level=100.0, pattern_offset=[3, 0], exposures_s=[0.01, 0.03, 0.1, 0.3])
        loaded = cap.load_capture(folder)
        assert loaded.model.sensor.black_level == 100.0
        assert loaded.model.pattern_offset == (3, 0)
        assert loaded.model.exposures == (0.01, 0.03, 0.1, 0.3)
        assert loaded.model.qwp_retardance == model.qwp_retardance  # the rest from camera_model

    def test_minimal_hand_written_capture(self, tmp_path, rng):
        # Only the required keys; camera model defaults; a 16-bit PNG made by another tool.
        folder = tmp_path / "c"
        folder.mkdir()
        frames = [rng.integers(16, 300 * k, size=(8, 16), dtype=np.uint16) for k in (1, 2)]
        for k, frame in enumerate(frames):
            Image.fromarray(frame).save(folder / f"f{k}.png")
        _write_json(
            folder, {"format": "pdir-capture/1", "exposures_s": [0.01, 0.02], "raw_files": ["f0.png", "f1.png"]}
        )
        loaded = cap.load_capture(folder)
        assert loaded.model == CameraModel(exposures=(0.01, 0.02))
        assert loaded.metadata == {}
        np.testing.assert_array_equal(loaded.raws, np.stack(frames))

    def test_whole_number_float_and_int32_npy_accepted(self, tmp_path, synthetic):
        raws, model = synthetic
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        names = _read_json(folder)["raw_files"]
        np.save(folder / names[0], raws[0].astype(np.float32))
        np.save(folder / names[1], raws[1].astype(np.int32))
        loaded = cap.load_capture(folder)
        assert loaded.raws.dtype == np.uint16
        np.testing.assert_array_equal(loaded.raws, raws)

    def test_overwrite(self, tmp_path, synthetic):
        raws, model = synthetic
        target = tmp_path / "c"
        cap.save_capture(target, raws, model, file_format="png")
        with pytest.raises(FileExistsError, match="not empty"):
            cap.save_capture(target, raws, model, file_format="npy")
        cap.save_capture(target, raws, model, file_format="npy", overwrite=True)
        assert sorted(p.name for p in target.iterdir())[-1] == "raw_0200.0ms.npy"
        assert not any(p.suffix == ".png" for p in target.iterdir())
        assert [p.name for p in tmp_path.iterdir()] == ["c"]  # no temp or old folders left

    def test_existing_empty_folder_is_used(self, tmp_path, synthetic):
        raws, model = synthetic
        (tmp_path / "c").mkdir()
        cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        assert cap.load_capture(tmp_path / "c").raws.shape == (4, H, W)


# --------------------------------------------------------------------------------------------
# Decoding from disk equals decoding in memory


class TestDecodeCapture:
    @pytest.mark.parametrize("file_format", ["png", "tiff", "npy"])
    @pytest.mark.parametrize("grid", ["half", "full"])
    def test_same_as_in_memory(self, tmp_path, rng, file_format, grid):
        model = CameraModel()  # the default camera, 10/20/100/200 ms
        raws = simulate_capture(_stokes_scene(rng), model, rng=np.random.default_rng(1234), noise=True)
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format=file_format)
        expected = decode(raws, model, grid=grid)
        for got in (
            capdec.decode_capture(folder, grid=grid),
            capdec.decode_capture(cap.load_capture(folder), grid=grid),
        ):
            np.testing.assert_array_equal(got.maps, expected.maps)
            np.testing.assert_array_equal(got.mask, expected.mask)
            np.testing.assert_array_equal(got.stokes, expected.stokes)
        n = 2 if grid == "half" else 1
        assert expected.maps.shape == (H // n, W // n, 9)

    def test_calibrated_model_is_used(self, tmp_path, synthetic):
        raws, model = synthetic
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        got = capdec.decode_capture(folder)
        np.testing.assert_array_equal(got.maps, decode(raws, model).maps)
        assert not np.array_equal(got.maps, decode(raws, CameraModel()).maps)


class TestDecodedCaptureMasks:
    def test_measured_foreground_and_input_mask(self, tmp_path, rng):
        model = CameraModel()
        st = np.zeros((H, W, 3, 4))
        st[8:24, 12:36, :, 0] = 0.05  # a bright rectangle on a black background
        raws = simulate_capture(st, model, rng=rng)
        got = capdec.decode_capture(cap.save_capture(tmp_path / "c", raws, model))
        assert isinstance(got, capdec.DecodedCapture) and got.foreground_source == "auto"
        assert got.measured.all()  # nothing saturates: every pixel was measured ...
        assert not got.mask.all()  # ... but the noise floor fails decode's s0 > 0 on some
        truth = np.zeros((H // 2, W // 2), bool)
        truth[4:12, 6:18] = True
        # A sharp-edged rectangle: the decoded edge is found to within one pixel.
        grown = np.zeros_like(truth)
        grown[3:13, 5:19] = True
        assert got.foreground[truth].all() and not got.foreground[~grown].any()
        np.testing.assert_array_equal(got.input_mask, got.foreground & got.measured)

    def test_saturated_pixels_are_not_given_to_the_network(self, rng):
        model = CameraModel()
        st = np.zeros((H, W, 3, 4))
        st[8:24, 12:36, :, 0] = 0.05
        st[14:18, 22:26, :, 0] = 100.0  # saturated in every exposure
        got = capdec.decode_capture(cap.Capture(raws=simulate_capture(st, model, rng=rng), model=model))
        assert got.foreground[8, 12] and not got.measured[8, 12]
        assert not got.input_mask[8, 12]

    def test_in_memory_capture_uses_the_automatic_mask(self, synthetic):
        raws, model = synthetic
        got = capdec.decode_capture(cap.Capture(raws=raws, model=model))
        assert got.foreground_source == "auto" and got.foreground.shape == (H // 2, W // 2)


# --------------------------------------------------------------------------------------------
# mask.png: the user's object mask


def _write_mask(folder: Path, array: np.ndarray, mode: str | None = None) -> Path:
    img = Image.fromarray(array) if mode is None else Image.fromarray(array).convert(mode)
    img.save(folder / capdec.MASK_FILE)
    return folder / capdec.MASK_FILE


class TestMaskFile:
    @pytest.fixture
    def folder(self, tmp_path, synthetic):
        return cap.save_capture(tmp_path / "c", *synthetic, file_format="png")

    @staticmethod
    def _shape_mask(h: int, w: int) -> np.ndarray:
        m = np.zeros((h, w), bool)
        m[2 : h - 3, 3 : w // 2] = True
        m[h // 2, w - 4] = True  # an isolated pixel: the file is used exactly, no clean-up
        return m

    @pytest.mark.parametrize("depth", ["8-bit", "16-bit", "bilevel"])
    def test_decoded_grid_mask_is_used_exactly(self, folder, depth):
        m = self._shape_mask(H // 2, W // 2)
        if depth == "8-bit":
            path = _write_mask(folder, np.where(m, 255, 0).astype(np.uint8))
        elif depth == "16-bit":
            path = _write_mask(folder, np.where(m, 1, 0).astype(np.uint16))  # any nonzero value
        else:
            path = _write_mask(folder, np.where(m, 255, 0).astype(np.uint8), "1")
        got = capdec.decode_capture(folder)
        np.testing.assert_array_equal(got.foreground, m)
        assert got.foreground_source == str(path)
        np.testing.assert_array_equal(got.input_mask, m & got.measured)

    def test_raw_grid_mask_is_reduced_by_2x2_blocks(self, folder):
        raw = np.zeros((H, W), np.uint8)
        raw[4:12, 6:14] = 255  # whole blocks: half-grid [2:6, 3:7]
        raw[20, 20] = raw[20, 21] = 255  # two of four: object
        raw[24, 24] = 255  # one of four: not object
        _write_mask(folder, raw)
        expected = np.zeros((H // 2, W // 2), bool)
        expected[2:6, 3:7] = True
        expected[10, 10] = True
        np.testing.assert_array_equal(capdec.decode_capture(folder).foreground, expected)
        # On the full grid the raw-size mask is the decoded size: used as it is.
        np.testing.assert_array_equal(capdec.decode_capture(folder, grid="full").foreground, raw > 0)

    def test_example_capture_with_its_truth_as_mask(self, tmp_path):
        truth = np.load(REPO / "examples" / "capture_truth.npz")["mask"].astype(bool)
        folder = tmp_path / "capture"
        shutil.copytree(REPO / "examples" / "capture", folder)
        _write_mask(folder, np.where(truth, 255, 0).astype(np.uint8))
        np.testing.assert_array_equal(capdec.decode_capture(folder).foreground, truth)

    @pytest.mark.parametrize(
        ("write", "match"),
        [
            (lambda f: _write_mask(f, np.zeros((H // 2, W // 2, 3), np.uint8)), "got mode 'RGB'"),
            (lambda f: _write_mask(f, np.zeros((H // 2, W // 2), np.uint8), "LA"), "got mode 'LA'"),
            (lambda f: _write_mask(f, np.zeros((H // 2, W // 2), np.uint8), "P"), "got mode 'P'"),
            (lambda f: _write_mask(f, np.full((H // 2, W // 2 + 1), 255, np.uint8)), "matches neither"),
            (lambda f: _write_mask(f, np.zeros((H // 2, W // 2), np.uint8)), "no object pixel"),
            (lambda f: (f / capdec.MASK_FILE).write_bytes(b"not a png"), "not a readable PNG"),
            (lambda f: _truncate(_write_mask(f, np.full((H, W), 255, np.uint8))), "cannot read mask image"),
        ],
        ids=["RGB", "LA", "palette", "wrong size", "empty", "not an image", "truncated"],
    )
    def test_bad_mask_files(self, folder, write, match):
        write(folder)
        with pytest.raises(ValueError, match=match) as info:
            capdec.decode_capture(folder)
        message = str(info.value)
        assert "\n" not in message and message.startswith(str(folder / capdec.MASK_FILE))

    def test_load_mask_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="mask file does not exist"):
            capdec.load_mask(tmp_path / capdec.MASK_FILE, (4, 4), (8, 8))


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


# --------------------------------------------------------------------------------------------
# Errors on load


@pytest.fixture
def saved(tmp_path, synthetic):
    """A valid .npy capture folder and its raws."""
    raws, model = synthetic
    return cap.save_capture(tmp_path / "c", raws, model, file_format="npy"), raws


def _replace_raw(folder: Path, k: int, array: np.ndarray) -> None:
    np.save(folder / _read_json(folder)["raw_files"][k], array)


def _replace_raw_png(folder: Path, k: int, img: Image.Image, suffix: str = ".png") -> None:
    name = _read_json(folder)["raw_files"][k].replace(".npy", suffix).replace(".png", suffix)
    img.save(folder / name)
    meta = _read_json(folder)
    meta["raw_files"][k] = name
    _write_json(folder, meta)


def _truncate_png(folder: Path) -> None:
    frame = np.load(folder / "raw_0010.0ms.npy")
    buf = folder / "full.png"
    Image.fromarray(frame).save(buf)
    data = buf.read_bytes()
    buf.unlink()
    (folder / "raw_0010.0ms.png").write_bytes(data[: len(data) // 2])
    meta = _read_json(folder)
    meta["raw_files"][0] = "raw_0010.0ms.png"
    _write_json(folder, meta)


LOAD_ERRORS = {
    # name: (mutation of a valid folder, exception, match)
    "missing capture.json": (lambda f, r: (f / "capture.json").unlink(), FileNotFoundError, r"capture\.json"),
    "invalid JSON": (lambda f, r: _write_json(f, '{"format": '), ValueError, r"capture\.json: invalid JSON"),
    "JSON not an object": (lambda f, r: _write_json(f, "[1, 2]"), ValueError, "JSON object"),
    "wrong format": (lambda f, r: _edit_json(f, format="pdir-capture/9"), ValueError, "unsupported format"),
    "no format": (lambda f, r: _edit_json(f, format=None), ValueError, "unsupported format None"),
    "missing exposures": (
        lambda f, r: _write_json(f, {"format": cap.CAPTURE_FORMAT, "raw_files": ["a.npy"]}),
        ValueError,
        "missing required key 'exposures_s'",
    ),
    "missing raw file": (lambda f, r: (f / "raw_0020.0ms.npy").unlink(), FileNotFoundError, r"raw_0020\.0ms\.npy"),
    "length mismatch": (
        lambda f, r: _edit_json(f, exposures_s=[0.01, 0.02, 0.1]),
        ValueError,
        "3 exposures_s but 4 raw_files",
    ),
    "no exposures": (lambda f, r: _edit_json(f, exposures_s=[], raw_files=[]), ValueError, "no exposures"),
    "zero exposure": (
        lambda f, r: _edit_json(f, exposures_s=[0.0, 0.02, 0.1, 0.2]),
        ValueError,
        r"exposures_s entry 0 s is outside the valid range \[1e-07, 10000\] s",
    ),
    "negative exposure": (
        lambda f, r: _edit_json(f, exposures_s=[-0.01, 0.02, 0.1, 0.2]),
        ValueError,
        "exposures_s entry -0.01 s is outside the valid range",
    ),
    "NaN exposure": (
        lambda f, r: _write_json(f, (f / "capture.json").read_text().replace("0.02,", "NaN,", 1)),
        ValueError,
        "exposures_s entry nan s is outside the valid range",
    ),
    "infinite exposure": (
        lambda f, r: _write_json(f, (f / "capture.json").read_text().replace("0.02,", "Infinity,", 1)),
        ValueError,
        "exposures_s entry inf s is outside the valid range",
    ),
    "tiny exposure": (
        lambda f, r: _edit_json(f, exposures_s=[1e-300, 0.02, 0.1, 0.2]),
        ValueError,
        "exposures_s entry 1e-300 s is outside the valid range",
    ),
    "huge exposure": (
        lambda f, r: _edit_json(f, exposures_s=[0.01, 0.02, 0.1, 1e300]),
        ValueError,
        "exposures_s entry 1e[+]300 s is outside the valid range",
    ),
    "exposure not a number": (
        lambda f, r: _edit_json(f, exposures_s=["10ms", 0.02, 0.1, 0.2]),
        ValueError,
        "must be a number",
    ),
    "raw path escapes folder": (
        lambda f, r: _edit_json(f, raw_files=["../x.npy", "b.npy", "c.npy", "d.npy"]),
        ValueError,
        "plain file names",
    ),
    "raw listed twice": (
        lambda f, r: _edit_json(f, raw_files=["raw_0010.0ms.npy"] * 2 + ["raw_0100.0ms.npy", "raw_0200.0ms.npy"]),
        ValueError,
        "more than once",
    ),
    "unsupported raw type": (
        lambda f, r: _edit_json(f, raw_files=["a.jpg", "b.npy", "c.npy", "d.npy"]),
        ValueError,
        r"a\.jpg: unsupported raw file type",
    ),
    "NaN in float raw": (
        lambda f, r: _replace_raw(f, 1, np.where(np.eye(H, W) > 0, np.nan, r[1]).astype(np.float32)),
        ValueError,
        r"raw_0020\.0ms\.npy: NaN in raw",
    ),
    "Inf in float raw": (
        lambda f, r: _replace_raw(f, 1, np.where(np.eye(H, W) > 0, np.inf, r[1])),
        ValueError,
        "Inf in raw",
    ),
    "fractional float raw": (lambda f, r: _replace_raw(f, 1, r[1] + 0.25), ValueError, "whole DN"),
    "complex raw": (lambda f, r: _replace_raw(f, 1, r[1].astype(np.complex64)), ValueError, "dtype must be an integer"),
    "bool raw": (lambda f, r: _replace_raw(f, 1, r[1] > 100), ValueError, "dtype must be an integer"),
    "int32 above uint16": (
        lambda f, r: _replace_raw(f, 1, r[1].astype(np.int32) + 70000),
        ValueError,
        r"do not fit uint16",
    ),
    "negative int raw": (lambda f, r: _replace_raw(f, 1, r[1].astype(np.int16) - 100), ValueError, "do not fit uint16"),
    "object array (pickle)": (
        lambda f, r: np.save(f / "raw_0020.0ms.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True),
        ValueError,
        r"raw_0020\.0ms\.npy: not a readable \.npy",
    ),
    "truncated npy": (
        lambda f, r: (f / "raw_0020.0ms.npy").write_bytes((f / "raw_0020.0ms.npy").read_bytes()[:300]),
        ValueError,
        r"raw_0020\.0ms\.npy: not a readable \.npy",
    ),
    "shapes differ": (lambda f, r: _replace_raw(f, 2, r[2][:, :-4]), ValueError, r"raw_0100\.0ms\.npy: raw shape"),
    "3-D raw": (lambda f, r: _replace_raw(f, 1, np.stack([r[1]] * 3, axis=-1)), ValueError, "2-D"),
    "size not a multiple of 4": (lambda f, r: _replace_raw(f, 1, r[1][:-2]), ValueError, "multiple of 4"),
    "too small": (lambda f, r: _replace_raw(f, 1, r[1][:4, :4]), ValueError, "at least 8x8"),
    "colour PNG": (
        lambda f, r: _replace_raw_png(f, 0, Image.fromarray(np.zeros((H, W, 3), np.uint8))),
        ValueError,
        r"raw_0010\.0ms\.png: colour image \(mode 'RGB', 3 channels\)",
    ),
    "8-bit PNG raw (a photo)": (
        lambda f, r: _replace_raw_png(f, 0, Image.fromarray((r[0] // 16).astype(np.uint8))),
        ValueError,
        r"raw_0010\.0ms\.png: raw is 8-bit \(an 8-bit greyscale image \(mode 'L'\)\) but the capture is 12-bit",
    ),
    "8-bit TIFF raw": (
        lambda f, r: _replace_raw_png(f, 0, Image.fromarray((r[0] // 16).astype(np.uint8)), ".tiff"),
        ValueError,
        r"raw_0010\.0ms\.tiff: raw is 8-bit .* but the capture is 12-bit",
    ),
    "uint8 npy raw": (
        lambda f, r: _replace_raw(f, 1, (r[1] // 16).astype(np.uint8)),
        ValueError,
        r"raw_0020\.0ms\.npy: raw is 8-bit \(a uint8 array\) but the capture is 12-bit",
    ),
    "int8 npy raw": (
        lambda f, r: _replace_raw(f, 1, np.zeros((H, W), np.int8)),
        ValueError,
        r"raw_0020\.0ms\.npy: raw is 8-bit \(a int8 array\)",
    ),
    "float TIFF": (
        lambda f, r: _replace_raw_png(f, 0, Image.fromarray(r[0].astype(np.float32)), ".tiff"),
        ValueError,
        "mode 'F' is not an integer grayscale mode",
    ),
    "truncated PNG": (lambda f, r: _truncate_png(f), ValueError, r"raw_0010\.0ms\.png: cannot read image"),
    "not an image": (
        lambda f, r: _replace_raw_png(f, 0, Image.new("L", (8, 8))) or (f / "raw_0010.0ms.png").write_text("hello"),
        ValueError,
        "not a readable PNG/TIFF image",
    ),
    "value above white level": (
        lambda f, r: _replace_raw(f, 3, np.full((H, W), 4096, np.uint16)),
        ValueError,
        r"raw_0200\.0ms\.npy: raw value 4096 above white_level 4095",
    ),
    "black level at white level": (
        lambda f, r: _edit_json(f, black_level=4095),
        ValueError,
        "black_level 4095 must be below the saturation threshold",
    ),
    "white level not 2**bits - 1": (
        lambda f, r: _edit_json(f, white_level=65520, bits=None) or _drop_key(f, "bits"),
        ValueError,
        r"white_level 65520 is not 2\*\*bits - 1",
    ),
    "white level and bits disagree": (
        lambda f, r: _edit_json(f, white_level=1023, bits=12),
        ValueError,
        "white_level 1023 does not match bits 12",
    ),
    "unknown camera model key": (
        lambda f, r: _edit_json(f, camera_model={"qwp_angel": 0.1}),
        ValueError,
        "invalid camera model .*unknown camera model keys",
    ),
    "bad camera model value": (
        lambda f, r: _edit_json(f, camera_model={"extinction_ratio": [0.5, 1, 1]}),
        ValueError,
        "invalid camera model .*extinction_ratio",
    ),
    "files out of order": (
        lambda f, r: _edit_json(
            f, raw_files=["raw_0200.0ms.npy", "raw_0020.0ms.npy", "raw_0100.0ms.npy", "raw_0010.0ms.npy"]
        ),
        ValueError,
        "out of order",
    ),
}


def _png_declaring(path: Path, width: int, height: int, bit_depth: int = 16) -> None:
    """A grey PNG whose header declares ``width x height`` pixels, with (almost) no pixel data."""

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def _raw_declaring(folder: Path, width: int, height: int) -> None:
    """Replace the first raw by a PNG declaring ``width x height`` pixels."""
    meta = _read_json(folder)
    meta["raw_files"][0] = "bomb.png"
    _write_json(folder, meta)
    _png_declaring(folder / "bomb.png", width, height)


def _sensor_value(folder: Path, key: str, text: str) -> None:
    """Set ``camera_model.sensor.<key>`` to a literal JSON token (``Infinity``, ``1e-320``, a 400-digit integer)."""
    meta = _read_json(folder)
    meta["camera_model"]["sensor"][key] = "__VALUE__"
    meta.pop(key, None)  # a top-level override (black_level) would win
    _write_json(folder, json.dumps(meta).replace('"__VALUE__"', text))


def _camera_value(folder: Path, key: str, text: str) -> None:
    meta = _read_json(folder)
    meta["camera_model"][key] = "__VALUE__"
    _write_json(folder, json.dumps(meta).replace('"__VALUE__"', text))


# Found by fuzzing 252 malformed capture folders: each used to end in a traceback (DecompressionBombError,
# OverflowError, RecursionError), in an error naming no field ("SVD did not converge", "sigma must be positive and
# finite") or in a silent success with all-zero maps.
LOAD_ERRORS.update(
    {
        "raw declaring 200 M pixels": (
            lambda f, r: _raw_declaring(f, 20000, 10000),
            ValueError,
            r"bomb\.png: raw image too large to read \(Image size \(200000000 pixels\) exceeds limit",
        ),
        "TIFF raw declaring 400 M pixels": (
            lambda f, r: _replace_raw_png(f, 0, Image.fromarray(np.zeros((8, 8), "<u2")), ".tif") or _tiff_declaring(f),
            ValueError,
            r"raw_0010\.0ms\.tif: raw image too large to read",
        ),
        "integer too large for a float": (
            lambda f, r: _write_json(
                f, (f / "capture.json").read_text().replace('"black_level": 64.0', '"black_level": 1' + "0" * 400)
            ),
            ValueError,
            r"black_level 10000000000000000000\.\.\. is too large for a floating-point number",
        ),
        "exposure too large for a float": (
            lambda f, r: _write_json(f, (f / "capture.json").read_text().replace("0.01,", "1" + "0" * 400 + ",", 1)),
            ValueError,
            "exposures_s entry 10000000000000000000... is too large",
        ),
        "camera model integer too large for a float": (
            lambda f, r: _sensor_value(f, "gain", "1" + "0" * 400),
            ValueError,
            r"invalid camera model \(SensorParams.gain must be in \[0.0001, 10000\]; got inf\)",
        ),
        "integer of 5000 digits": (
            lambda f, r: _write_json(
                f, (f / "capture.json").read_text().replace('"bits": 12', '"bits": ' + "9" * 5000)
            ),
            ValueError,
            r"capture\.json: invalid JSON \(Exceeds the limit",
        ),
        "nested 100000 levels": (
            lambda f, r: _write_json(f, "[" * 100_000 + "]" * 100_000),
            ValueError,
            r"capture\.json: invalid JSON \(nested too deeply\)",
        ),
        "nested 100000 levels in a key": (
            lambda f, r: _write_json(
                f, (f / "capture.json").read_text().rstrip()[:-1] + ', "x": ' + "[" * 100_000 + "]" * 100_000 + "}"
            ),
            ValueError,
            r"capture\.json: invalid JSON \(nested too deeply\)",
        ),
        "gain 1e-320": (lambda f, r: _sensor_value(f, "gain", "1e-320"), ValueError, "SensorParams.gain must be in"),
        "gain 1e308": (lambda f, r: _sensor_value(f, "gain", "1e308"), ValueError, "SensorParams.gain must be in"),
        "gain inf": (lambda f, r: _sensor_value(f, "gain", "Infinity"), ValueError, "SensorParams.gain must be in"),
        "saturation 1e-320": (
            lambda f, r: _sensor_value(f, "saturation", "1e-320"),
            ValueError,
            "SensorParams.saturation must be in",
        ),
        "black level above the saturation threshold": (
            lambda f, r: _edit_json(f, black_level=3900.0),
            ValueError,
            "black_level 3900 must be below the saturation threshold",
        ),
        "extinction ratio 1": (
            lambda f, r: _camera_value(f, "extinction_ratio", "[1, 1, 1]"),
            ValueError,
            r"invalid camera model \(extinction_ratio\[R\] must be in \[2, inf\]; got 1\)",
        ),
        "analyzer transmittance 1e300": (
            lambda f, r: _camera_value(f, "analyzer_transmittance", "1e300"),
            ValueError,
            r"analyzer_transmittance must be in \[0.001, 1\]; got 1e\+300",
        ),
        "QWP angle inf": (
            lambda f, r: _camera_value(f, "qwp_angle", "Infinity"),
            ValueError,
            r"qwp_angle \(radians\) must be in \[-6.28319, 6.28319\]; got inf",
        ),
        "QWP angle not a number": (
            lambda f, r: _camera_value(f, "qwp_angle", '"x"'),
            ValueError,
            "qwp_angle .* must be a number",
        ),
        "bits 12.5": (
            lambda f, r: _drop_top(f, "white_level") or _sensor_value(f, "bits", "12.5"),
            ValueError,
            "SensorParams.bits must be an integer",
        ),
        "raw file name too long": (
            lambda f, r: _edit_json(f, raw_files=["r" * 300 + ".npy", *_read_json(f)["raw_files"][1:]]),
            ValueError,
            "raw_files entries must be plain file names",
        ),
    }
)


def _tiff_declaring(folder: Path) -> None:
    """Patch the width and height tags of the first raw (an 8x8 TIFF) to 20000 x 20000."""
    path = folder / _read_json(folder)["raw_files"][0]
    data = bytearray(path.read_bytes())
    assert data[:2] == b"II"
    ifd = struct.unpack("<I", data[4:8])[0]
    for i in range(struct.unpack("<H", data[ifd : ifd + 2])[0]):
        entry = ifd + 2 + 12 * i
        tag, kind = struct.unpack("<HH", data[entry : entry + 4])
        if tag in (256, 257):  # ImageWidth, ImageLength
            data[entry + 8 : entry + 12] = struct.pack("<HH", 20000, 0) if kind == 3 else struct.pack("<I", 20000)
    path.write_bytes(bytes(data))


def _drop_top(folder: Path, *keys: str) -> None:
    meta = _read_json(folder)
    for key in keys:
        meta.pop(key, None)
    _write_json(folder, meta)


def _drop_key(folder: Path, key: str) -> None:
    meta = _read_json(folder)
    meta.pop(key, None)
    meta["camera_model"]["sensor"].pop("bits", None)
    _write_json(folder, meta)


class TestLoadErrors:
    @pytest.mark.parametrize("case", list(LOAD_ERRORS), ids=list(LOAD_ERRORS))
    def test_raises(self, saved, case):
        folder, raws = saved
        mutate, exc, match = LOAD_ERRORS[case]
        mutate(folder, raws)
        with pytest.raises(exc, match=match) as info:
            cap.load_capture(folder)
        message = str(info.value)
        assert "\n" not in message
        assert str(folder) in message  # every message names the folder or a file in it

    def test_missing_folder(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="capture folder does not exist"):
            cap.load_capture(tmp_path / "nope")

    def test_folder_is_a_file(self, tmp_path):
        (tmp_path / "f").write_text("x")
        with pytest.raises(NotADirectoryError, match="not a folder"):
            cap.load_capture(tmp_path / "f")

    def test_8_bit_raw_accepted_for_an_8_bit_sensor(self, tmp_path, rng):
        model = CameraModel(sensor=SensorParams(bits=8, black_level=4.0, electrons_per_unit=5e4))
        raws = simulate_capture(_stokes_scene(rng), model, rng=rng)
        folder = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        for k in range(4):
            _replace_raw(folder, k, raws[k].astype(np.uint8))
        np.testing.assert_array_equal(cap.load_capture(folder).raws, raws)

    def test_dark_frames_are_not_judged_for_order(self, saved):
        folder, raws = saved
        black = np.full((H, W), 64, np.uint16)
        for k in range(4):
            _replace_raw(folder, k, black + (k % 2))
        assert cap.load_capture(folder).raws.shape == (4, H, W)


# --------------------------------------------------------------------------------------------
# Errors on save, validate_capture, atomicity


class TestSaveErrors:
    def test_bad_file_format(self, tmp_path, synthetic):
        with pytest.raises(ValueError, match="file_format must be one of"):
            cap.save_capture(tmp_path / "c", *synthetic, file_format="jpg")

    def test_extra_uses_reserved_key(self, tmp_path, synthetic):
        with pytest.raises(ValueError, match=r"extra may not set the capture format keys \['exposures_s'\]"):
            cap.save_capture(tmp_path / "c", *synthetic, extra={"exposures_s": [1.0]})

    @pytest.mark.parametrize("extra", [{"x": float("nan")}, {"x": object()}])
    def test_extra_not_json(self, tmp_path, synthetic, extra):
        with pytest.raises(ValueError, match="not valid JSON"):
            cap.save_capture(tmp_path / "c", *synthetic, extra=extra)
        assert not (tmp_path / "c").exists()

    def test_wrong_number_of_raws(self, tmp_path, synthetic):
        raws, model = synthetic
        with pytest.raises(ValueError, match="3 raw frames for 4 exposure times"):
            cap.save_capture(tmp_path / "c", raws[:3], model)

    def test_above_white_level(self, tmp_path, synthetic):
        raws, model = synthetic
        with pytest.raises(ValueError, match="above white_level 4095"):
            cap.save_capture(tmp_path / "c", raws.astype(np.int32) * 16, model)

    def test_raws_out_of_order(self, tmp_path, synthetic):
        raws, model = synthetic
        with pytest.raises(ValueError, match="out of order"):
            cap.save_capture(tmp_path / "c", raws[::-1], model)

    def test_target_is_a_file(self, tmp_path, synthetic):
        (tmp_path / "c").write_text("x")
        with pytest.raises(FileExistsError, match="not a folder"):
            cap.save_capture(tmp_path / "c", *synthetic, overwrite=True)

    def test_missing_parent(self, tmp_path, synthetic):
        with pytest.raises(FileNotFoundError, match="parent folder"):
            cap.save_capture(tmp_path / "a" / "c", *synthetic)


class TestValidateCapture:
    def test_valid(self, synthetic):
        raws, model = synthetic
        cap.validate_capture(cap.Capture(raws=raws, model=model))

    @pytest.mark.parametrize(
        ("change", "match"),
        [
            (lambda r, m: (r[0], m), r"raws must have shape \(E, H, W\)"),
            (lambda r, m: (r[:2], m), "2 raw frames for 4 exposure times"),
            (lambda r, m: (r[:, :30], m), "multiple of 4"),
            (lambda r, m: (r.astype(np.float64) + 0.5, m), "whole DN"),
        ],
    )
    def test_invalid(self, synthetic, change, match):
        raws, model = change(*synthetic)
        with pytest.raises(ValueError, match=match):
            cap.validate_capture(cap.Capture(raws=raws, model=model))

    def test_decode_capture_validates_in_memory_capture(self, synthetic):
        raws, model = synthetic
        with pytest.raises(ValueError, match="above white_level"):
            capdec.decode_capture(cap.Capture(raws=raws.astype(np.int32) + 8000, model=model))


class TestAtomicSave:
    @staticmethod
    def _failing_writer(monkeypatch, after: int = 1):
        real = cap.write_raw
        calls = []

        def writer(path, raw, file_format):
            if len(calls) >= after:
                raise OSError("disk full (simulated)")
            calls.append(path)
            real(path, raw, file_format)

        monkeypatch.setattr(cap, "write_raw", writer)
        return calls

    @pytest.mark.parametrize("file_format", ["png", "npy"])
    def test_failure_leaves_nothing(self, tmp_path, monkeypatch, synthetic, file_format):
        calls = self._failing_writer(monkeypatch)
        with pytest.raises(OSError, match="disk full"):
            cap.save_capture(tmp_path / "c", *synthetic, file_format=file_format)
        assert len(calls) == 1 and calls[0].parent != tmp_path / "c"  # wrote into a temp folder
        assert list(tmp_path.iterdir()) == []  # neither the target nor a temp folder

    def test_failure_keeps_previous_capture(self, tmp_path, monkeypatch, synthetic):
        raws, model = synthetic
        target = cap.save_capture(tmp_path / "c", raws, model, file_format="npy")
        before = sorted((p.name, p.read_bytes()) for p in target.iterdir())
        self._failing_writer(monkeypatch, after=2)
        with pytest.raises(OSError, match="disk full"):
            cap.save_capture(target, raws, model, file_format="png", overwrite=True)
        assert sorted((p.name, p.read_bytes()) for p in target.iterdir()) == before
        assert [p.name for p in tmp_path.iterdir()] == ["c"]

    def test_interrupt_leaves_nothing(self, tmp_path, monkeypatch, synthetic):
        def interrupted(path, raw, file_format):
            raise KeyboardInterrupt

        monkeypatch.setattr(cap, "write_raw", interrupted)
        with pytest.raises(KeyboardInterrupt):
            cap.save_capture(tmp_path / "c", *synthetic)
        assert list(tmp_path.iterdir()) == []


class TestLargeImages:
    def test_raw_declaring_100m_pixels_warns_nothing(self, saved):
        # Between 89 M and 179 M declared pixels Pillow only warns (DecompressionBombWarning), and that warning was
        # printed before the error line. A header that merely claims the size fails on reading, without a warning.
        folder, _ = saved
        _raw_declaring(folder, 10000, 10000)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(ValueError, match=r"bomb\.png: cannot read image"):
                cap.load_capture(folder)
        assert [str(w.message) for w in caught] == []

    def test_mask_declaring_200m_pixels(self, saved):
        folder, _ = saved
        _png_declaring(folder / capdec.MASK_FILE, 20000, 10000, bit_depth=8)
        with pytest.raises(ValueError, match=r"mask\.png: mask image too large to read"):
            capdec.decode_capture(folder)


def _bracket(folder_root: Path, raws: np.ndarray, model: CameraModel, name: str = "c") -> tuple[cap.Capture, Path]:
    folder = cap.save_capture(folder_root / name, raws, model, file_format="npy")
    return cap.load_capture(folder), folder


class TestCheckUsable:
    """Captures that decode to nothing usable are refused with the reason; one without an object warns."""

    def test_good_capture_passes_silently(self, tmp_path, disc_capture):
        capture, _ = _bracket(tmp_path, *disc_capture)  # an object on a dark background, no dark frames
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            capdec.check_usable(capdec.decode_capture(capture), capture, need_object=True)

    @pytest.mark.parametrize(
        ("fill", "match"),
        [
            (
                lambda r, m: np.full_like(r, int(m.sensor.black_level)),
                "every raw value is at or below black_level 64 DN",
            ),
            (lambda r, m: np.zeros_like(r), "every raw value is at or below black_level 64 DN"),
            (
                lambda r, m: np.full_like(r, m.sensor.white_level),
                r"every pixel is saturated \(at or above 3685.5 DN, saturation x white_level\) in every exposure",
            ),
            (
                lambda r, m: np.concatenate([np.full_like(r[:2], 64), np.full_like(r[2:], m.sensor.white_level)]),
                "no pixel has signal above black_level 64 DN in an exposure where it is below saturation",
            ),
        ],
        ids=["all dark", "all zero", "all saturated", "dark then saturated"],
    )
    def test_nothing_usable_is_refused(self, tmp_path, synthetic, fill, match):
        raws, model = synthetic
        capture, folder = _bracket(tmp_path, fill(raws, model), model)
        decoded = capdec.decode_capture(capture)
        assert not decoded.mask.any() and not decoded.maps.any()  # what used to be written without a word
        with pytest.raises(ValueError, match=match) as info:
            capdec.check_usable(decoded, capture)
        assert str(info.value).startswith(f"{folder}: nothing usable: ") and "\n" not in str(info.value)

    def test_black_level_at_the_data(self, tmp_path, rng):
        # A dim scene whose brightest raw value becomes the black level: every pixel at or below it.
        model = _calibrated_model(sensor=SensorParams(black_level=64.0, bits=12))
        raws = simulate_capture(0.01 * _stokes_scene(rng), model, rng=rng)
        model = model.replace(sensor=SensorParams(black_level=float(raws.max()), bits=12))
        capture, _ = _bracket(tmp_path, raws, model)
        with pytest.raises(ValueError, match=f"at or below black_level {raws.max()} DN"):
            capdec.check_usable(capdec.decode_capture(capture), capture)

    def test_noise_only_warns_or_refuses(self, tmp_path, rng):
        # A dark capture with read noise: about half the background passes the decoder's mask, but no object
        # stands out from the noise floor. decode.py warns (one line); inference has nothing to reconstruct.
        model = _calibrated_model()
        capture, folder = _bracket(tmp_path, simulate_capture(np.zeros((H, W, 3, 4)), model, rng=rng), model)
        decoded = capdec.decode_capture(capture)
        assert decoded.mask.any() and not decoded.input_mask.any()
        with pytest.warns(capdec.CaptureWarning, match="no object stands out from the background") as record:
            capdec.check_usable(decoded, capture)
        assert len(record) == 1
        with pytest.raises(ValueError, match=f"{folder}: nothing to reconstruct: no object stands out"):
            capdec.check_usable(decoded, capture, need_object=True)

    def test_mask_file_outside_the_measured_pixels(self, tmp_path, synthetic):
        raws, model = synthetic
        raws = raws.copy()
        raws[:, :, : W // 2] = model.sensor.white_level  # left half saturated everywhere
        capture, folder = _bracket(tmp_path, raws, model)
        mask = np.zeros((H // 2, W // 2), np.uint8)
        mask[:, :4] = 255
        Image.fromarray(mask).save(folder / capdec.MASK_FILE)
        decoded = capdec.decode_capture(capture)
        with pytest.raises(ValueError, match=r"mask\.png covers no measured pixel"):
            capdec.check_usable(decoded, capture, need_object=True)


# ------------------------------------------------------------------------------------------------
# CaptureMeta: radiometry and geometry parsed once, at load time


def test_capture_meta_is_parsed_at_load_and_without_the_raws(tmp_path):
    model = CameraModel(exposures=(0.01, 0.1))
    raws = simulate_capture(np.full((8, 12, 3, 4), 0.0) + [0.1, 0, 0, 0], model, noise=False)
    k_raw = [[50.0, 0.0, 13.0], [0.0, 52.0, 7.0], [0.0, 0.0, 1.0]]
    extra = {"rig": {"display": {"radiance": 0.5}}, "intrinsics": k_raw, "distance_m": 0.6}
    folder = cap.save_capture(tmp_path / "c", raws, model, extra=extra)
    meta = cap.load_capture(folder).meta
    assert (meta.radiance, meta.distance_m, meta.rig.display.radiance) == (0.5, 0.6, 0.5)
    # the half grid: pixel (i, j) is raw block (2i..2i+1, 2j..2j+1), its centre raw (2j + 1, 2i + 1)
    k = meta.grid_intrinsics((16, 24), (8, 12))
    raw_uv = np.array(k_raw) @ [0.1, -0.2, 1.0]
    np.testing.assert_allclose(k @ [0.1, -0.2, 1.0], [raw_uv[0] / 2, raw_uv[1] / 2, 1.0], rtol=1e-12)
    for name in cap.load_capture(folder).raw_files:
        (folder / name).unlink()  # the light reader never opens them
    assert cap.read_capture_meta(folder).intrinsics.tolist() == k_raw
    # Without intrinsics: the rig camera's focal length, principal point at the raw image's centre.
    plain = cap.read_capture_meta(cap.save_capture(tmp_path / "p", raws, model, extra={"radiometry": "relative"}))
    assert plain.radiance is None and plain.distance_m is None
    f = plain.rig.camera.focal_length_px
    np.testing.assert_array_equal(plain.raw_intrinsics((16, 24)), [[f, 0, 12], [0, f, 8], [0, 0, 1]])


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ({"intrinsics": [[1, 0, 0], [0, 1, 0]]}, r"intrinsics must be a finite 3x3 matrix, got shape \(2, 3\)"),
        ({"intrinsics": [[1, 0, 0], [0, 1, "x"], [0, 0, 1]]}, "intrinsics must be a finite 3x3 matrix"),
        ({"distance_m": -0.5}, r"distance_m must be > 0, got -0.5"),
        ({"distance_m": "0.5"}, "distance_m must be a number"),
        ({"rig": {"display": {"radiance": 0}}}, "invalid rig: display.radiance must be > 0"),
        ({"radiometry": "absolute"}, r"radiometry must be one of \['calibrated', 'relative'\]"),
    ],
    ids=["2x3 intrinsics", "string in intrinsics", "negative distance", "distance as text", "bad rig", "radiometry"],
)
def test_bad_geometry_or_radiometry_fails_at_load_naming_the_file(tmp_path, extra, match):
    model = CameraModel(exposures=(0.01, 0.1))
    raws = simulate_capture(np.full((8, 8, 3, 4), 0.0) + [0.1, 0, 0, 0], model, noise=False)
    folder = cap.save_capture(tmp_path / "c", raws, model, extra=extra)
    for load in (cap.load_capture, cap.read_capture_meta):
        with pytest.raises(ValueError, match=rf"^{re.escape(str(folder / 'capture.json'))}: {match}"):
            load(folder)
