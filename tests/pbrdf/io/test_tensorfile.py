"""Mitsuba tensor files: bit-exact round trips, byte equality with ``mitsuba.tensor_io``, errors, atomic writes."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from pbrdf.io import tensorfile
from pbrdf.io.atomic import temporary_target
from pbrdf.io.tensorfile import read_tensor_file, write_tensor_file


def _bits(a):
    """Bit patterns, so that -0.0 vs 0.0 and NaN payloads count as differences."""
    a = np.ascontiguousarray(a)
    return a.view(f"u{a.dtype.itemsize}") if a.dtype.kind == "f" else a


@pytest.fixture
def fields(rng):
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1e-45, 3.4e38], dtype=np.float32)
    big = rng.normal(size=(300, 1000)).astype(np.float32)  # 1.2 MB: memory-mapped by default
    big[0, :7] = special
    return {
        "M": big,
        "wvls": np.array([450, 500, 550, 600, 650], dtype=np.uint16),
        "théta": rng.normal(size=(1, 9)),  # float64, non-ASCII name
        "i8": np.array([-128, 0, 127], dtype=np.int8),
        "u8": np.arange(5, dtype=np.uint8),
        "i16": np.array([-3, 4], dtype=np.int16),
        "u32": np.array([2**32 - 1], dtype=np.uint32),
        "i32": np.array([[-(2**31)]], dtype=np.int32),
        "u64": np.array([2**64 - 1], dtype=np.uint64),
        "i64": np.array([-(2**63)], dtype=np.int64),
        "f16": np.array([1.5, -0.0, 65504], dtype=np.float16),
        "scalar": np.array(3.25),  # 0-d: stored as (1,), like Mitsuba's writer
        "empty": np.zeros((0, 4), dtype=np.float32),  # last: Mitsuba's writer adds no padding for it
    }


class TestTensorFile:
    @pytest.mark.parametrize("mmap", [True, False])
    def test_round_trip_bit_exact(self, tmp_path, fields, mmap):
        path = write_tensor_file(tmp_path / "f.tensor", fields)
        back = read_tensor_file(path, mmap=mmap)
        assert list(back) == list(fields)  # names and order
        for name, a in fields.items():
            b = back[name]
            assert b.dtype == a.dtype, name
            assert b.shape == np.atleast_1d(a).shape, name
            np.testing.assert_array_equal(_bits(b), _bits(np.atleast_1d(a)), err_msg=name)
        assert isinstance(back["M"], np.memmap) == mmap
        assert not isinstance(back["wvls"], np.memmap)  # small fields are loaded

    def test_memmap_is_read_only(self, tmp_path, fields):
        back = read_tensor_file(write_tensor_file(tmp_path / "f.tensor", fields))
        with pytest.raises(ValueError, match="read-only"):
            back["M"][0, 0] = 1.0

    def test_bytes_identical_to_mitsuba_writer(self, tmp_path, fields, mi_variant):
        mi_variant("scalar_spectral_polarized")
        from mitsuba import tensor_io

        tensor_io.write(str(tmp_path / "mitsuba.tensor"), **fields)
        write_tensor_file(tmp_path / "ours.tensor", fields)
        assert (tmp_path / "ours.tensor").read_bytes() == (tmp_path / "mitsuba.tensor").read_bytes()

    def test_interoperates_with_mitsuba_reader_and_writer(self, tmp_path, fields, mi_variant):
        mi_variant("scalar_spectral_polarized")
        from mitsuba import tensor_io

        theirs = {k: v for k, v in fields.items() if k != "scalar"}  # its reader cannot read ndim 0 anyway
        tensor_io.write(str(tmp_path / "mitsuba.tensor"), **theirs)
        ours = read_tensor_file(tmp_path / "mitsuba.tensor")
        write_tensor_file(tmp_path / "ours.tensor", theirs)
        back = tensor_io.read(str(tmp_path / "ours.tensor"))
        for name, a in theirs.items():
            for b in (ours[name], back[name]):
                assert b.dtype == a.dtype and b.shape == a.shape, name
                np.testing.assert_array_equal(_bits(b), _bits(a), err_msg=name)

    def test_header_layout(self, tmp_path):
        """The documented layout, byte by byte: magic, version, count, name, ndim, code, offset, shape."""
        path = write_tensor_file(tmp_path / "f.tensor", {"ab": np.array([[1.0, 2.0]], np.float32)})
        raw = path.read_bytes()
        head = b"tensor_file\x00" + struct.pack("<BBI", 1, 0, 1) + struct.pack("<H", 2) + b"ab"
        head += struct.pack("<HBQ", 2, 10, 56) + struct.pack("<QQ", 1, 2)  # header 49 bytes, data at 56
        assert raw == head + b"\x00" * 7 + np.array([1.0, 2.0], "<f4").tobytes()

    def test_errors(self, tmp_path, fields):
        good = write_tensor_file(tmp_path / "good.tensor", fields).read_bytes()
        cases = {
            "bad magic": (b"tensor_fil\x00\x00" + good[12:], "bad magic"),
            "version": (good[:12] + b"\x02\x00" + good[14:], r"unsupported version 2\.0 \(expected 1\.0\)"),
            "empty": (b"", "truncated header"),
            "header cut": (good[:40], "truncated header"),
            "data cut": (good[:-3], "truncated: field 'scalar'"),
            "M cut": (good[:200_000], "truncated: field 'M'"),
        }
        bad_code = bytearray(good)
        bad_code[12 + 2 + 4 + 2 + 1 + 2] = 42  # the dtype code of the first field, "M"
        cases["dtype"] = (bytes(bad_code), "field 'M' has unknown dtype code 42")
        for label, (data, match) in cases.items():
            p = tmp_path / f"{label}.tensor"
            p.write_bytes(data)
            with pytest.raises(ValueError, match=match) as info:
                read_tensor_file(p)
            assert str(p) in str(info.value) and "\n" not in str(info.value), label
        with pytest.raises(FileNotFoundError):
            read_tensor_file(tmp_path / "missing.tensor")

    def test_write_errors(self, tmp_path):
        with pytest.raises(ValueError, match="field 'mask': unsupported dtype bool"):
            write_tensor_file(tmp_path / "x.tensor", {"mask": np.zeros(3, bool)})
        with pytest.raises(ValueError, match="non-empty strings"):
            write_tensor_file(tmp_path / "x.tensor", {"": np.zeros(3)})
        assert not list(tmp_path.iterdir())

    def test_atomic_write_keeps_old_file(self, tmp_path, fields, monkeypatch):
        path = write_tensor_file(tmp_path / "f.tensor", {"a": np.arange(3.0)})
        before = path.read_bytes()

        def fail(*args):
            raise OSError("disk full")

        monkeypatch.setattr(tensorfile, "_write_array", fail)
        with pytest.raises(OSError, match="disk full"):
            write_tensor_file(path, fields)
        assert path.read_bytes() == before
        assert [p.name for p in tmp_path.iterdir()] == ["f.tensor"]  # no temporary sibling left
        assert temporary_target(".f.tensor.tmp-1-0a1b2c3d") == "f.tensor"

    def test_chunked_writing_of_a_memmap(self, tmp_path, rng, monkeypatch):
        """Arrays larger than the chunk size are written piecewise, from a memmap, bit-exactly."""
        a = rng.normal(size=(6, 5, 70)).astype(np.float32)
        src = read_tensor_file(write_tensor_file(tmp_path / "a.tensor", {"a": a}), mmap=False)["a"]
        mm = np.memmap(tmp_path / "raw.bin", dtype=np.float32, mode="w+", shape=a.shape)
        mm[:] = src
        monkeypatch.setattr(tensorfile, "_CHUNK_BYTES", 1000)  # rows of 1400 bytes: recursion and slicing
        back = read_tensor_file(write_tensor_file(tmp_path / "b.tensor", {"a": mm[:, ::-1]}), mmap=False)["a"]
        np.testing.assert_array_equal(_bits(back), _bits(a[:, ::-1]))


def test_module_exports():
    assert set(tensorfile.__all__) <= set(dir(tensorfile))
