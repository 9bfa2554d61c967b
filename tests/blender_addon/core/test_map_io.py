"""PBR map files as arrays (blender_addon/core/map_io.py): reading, channel picking, validation."""

import numpy as np
import pytest
from PIL import Image

from blender_addon.core import map_io
from blender_addon.core.map_names import match_map_files
from pbrdf.io.exr import write_exr


def _exr(path, prefix, img, comps):
    img = np.asarray(img, np.float32)
    img = img[..., None] if img.ndim == 2 else img
    write_exr(path, {f"{prefix}.{c}": img[..., i] for i, c in enumerate(comps)})
    return path


def _png(path, img01):
    a = np.rint(np.clip(img01, 0, 1) * 255).astype(np.uint8)
    Image.fromarray(a).save(path)
    return path


def _sphere_normals(h, w):
    y, x = np.mgrid[0:h, 0:w]
    x = (x + 0.5 - w / 2) / (0.45 * w)
    y = -(y + 0.5 - h / 2) / (0.45 * h)
    r2 = x**2 + y**2
    inside = r2 < 1
    n = np.stack([x, y, np.sqrt(np.clip(1 - r2, 0, 1))], -1)
    n[~inside] = 0
    return n.astype(np.float32), inside


class TestLoad:
    def test_exr_maps_round_trip(self, tmp_path):
        n, inside = _sphere_normals(12, 16)
        alb = np.random.default_rng(0).uniform(0, 1, (12, 16, 3)).astype(np.float32)
        _exr(tmp_path / "a_normal.exr", "normal", n, "XYZ")
        _exr(tmp_path / "a_albedo.exr", "albedo", alb, "RGB")
        _exr(tmp_path / "a_roughness.exr", "roughness", np.full((12, 16), 0.3), "Y")
        maps = map_io.load_maps(match_map_files(tmp_path))
        np.testing.assert_array_equal(maps.valid, inside)  # mask from the non-zero normals
        assert maps.mask_source == "normal"
        np.testing.assert_allclose(maps.normal[inside], n[inside], atol=1e-6)
        assert (maps.normal[~inside] == [0, 0, 1]).all()
        np.testing.assert_array_equal(maps.albedo, alb)  # EXR albedo is linear: no transfer function
        assert maps.metallic is None and maps.present() == ("normal", "albedo", "roughness")

    def test_png_normals_and_srgb_albedo(self, tmp_path):
        n, inside = _sphere_normals(12, 16)
        _png(tmp_path / "a_nrm.png", 0.5 + 0.5 * n)  # background encodes as (0.5, 0.5, 0.5)...
        _png(tmp_path / "a_mask.png", inside.astype(float))
        _png(tmp_path / "a_basecolor.png", np.full((12, 16, 3), 128 / 255))
        maps = map_io.load_maps(match_map_files(tmp_path))
        ang = np.degrees(np.arccos(np.clip((maps.normal * n).sum(-1), -1, 1)))[inside]
        assert ang.max() < 1.0  # 8-bit quantisation: at most ~0.6 degrees
        np.testing.assert_allclose(np.linalg.norm(maps.normal, axis=-1), 1, atol=1e-6)
        # IEC 61966-2-1: 128/255 -> ((0.50196 + 0.055) / 1.055) ** 2.4 = 0.21586
        np.testing.assert_allclose(maps.albedo, 0.21586, atol=1e-4)

    def test_encoded_exr_normals_are_recognised(self, tmp_path):
        n, inside = _sphere_normals(8, 8)
        enc = np.where(inside[..., None], 0.5 + 0.5 * n, 0)
        _exr(tmp_path / "b_normal.exr", "", enc, "RGB")
        _exr(tmp_path / "b_mask.exr", "mask", inside.astype(float), "Y")
        maps = map_io.load_maps(match_map_files(tmp_path))
        np.testing.assert_allclose(maps.normal[inside], n[inside], atol=1e-5)

    def test_sizes_must_agree(self, tmp_path):
        _exr(tmp_path / "a_normal.exr", "normal", _sphere_normals(8, 8)[0], "XYZ")
        _exr(tmp_path / "a_albedo.exr", "albedo", np.zeros((8, 9, 3)), "RGB")
        with pytest.raises(ValueError, match=r"sizes differ.*normal a_normal.exr 8x8, albedo a_albedo.exr 8x9"):
            map_io.load_maps(match_map_files(tmp_path))

    def test_nonfinite_values(self, tmp_path):
        alb = np.zeros((8, 8, 3))
        alb[2, 5, 1] = np.nan
        write_exr(
            tmp_path / "a_albedo.exr", {f"albedo.{c}": alb[..., i] for i, c in enumerate("RGB")}, allow_nonfinite=True
        )
        with pytest.raises(ValueError, match=r"albedo map has NaN/Inf in 1 pixel\(s\), first at \(row 2, col 5\)"):
            map_io.load_maps({"albedo": tmp_path / "a_albedo.exr"})

    def test_non_unit_normals(self, tmp_path):
        n, _ = _sphere_normals(8, 8)
        n[4, 4] *= 0.8
        _exr(tmp_path / "a_normal.exr", "normal", n, "XYZ")
        with pytest.raises(
            ValueError, match=r"not unit length in 1 of \d+ pixel\(s\) \(first at row 4, col 4: \|n\| = 0.8000"
        ):
            map_io.load_maps(match_map_files(tmp_path))

    def test_out_of_range_values_are_clipped_and_reported(self, tmp_path):
        r = np.full((4, 4), 0.5)
        r[0, 0] = 1.2
        _exr(tmp_path / "a_rough.exr", "roughness", r, "Y")
        maps = map_io.load_maps(match_map_files(tmp_path, required=()))
        assert maps.roughness[0, 0] == 1.0
        assert len(maps.warnings) == 1 and "roughness outside [0, 1] in 1 pixel(s)" in maps.warnings[0]

    def test_depth_rules(self, tmp_path):
        _png(tmp_path / "a_depth.png", np.full((4, 4), 0.5))
        with pytest.raises(ValueError, match="depth maps must be float EXR"):
            map_io.load_maps({"depth": tmp_path / "a_depth.png"})
        d = np.full((4, 4), 2.0)
        d[1, 2] = -1
        _exr(tmp_path / "a_depth.exr", "depth", d, "Y")
        with pytest.raises(ValueError, match=r"depth must be finite and > 0 .*row 1, col 2"):
            map_io.load_maps({"depth": tmp_path / "a_depth.exr"})

    def test_ambiguous_channels(self, tmp_path):
        write_exr(tmp_path / "a_rough.exr", {"a.Y": np.zeros((2, 2)), "b.Y": np.zeros((2, 2))})
        with pytest.raises(ValueError, match="cannot tell which channel holds the roughness map"):
            map_io.load_maps({"roughness": tmp_path / "a_rough.exr"})


