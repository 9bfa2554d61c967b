"""EXR I/O on real OpenEXR files: exact round trips, errors, atomic writes, headers."""

import json
import os
import re

import numpy as np
import OpenEXR
import pytest

from pbrdf.io.exr import (
    COMPRESSIONS,
    MissingChannelError,
    exr_channel_names,
    read_exr,
    read_exr_header,
    split_channels,
    stack_channels,
    write_exr,
)


def _bits(a):
    """Bit patterns, so that -0.0 vs 0.0 and NaN payloads count as differences."""
    return np.ascontiguousarray(a).view(np.uint16 if a.dtype == np.float16 else np.uint32)


@pytest.fixture
def channels(rng):
    h, w = 7, 5
    special = np.array([0.0, -0.0, 1e-45, -1e-38, 3.4e38, -1.0, 0.5], dtype=np.float32)  # denormal, extremes
    a = rng.normal(size=(h, w)).astype(np.float32)
    a[:, 0] = special
    return {
        "maps.R_unpol": a,
        "normal.X": rng.uniform(-1, 1, (h, w)).astype(np.float32),
        "stokes.R.S0": rng.uniform(0, 10, (h, w)).astype(np.float32),
        "depth.Z": rng.uniform(0.1, 3, (h, w)).astype(np.float32),
    }


def test_float32_round_trip_is_exact_and_names_are_kept(tmp_path, channels):
    path = write_exr(tmp_path / "a.exr", channels)
    assert path == tmp_path / "a.exr"
    back = read_exr(path)
    assert sorted(back) == sorted(channels)
    assert exr_channel_names(path) == sorted(channels)  # OpenEXR stores channels sorted by name
    for name, arr in channels.items():
        assert back[name].dtype == np.float32 and back[name].shape == arr.shape
        np.testing.assert_array_equal(_bits(back[name]), _bits(arr))
        np.testing.assert_allclose(back[name], arr, rtol=0, atol=0)
    assert os.listdir(tmp_path) == ["a.exr"]  # no temporary file left


def test_half_storage_equals_float16_cast(tmp_path, channels):
    small = {k: np.clip(v, -1000, 1000) for k, v in channels.items()}  # within the float16 range
    path = write_exr(tmp_path / "h.exr", small, half=True)
    for name, arr in read_exr(path).items():
        assert arr.dtype == np.float32
        np.testing.assert_array_equal(arr, small[name].astype(np.float16).astype(np.float32))

    path = write_exr(tmp_path / "h2.exr", small, half={"normal.X"})
    back = read_exr(path)
    np.testing.assert_array_equal(back["normal.X"], small["normal.X"].astype(np.float16).astype(np.float32))
    np.testing.assert_array_equal(back["maps.R_unpol"], small["maps.R_unpol"])  # still float32

    with pytest.raises(ValueError, match="half names channels that are not written"):
        write_exr(tmp_path / "x.exr", channels, half={"nope"})
    # 3.4e38 overflows half: refused (an Inf would be written otherwise)
    with pytest.raises(ValueError, match=r"'maps.R_unpol': values beyond the float16 range"):
        write_exr(tmp_path / "x.exr", channels, half=True)


def test_integer_bool_and_float64_channels(tmp_path, rng):
    ids = rng.integers(0, 2**32, (3, 4), dtype=np.uint64)
    mask = rng.random((3, 4)) > 0.5
    f64 = rng.normal(size=(3, 4))
    back = read_exr(write_exr(tmp_path / "i.exr", {"id": ids, "mask.Y": mask, "f": f64}))
    assert back["id"].dtype == np.uint32 and back["mask.Y"].dtype == np.uint32
    np.testing.assert_array_equal(back["id"], ids)
    np.testing.assert_array_equal(back["mask.Y"], mask.astype(np.uint32))
    np.testing.assert_array_equal(back["f"], f64.astype(np.float32))  # float64 is rounded to float32
    with pytest.raises(ValueError, match="'neg'.*do not fit uint32"):
        write_exr(tmp_path / "x.exr", {"neg": np.array([[-1, 2]])})
    with pytest.raises(ValueError, match="'c'.*unsupported dtype complex"):
        write_exr(tmp_path / "x.exr", {"c": np.zeros((2, 2), complex)})
    with pytest.raises(ValueError, match="half applies to float channels only"):
        write_exr(tmp_path / "x.exr", {"id": ids}, half={"id"})


@pytest.mark.parametrize("compression", sorted(COMPRESSIONS))
def test_every_offered_compression_is_lossless(tmp_path, channels, compression):
    path = write_exr(tmp_path / "c.exr", channels, compression=compression)
    assert read_exr_header(path)["compression"] == compression
    for name, arr in read_exr(path).items():
        np.testing.assert_array_equal(_bits(arr), _bits(channels[name]))


