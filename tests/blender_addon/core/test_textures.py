"""Texture images as values (blender_addon/core/textures.py): decoding, bad files, area averaging, the cache."""

import os
import struct
import time
import zlib

import numpy as np
import pytest
from PIL import Image

from blender_addon.core import textures
from blender_addon.core.textures import (
    TextureNotFoundError,
    TextureSpec,
    clear_texture_cache,
    texture_array,
    texture_mean,
    texture_size_for,
)


def srgb_decode(c):
    """IEC 61966-2-1 (sRGB) decoding, scalar by scalar: the reference for the vectorised decode."""
    c = float(c)
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def png_bytes(width, height, bit_depth, colour_type, scanlines):
    """A PNG file written by hand (PNG spec: signature, IHDR, one zlib IDAT, IEND, CRC-32 per chunk)."""

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    head = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    idat = zlib.compress(scanlines)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def png16(path, rgb16):
    """A 16-bit RGB PNG (Pillow cannot write one): filter-0 rows of big-endian samples."""
    h, w, _ = rgb16.shape
    path.write_bytes(png_bytes(w, h, 16, 2, b"".join(b"\0" + row.astype(">u2").tobytes() for row in rgb16)))
    return path


def spec(path, channels=(0, 1, 2), colorspace="linear"):
    return TextureSpec(str(path), channels=channels, factor=(1.0,) * len(channels), colorspace=colorspace)


@pytest.fixture(autouse=True)
def _fresh_cache():
    clear_texture_cache()
    yield
    clear_texture_cache()


class TestDecoding:
    def test_8bit_srgb_png_decodes_colour_to_linear(self, tmp_path):
        rgb = np.array([[[0, 128, 255], [10, 64, 200]]], np.uint8)
        Image.fromarray(rgb).save(tmp_path / "a.png")
        got = texture_array(spec(tmp_path / "a.png", colorspace="srgb"))
        want = np.vectorize(srgb_decode)(rgb / 255.0)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
        assert got[0, 0, 1] == pytest.approx(0.21586, abs=1e-5)  # mid-grey 128: IEC 61966-2-1

    def test_linear_data_is_read_as_stored(self, tmp_path):
        rgb = np.array([[[0, 128, 255]]], np.uint8)
        Image.fromarray(rgb).save(tmp_path / "a.png")
        np.testing.assert_allclose(texture_array(spec(tmp_path / "a.png")), rgb / 255.0, atol=1e-7)

    def test_alpha_is_never_srgb_decoded(self, tmp_path):
        rgba = np.array([[[128, 128, 128, 128]]], np.uint8)
        Image.fromarray(rgba).save(tmp_path / "a.png")
        got = texture_array(spec(tmp_path / "a.png", channels=(0, 3), colorspace="srgb"))
        np.testing.assert_allclose(got[0, 0], [srgb_decode(128 / 255), 128 / 255], atol=1e-6)

    def test_missing_alpha_reads_opaque(self, tmp_path):
        Image.fromarray(np.full((2, 2, 3), 7, np.uint8)).save(tmp_path / "a.png")
        assert np.all(texture_array(spec(tmp_path / "a.png", channels=(3,))) == 1.0)

    def test_16bit_grey_png_scaled_by_65535(self, tmp_path):
        grey = np.array([[0, 30000, 65535]], np.uint16)
        Image.fromarray(grey).save(tmp_path / "g.png")
        assert Image.open(tmp_path / "g.png").mode == "I;16"
        got = texture_array(spec(tmp_path / "g.png", channels=(0, 1, 2)))
        np.testing.assert_allclose(got[..., 0], grey / 65535.0, rtol=0, atol=1e-7)  # 8 bits could not: 1/255 apart
        np.testing.assert_array_equal(got[..., 0], got[..., 2])  # grey serves every colour channel
        srgb = texture_array(spec(tmp_path / "g.png", channels=(1,), colorspace="srgb"))
        assert srgb[0, 1, 0] == pytest.approx(srgb_decode(30000 / 65535), abs=1e-6)

    def test_16bit_colour_png_within_8bit_precision(self, tmp_path):
        rgb16 = np.array([[[3000, 40000, 65535], [0, 257, 12345]]], np.uint16)
        got = texture_array(spec(png16(tmp_path / "c.png", rgb16)))
        np.testing.assert_allclose(got, rgb16 / 65535.0, rtol=0, atol=1 / 255)  # documented: Pillow keeps 8 bits

    def test_paletted_png_converted_with_its_transparency(self, tmp_path):
        im = Image.new("P", (2, 1))
        im.putpalette([255, 0, 0, 0, 0, 255] + [0] * 762)
        im.putdata([0, 1])
        im.save(tmp_path / "p.png", transparency=1)
        got = texture_array(spec(tmp_path / "p.png", channels=(0, 1, 2, 3)))
        np.testing.assert_array_equal(got[0], [[1, 0, 0, 1], [0, 0, 1, 0]])

    def test_transparent_key_colour_becomes_alpha(self, tmp_path):
        Image.fromarray(np.array([[0, 255]], np.uint8)).save(tmp_path / "k.png", transparency=0)  # tRNS chunk
        got = texture_array(spec(tmp_path / "k.png", channels=(0, 3)))
        np.testing.assert_array_equal(got[0], [[0, 0], [1, 1]])

    def test_grey_alpha_png(self, tmp_path):
        la = np.array([[[128, 64]]], np.uint8)
        Image.fromarray(la, mode="LA").save(tmp_path / "la.png")
        got = texture_array(spec(tmp_path / "la.png", channels=(0, 1, 2, 3), colorspace="srgb"))
        np.testing.assert_allclose(got[0, 0], [srgb_decode(128 / 255)] * 3 + [64 / 255], atol=1e-6)

    def test_exr_read_as_stored_even_when_srgb(self, tmp_path):
        write_exr = pytest.importorskip("pbrdf.io.exr").write_exr
        img = np.array([[[0.25, 0.5, 2.0]]], np.float32)
        write_exr(tmp_path / "a.exr", {c: img[..., i] for i, c in enumerate("RGB")})
        np.testing.assert_array_equal(texture_array(spec(tmp_path / "a.exr", colorspace="srgb")), img)

    def test_factor_multiplies_each_channel(self, tmp_path):
        Image.fromarray(np.full((1, 1, 3), 255, np.uint8)).save(tmp_path / "w.png")
        t = TextureSpec(str(tmp_path / "w.png"), channels=(2, 1), factor=(0.5, 0.25))
        np.testing.assert_array_equal(texture_array(t)[0, 0], [0.5, 0.25])