def test_extend_past_mask_keeps_the_inside_and_continues_the_surface():
    """Two rings past the mask: inside unchanged, unit normals, neighbours' albedo, a plane's depth continued."""
    h, w = 12, 16
    yy, xx = np.mgrid[0:h, 0:w]
    mask = ((yy - 5.5) ** 2 + (xx - 7.5) ** 2 < 16).astype(np.float32)
    inside = mask > 0.5
    n = np.where(inside[..., None], np.float32([0.3, -0.2, 0.9327379]), 0.0).astype(np.float32)
    depth = np.where(inside, 2.0 + 0.01 * xx - 0.02 * yy, np.inf).astype(np.float32)  # a tilted plane
    albedo = np.where(inside[..., None], 0.4, 0.0).astype(np.float32) * np.ones(3, np.float32)
    maps = map_io.PBRMaps(normal=n, albedo=albedo, mask=mask, depth=depth, mask_source="file")
    out = map_io.extend_past_mask(maps, 2)
    ring = map_io.dilate(inside, 2) & ~inside
    beyond = ~map_io.dilate(inside, 2)
    assert ring.sum() > 20 and not (out.albedo[..., 0] > 0)[beyond].any()
    np.testing.assert_array_equal(out.mask, mask)
    np.testing.assert_array_equal(out.normal[inside], n[inside])
    np.testing.assert_allclose(np.linalg.norm(out.normal[ring], axis=-1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(out.albedo[ring], 0.4, rtol=1e-6)
    np.testing.assert_allclose(out.depth[ring], (2.0 + 0.01 * xx - 0.02 * yy)[ring], rtol=1e-6)  # a plane stays one
    assert maps.depth is depth and np.isinf(maps.depth[~inside]).all()  # the input is not changed


@pytest.mark.parametrize("tile", [4, 5, 32])
def test_extend_past_mask_by_tiles_is_the_whole_frame_extension(tile):
    """Extending only the outline's tiles gives pbrdf's extend_maps over the whole frame, value for value.

    Blobs and holes of random sizes, one touching two sides of a frame that is no multiple of the tile,
    random values (so each ring's neighbours matter) and depth continued from two pixels away.
    """
    from pbrdf.geometry.relief import extend_maps

    rng = np.random.default_rng(tile)
    h, w = 37, 53
    yy, xx = np.mgrid[0:h, 0:w]
    mask = ((yy - 18) ** 2 / 100 + (xx - 20) ** 2 / 200 < 1) & ((yy - 17) ** 2 + (xx - 22) ** 2 > 9)
    mask |= (yy - 36) ** 2 + (xx - 52) ** 2 < 30  # at the corner of the frame
    mask |= (yy == 3) & (xx == 45)  # one pixel alone
    n = rng.normal(size=(h, w, 3)) + [0, 0, 3]
    maps = map_io.PBRMaps(
        normal=(n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32),
        albedo=rng.uniform(size=(h, w, 3)).astype(np.float32),
        roughness=rng.uniform(size=(h, w)).astype(np.float32),
        depth=(2.0 + 0.05 * rng.uniform(size=(h, w))).astype(np.float32),
        mask=mask.astype(np.float32),
        mask_source="file",
    )
    whole = extend_maps({k: getattr(maps, k) for k in ("normal", "albedo", "roughness", "depth")}, mask, 2)
    out = map_io.extend_past_mask(maps, 2, tile=tile)
    for key, want in whole.items():
        assert getattr(out, key).dtype == want.dtype == np.float32
        np.testing.assert_array_equal(getattr(out, key), want, err_msg=key)