def test_bad_arguments(tmp_path, channels):
    with pytest.raises(ValueError, match=r"channel 'b': shape \(3, 5\) differs from \(7, 5\)"):
        write_exr(tmp_path / "x.exr", {**channels, "b": np.zeros((3, 5), np.float32)})
    with pytest.raises(ValueError, match=r"channel 'v': expected a 2-D \(H, W\) array; got shape \(7, 5, 3\)"):
        write_exr(tmp_path / "x.exr", {"v": np.zeros((7, 5, 3), np.float32)})
    with pytest.raises(ValueError, match="empty image"):
        write_exr(tmp_path / "x.exr", {"v": np.zeros((0, 5), np.float32)})
    with pytest.raises(ValueError, match="non-empty dict"):
        write_exr(tmp_path / "x.exr", {})
    with pytest.raises(ValueError, match=r"unknown compression 'dwaa'; valid: \["):
        write_exr(tmp_path / "x.exr", channels, compression="dwaa")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_exr(tmp_path / "no" / "x.exr", channels)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(("value", "what"), [(np.nan, "NaN"), (np.inf, "Inf"), (-np.inf, "Inf")])
def test_nonfinite_values_are_refused(tmp_path, channels, value, what):
    bad = channels["normal.X"].copy()
    bad[2, 3] = value
    with pytest.raises(ValueError, match=rf"channel 'normal.X': {what} in 1 pixel\(s\), first at \(row 2, col 3\)"):
        write_exr(tmp_path / "x.exr", {**channels, "normal.X": bad})
    assert not (tmp_path / "x.exr").exists()
    back = read_exr(write_exr(tmp_path / "ok.exr", {"n": bad}, allow_nonfinite=True))["n"]
    np.testing.assert_array_equal(back, bad)


def _truncated(path, channels):
    write_exr(path, {k: np.tile(v, (20, 20)) for k, v in channels.items()})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _random(path, channels):
    path.write_bytes(np.random.default_rng(5).integers(0, 256, 4096, dtype=np.uint8).tobytes())


def _empty(path, channels):
    path.write_bytes(b"")


def _png(path, channels):
    from PIL import Image

    Image.fromarray(np.zeros((4, 4), np.uint8)).save(path, format="PNG")


def _magic_only(path, channels):
    path.write_bytes(b"\x76\x2f\x31\x01\x02\x00\x00\x00" + b"\x00" * 3)


@pytest.mark.parametrize("corrupt", [_truncated, _random, _empty, _png, _magic_only])
def test_corrupt_files_raise_one_line_value_error(tmp_path, channels, corrupt):
    path = tmp_path / "bad.exr"
    corrupt(path, channels)
    for read in (read_exr, read_exr_header, exr_channel_names):
        if corrupt is _truncated and read is not read_exr:
            continue  # the header of a file cut in half is intact
        with pytest.raises(ValueError, match=re.escape(f"{path}: not a readable EXR file: ")) as err:
            read(path)
        assert "\n" not in str(err.value)


def test_truncated_file_message_says_why(tmp_path, channels):
    path = tmp_path / "cut.exr"
    _truncated(path, channels)
    with pytest.raises(ValueError, match="truncated or corrupt pixel data in part 0"):
        read_exr(path)


def test_missing_file(tmp_path):
    path = tmp_path / "missing.exr"
    for read in (read_exr, read_exr_header):
        with pytest.raises(FileNotFoundError, match=re.escape(str(path))):
            read(path)


def _failing_write(fail_with):
    original = OpenEXR.File.write

    def write(self, filename):
        original(self, filename)  # a real, complete file ...
        with open(filename, "r+b") as f:  # ... cut short, as by a crash mid-write
            f.truncate(64)
        raise fail_with

    return write


@pytest.mark.parametrize(
    ("error", "expected"), [(RuntimeError("disk full"), OSError), (KeyboardInterrupt(), KeyboardInterrupt)]
)
def test_atomic_write_leaves_no_partial_file(tmp_path, channels, monkeypatch, error, expected):
    target = tmp_path / "a.exr"
    old = {"old": np.arange(6, dtype=np.float32).reshape(2, 3)}
    write_exr(target, old)
    monkeypatch.setattr(OpenEXR.File, "write", _failing_write(error))
    with pytest.raises(expected):
        write_exr(target, channels)
    with pytest.raises(expected):
        write_exr(tmp_path / "new.exr", channels)
    monkeypatch.undo()
    assert os.listdir(tmp_path) == ["a.exr"]  # neither the new target nor a temporary file
    back = read_exr(target)
    assert list(back) == ["old"]
    np.testing.assert_array_equal(back["old"], old["old"])