class TestBadInput:
    def _one_line(self, exc, name):
        text = str(exc.value)
        assert "\n" not in text and name in text
        return text

    def test_missing_file(self, tmp_path):
        with pytest.raises(TextureNotFoundError) as e:
            texture_array(spec(tmp_path / "none.png"))
        assert isinstance(e.value, ValueError) and isinstance(e.value, FileNotFoundError)
        self._one_line(e, "none.png")

    def test_truncated_png(self, tmp_path):
        noise = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)  # incompressible
        Image.fromarray(noise).save(tmp_path / "t.png")
        data = (tmp_path / "t.png").read_bytes()
        (tmp_path / "t.png").write_bytes(data[: len(data) // 2])
        with pytest.raises(ValueError, match="cannot read texture") as e:
            texture_array(spec(tmp_path / "t.png"))
        self._one_line(e, "t.png")

    def test_not_an_image(self, tmp_path):
        (tmp_path / "x.png").write_text("hello")
        with pytest.raises(ValueError, match="not a readable image") as e:
            texture_array(spec(tmp_path / "x.png"))
        self._one_line(e, "x.png")

    def test_image_bomb_refused_before_decoding(self, tmp_path):
        # A header declaring 30000 x 30000 RGB (2.7 GB decoded) and one row of data.
        (tmp_path / "bomb.png").write_bytes(png_bytes(30000, 30000, 8, 2, b"\0" * (3 * 30000 + 1)))
        t0 = time.perf_counter()
        with pytest.raises(ValueError, match="too large") as e:
            texture_array(spec(tmp_path / "bomb.png"))
        assert time.perf_counter() - t0 < 2.0  # refused from the header, not after allocating gigabytes
        self._one_line(e, "bomb.png")

    def test_exr_with_nan(self, tmp_path):
        write_exr = pytest.importorskip("pbrdf.io.exr").write_exr
        img = np.array([[0.5, np.nan], [np.inf, 0.1]], np.float32)
        write_exr(tmp_path / "n.exr", {"Y": img}, allow_nonfinite=True)
        with pytest.raises(ValueError, match="2 NaN/Inf") as e:
            texture_array(spec(tmp_path / "n.exr", channels=(0,)))
        self._one_line(e, "n.exr")

    def test_embedded_image_not_supported_yet(self, tmp_path):
        with pytest.raises(ValueError, match="not supported yet"):
            texture_array(spec(f"{tmp_path}/model.glb#image=3"))

    def test_bad_max_size(self, tmp_path):
        with pytest.raises(ValueError, match="max_size"):
            texture_array(spec(tmp_path / "a.png"), max_size=0)


def box_reference(img, h_out, w_out):
    """Area average by replication: repeat each texel so both grids divide, then block means."""
    h, w = img.shape[:2]
    lh, lw = h_out // np.gcd(h, h_out), w_out // np.gcd(w, w_out)
    big = np.repeat(np.repeat(img, lh, axis=0), lw, axis=1)
    return big.reshape(h_out, h * lh // h_out, w_out, w * lw // w_out, -1).mean(axis=(1, 3))


class TestMaxSize:
    def test_halves_a_checker_exactly(self, tmp_path):
        cells = (np.add.outer(np.arange(8) // 2, np.arange(8) // 2) % 2 * 255).astype(np.uint8)  # 2x2-texel cells
        Image.fromarray(cells).save(tmp_path / "c.png")
        got = texture_array(spec(tmp_path / "c.png", channels=(0,)), max_size=4)
        np.testing.assert_array_equal(got[..., 0], np.add.outer(np.arange(4), np.arange(4)) % 2)

    def test_averages_linear_values_after_srgb_decoding(self, tmp_path):
        cells = (np.add.outer(np.arange(4), np.arange(4)) % 2 * 255).astype(np.uint8)  # 1-texel black/white checker
        Image.fromarray(cells).save(tmp_path / "c.png")
        got = texture_array(spec(tmp_path / "c.png", channels=(0,), colorspace="srgb"), max_size=2)
        np.testing.assert_allclose(got, 0.5, atol=1e-7)  # half the light, not decode(0.5) = 0.214

    @pytest.mark.parametrize("shape,max_size", [((37, 53), 10), ((6, 9), 6), ((50, 20), 7)])
    def test_area_average_matches_replication_and_keeps_the_mean(self, tmp_path, shape, max_size):
        img = np.random.default_rng(1).integers(0, 256, (*shape, 3), dtype=np.uint8)
        Image.fromarray(img).save(tmp_path / "r.png")
        got = texture_array(spec(tmp_path / "r.png"), max_size=max_size)
        s = max_size / max(shape)
        h_out, w_out = round(shape[0] * s), round(shape[1] * s)
        assert got.shape == (h_out, w_out, 3) and max(got.shape[:2]) == max_size
        np.testing.assert_allclose(got, box_reference(img / 255.0, h_out, w_out), atol=1e-6)
        np.testing.assert_allclose(got.mean(axis=(0, 1)), (img / 255.0).mean(axis=(0, 1)), atol=1e-6)

    def test_small_images_kept(self, tmp_path):
        Image.fromarray(np.zeros((5, 3, 3), np.uint8)).save(tmp_path / "s.png")
        assert texture_array(spec(tmp_path / "s.png"), max_size=8).shape == (5, 3, 3)

    def test_size_policy(self):
        assert texture_size_for(384) == 768  # two texels per pixel across the frame
        assert texture_size_for(100, 0.5, texels_per_pixel=1.0) == 50
        assert texture_size_for(2) == 8
        with pytest.raises(ValueError, match="resolution"):
            texture_size_for(0)

    def test_texture_mean(self, tmp_path):
        img = np.random.default_rng(2).integers(0, 256, (130, 70, 3), dtype=np.uint8)
        Image.fromarray(img).save(tmp_path / "m.png")
        t = TextureSpec(str(tmp_path / "m.png"), factor=(1.0, 0.5, 2.0))
        np.testing.assert_allclose(texture_mean(t), (img / 255.0).mean(axis=(0, 1)) * [1, 0.5, 2], atol=1e-6)


class TestCache:
    def test_a_rewritten_file_is_read_again(self, tmp_path):
        path = tmp_path / "a.png"
        Image.fromarray(np.full((2, 2, 3), 255, np.uint8)).save(path)
        assert texture_array(spec(path)).max() == 1.0
        Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(path)
        os.utime(path, ns=(1, 1))  # another mtime, even on a coarse clock
        assert texture_array(spec(path)).max() == 0.0

    def test_callers_cannot_change_the_cached_array(self, tmp_path):
        path = tmp_path / "a.png"
        Image.fromarray(np.full((2, 2, 3), 255, np.uint8)).save(path)
        first = texture_array(spec(path))
        first[:] = 0
        assert texture_array(spec(path)).min() == 1.0

    def test_bounded(self):
        for seed in range(textures.CACHE_ENTRIES + 5):
            texture_array(TextureSpec("procedural:noise", channels=(0,), factor=(1.0,),
                                      params={"seed": seed, "size": 8}))  # fmt: skip
        assert len(textures._cache) == textures.CACHE_ENTRIES