def test_partial_read_and_missing_channel(tmp_path, channels):
    path = write_exr(tmp_path / "a.exr", channels)
    back = read_exr(path, ["stokes.R.S0", "depth.Z"])
    assert list(back) == ["stokes.R.S0", "depth.Z"]  # requested order
    np.testing.assert_array_equal(back["depth.Z"], channels["depth.Z"])
    with pytest.raises(MissingChannelError, match=r"no channel\(s\) \['normal.Y'\]; available: \['depth.Z'") as err:
        read_exr(path, ["normal.X", "normal.Y"])
    assert isinstance(err.value, KeyError) and isinstance(err.value, ValueError)
    with pytest.raises(ValueError, match="list of names"):
        read_exr(path, "depth.Z")


def test_header_attributes_round_trip(tmp_path, channels):
    meta = {"rig": {"distance_m": 0.5, "poses": [[1, 0, 0], [0, 1, 0]]}, "name": "héllo ✓", "seed": 7}
    header = {"pdir.meta": json.dumps(meta), "pdir.count": -42, "pdir.scale": 0.5, "empty": ""}
    path = write_exr(tmp_path / "a.exr", channels, header=header)
    info = read_exr_header(path)
    assert info["attributes"] == header
    assert json.loads(info["attributes"]["pdir.meta"]) == meta
    assert (info["width"], info["height"], info["parts"]) == (5, 7, 1)
    assert info["channels"] == sorted(channels)
    assert info["compression"] == "zip"


@pytest.mark.parametrize(
    ("header", "match"),
    [
        ({"f": 0.1}, "not exactly a finite float32"),  # EXR float attributes are 32-bit
        ({"i": 2**40}, "outside int32"),  # OpenEXR would store 0
        ({"d": {"a": 1}}, "JSON string"),
        ({"b": True}, "unsupported type bool"),
        ({"compression": "zip"}, "managed by the writer"),
        ({"": "x"}, "non-empty strings"),
    ],
)
def test_bad_header_attributes(tmp_path, channels, header, match):
    with pytest.raises(ValueError, match=match):
        write_exr(tmp_path / "a.exr", channels, header=header)
    assert os.listdir(tmp_path) == []


def test_multi_part_file_like_blender_5(tmp_path):
    """Blender 5 writes multilayer EXRs as multi-part files: all parts' channels are read."""
    normal = np.arange(20, dtype=np.float32).reshape(4, 5) / 20
    depth = np.full((4, 5), 2.5, np.float32)
    parts = [
        OpenEXR.Part({}, {"Normal.X": normal.copy()}, "Normal"),
        OpenEXR.Part({}, {"Depth.V": depth.astype(np.float16)}, "Depth"),
    ]
    path = tmp_path / "multi.exr"
    OpenEXR.File(parts).write(str(path))
    back = read_exr(path)
    assert list(back) == ["Normal.X", "Depth.V"]
    np.testing.assert_array_equal(back["Normal.X"], normal)
    np.testing.assert_array_equal(back["Depth.V"], depth)
    assert read_exr_header(path)["parts"] == 2
    assert list(read_exr(path, ["Depth.V"])) == ["Depth.V"]


def test_stack_and_split_channels(rng):
    arr = rng.random((3, 4, 3)).astype(np.float32)
    ch = split_channels("normal", arr, ["X", "Y", "Z"])
    assert list(ch) == ["normal.X", "normal.Y", "normal.Z"]
    np.testing.assert_array_equal(stack_channels(ch, "normal", ["X", "Y", "Z"]), arr)
    np.testing.assert_array_equal(stack_channels(ch, "normal", ["Z", "X"]), arr[..., [2, 0]])
    assert list(split_channels("", arr, ["a", "b", "c"])) == ["a", "b", "c"]
    with pytest.raises(ValueError, match=r"normal must have shape \(H, W, 2\)"):
        split_channels("normal", arr, ["X", "Y"])
    with pytest.raises(MissingChannelError, match=r"\['normal.W'\]"):
        stack_channels(ch, "normal", ["X", "W"])


def test_split_write_read_stack(tmp_path, rng):
    stokes = rng.normal(size=(3, 4, 3, 4)).astype(np.float32)
    names = [f"{c}.S{k}" for c in "RGB" for k in range(4)]
    path = write_exr(tmp_path / "s.exr", split_channels("stokes", stokes.reshape(3, 4, 12), names))
    back = stack_channels(read_exr(path), "stokes", names).reshape(3, 4, 3, 4)
    np.testing.assert_array_equal(back, stokes)
