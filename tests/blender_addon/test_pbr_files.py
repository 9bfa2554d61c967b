"""PBR map files without bpy: token matching, loading, validation, frustum and depth-mesh math."""

import numpy as np
import pytest
from PIL import Image

from blender_addon.core import pbr_files as pf
from pbrdf.io.exr import write_exr


def _touch(folder, *names):
    for n in names:
        (folder / n).write_bytes(b"")
    return folder


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


class TestTokens:
    @pytest.mark.parametrize(
        ("name", "kind"),
        [
            ("rock_albedo.png", "albedo"),
            ("rock_Diffuse.png", "albedo"),
            ("RockBaseColor.png", "albedo"),
            ("rock_base_color.exr", "albedo"),
            ("rock-basecolor.jpg", "albedo"),
            ("rock_COLOR.png", "albedo"),
            ("rock_nrm.png", "normal"),
            ("rock_Normal.exr", "normal"),
            ("rock.normals.png", "normal"),
            ("rock_rough.png", "roughness"),
            ("RockRoughness2K.png", "roughness"),
            ("rock_metal.png", "metallic"),
            ("rock_Metallic.png", "metallic"),
            ("rock-metalness.png", "metallic"),
            ("rock_mask.exr", "mask"),
            ("rock_alpha.png", "mask"),
            ("rock_Opacity.png", "mask"),
            ("rock_depth.exr", "depth"),
            ("rock_Z.exr", "depth"),
            ("rock_height.exr", "depth"),
        ],
    )
    def test_synonyms(self, name, kind):
        assert pf.match_kinds(pf.filename_tokens(name)) == (kind,)

    @pytest.mark.parametrize("name", ["dialbedo.png", "metalnessy.png", "abnormal.png", "roughly.png", "colormap.png"])
    def test_token_boundaries(self, name):
        assert pf.match_kinds(pf.filename_tokens(name)) == ()

    def test_tokens_split_case_digits_separators(self):
        assert pf.filename_tokens("x/chart01_BaseColor.PNG") == ("chart", "01", "base", "color")
        assert pf.filename_tokens("RGBNormal-v2.exr") == ("rgb", "normal", "v", "2")


class TestMatch:
    def test_infer_folder_prefers_exr(self, tmp_path):
        names = [f"cap_{k}.{e}" for k in ("normal", "albedo", "roughness", "metallic", "mask") for e in ("exr", "png")]
        _touch(tmp_path, *names, "notes.txt", "capture.json", ".cap_normal.exr.tmp-1-ab")
        m = pf.match_map_files(tmp_path)
        assert {k: p.name for k, p in m.files.items()} == {
            "normal": "cap_normal.exr",
            "albedo": "cap_albedo.exr",
            "roughness": "cap_roughness.exr",
            "metallic": "cap_metallic.exr",
            "mask": "cap_mask.exr",
        }
        assert sorted(p.name for p in m.superseded) == sorted(n for n in names if n.endswith(".png"))
        assert m.missing == ("depth",)
        assert "missing: depth" in m.summary()

    def test_asset_name_with_kind_tokens_is_stripped(self, tmp_path):
        # "color" (albedo) and "metal" (metallic) in the asset name itself
        _touch(tmp_path, "color_metal_chart_normal.exr", "color_metal_chart_albedo.exr", "color_metal_chart_rough.png")
        m = pf.match_map_files(tmp_path)
        assert {k: p.name for k, p in m.files.items()} == {
            "normal": "color_metal_chart_normal.exr",
            "albedo": "color_metal_chart_albedo.exr",
            "roughness": "color_metal_chart_rough.png",
        }

    def test_two_files_for_one_kind_are_ambiguous(self, tmp_path):
        _touch(tmp_path, "a_normal.exr", "a_albedo.png", "a_diffuse.png")
        with pytest.raises(ValueError, match=r"ambiguous.*2 files match albedo \(a_albedo.png, a_diffuse.png\)"):
            pf.match_map_files(tmp_path)

    def test_file_matching_two_kinds_is_ambiguous(self, tmp_path):
        _touch(tmp_path, "x_normal.exr", "y_rough_metal.png")
        with pytest.raises(ValueError, match=r"y_rough_metal.png matches several maps \(roughness, metallic\)"):
            pf.match_map_files(tmp_path)

    def test_missing_required_map(self, tmp_path):
        _touch(tmp_path, "a_albedo.png", "a_rough.png")
        with pytest.raises(FileNotFoundError, match=r"no normal map in .*normal, normals, nrm"):
            pf.match_map_files(tmp_path, required=("normal",))
        m = pf.match_map_files(tmp_path, required=())
        assert m.missing == ("normal", "metallic", "mask", "depth")

    def test_explicit_files_and_mapping(self, tmp_path):
        _touch(tmp_path, "a_normal.exr", "a_albedo.png", "weird.png")
        m = pf.match_map_files([tmp_path / "a_normal.exr", tmp_path / "weird.png"])
        assert list(m.files) == ["normal"] and [p.name for p in m.unmatched] == ["weird.png"]
        m = pf.match_map_files({"albedo": tmp_path / "weird.png", "normal": tmp_path / "a_normal.exr"})
        assert m.files["albedo"].name == "weird.png"
        with pytest.raises(ValueError, match="unknown map kinds"):
            pf.match_map_files({"colour": tmp_path / "weird.png"})
        m = pf.match_map_files(iter([tmp_path]))  # folders inside a list are expanded
        assert {k: p.name for k, p in m.files.items()} == {"normal": "a_normal.exr", "albedo": "a_albedo.png"}

    def test_bad_sources(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="no such folder"):
            pf.match_map_files(tmp_path / "nope")
        _touch(tmp_path, "a_normal.tga")
        with pytest.raises(ValueError, match="unsupported map format '.tga'"):
            pf.match_map_files([tmp_path / "a_normal.tga"])
        with pytest.raises(FileNotFoundError, match="map file not found"):
            pf.match_map_files([tmp_path / "gone_normal.exr"])


class TestLoad:
    def test_exr_maps_round_trip(self, tmp_path):
        n, inside = _sphere_normals(12, 16)
        alb = np.random.default_rng(0).uniform(0, 1, (12, 16, 3)).astype(np.float32)
        _exr(tmp_path / "a_normal.exr", "normal", n, "XYZ")
        _exr(tmp_path / "a_albedo.exr", "albedo", alb, "RGB")
        _exr(tmp_path / "a_roughness.exr", "roughness", np.full((12, 16), 0.3), "Y")
        maps = pf.load_maps(pf.match_map_files(tmp_path))
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
        maps = pf.load_maps(pf.match_map_files(tmp_path))
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
        maps = pf.load_maps(pf.match_map_files(tmp_path))
        np.testing.assert_allclose(maps.normal[inside], n[inside], atol=1e-5)

    def test_sizes_must_agree(self, tmp_path):
        _exr(tmp_path / "a_normal.exr", "normal", _sphere_normals(8, 8)[0], "XYZ")
        _exr(tmp_path / "a_albedo.exr", "albedo", np.zeros((8, 9, 3)), "RGB")
        with pytest.raises(ValueError, match=r"sizes differ.*normal a_normal.exr 8x8, albedo a_albedo.exr 8x9"):
            pf.load_maps(pf.match_map_files(tmp_path))

    def test_nonfinite_values(self, tmp_path):
        alb = np.zeros((8, 8, 3))
        alb[2, 5, 1] = np.nan
        write_exr(
            tmp_path / "a_albedo.exr", {f"albedo.{c}": alb[..., i] for i, c in enumerate("RGB")}, allow_nonfinite=True
        )
        with pytest.raises(ValueError, match=r"albedo map has NaN/Inf in 1 pixel\(s\), first at \(row 2, col 5\)"):
            pf.load_maps({"albedo": tmp_path / "a_albedo.exr"})

    def test_non_unit_normals(self, tmp_path):
        n, _ = _sphere_normals(8, 8)
        n[4, 4] *= 0.8
        _exr(tmp_path / "a_normal.exr", "normal", n, "XYZ")
        with pytest.raises(
            ValueError, match=r"not unit length in 1 of \d+ pixel\(s\) \(first at row 4, col 4: \|n\| = 0.8000"
        ):
            pf.load_maps(pf.match_map_files(tmp_path))

    def test_out_of_range_values_are_clipped_and_reported(self, tmp_path):
        r = np.full((4, 4), 0.5)
        r[0, 0] = 1.2
        _exr(tmp_path / "a_rough.exr", "roughness", r, "Y")
        maps = pf.load_maps(pf.match_map_files(tmp_path, required=()))
        assert maps.roughness[0, 0] == 1.0
        assert len(maps.warnings) == 1 and "roughness outside [0, 1] in 1 pixel(s)" in maps.warnings[0]

    def test_depth_rules(self, tmp_path):
        _png(tmp_path / "a_depth.png", np.full((4, 4), 0.5))
        with pytest.raises(ValueError, match="depth maps must be float EXR"):
            pf.load_maps({"depth": tmp_path / "a_depth.png"})
        d = np.full((4, 4), 2.0)
        d[1, 2] = -1
        _exr(tmp_path / "a_depth.exr", "depth", d, "Y")
        with pytest.raises(ValueError, match=r"depth must be finite and > 0 .*row 1, col 2"):
            pf.load_maps({"depth": tmp_path / "a_depth.exr"})

    def test_ambiguous_channels(self, tmp_path):
        write_exr(tmp_path / "a_rough.exr", {"a.Y": np.zeros((2, 2)), "b.Y": np.zeros((2, 2))})
        with pytest.raises(ValueError, match="cannot tell which channel holds the roughness map"):
            pf.load_maps({"roughness": tmp_path / "a_rough.exr"})


class TestFrustum:
    def test_docstring_example(self):
        f = pf.blender_frustum(4, 2, lens=36, sensor_width=36, sensor_height=24)
        assert (f.half_width, f.half_height) == (0.5, 0.25)
        np.testing.assert_allclose(f.pixel_xy()[0, 0], [-0.375, 0.125])

    def test_projection_matches_pinhole_intrinsics(self, rng):
        # independent pinhole model: f_px = lens / sensor_width * W, principal point at the centre
        w, h, lens, sw = 640, 480, 35.0, 36.0
        f = pf.blender_frustum(w, h, lens=lens, sensor_width=sw, sensor_height=24.0)
        fpx = lens / sw * w
        p = rng.uniform([-1, -1, -5], [1, 1, -1], (50, 3))
        expected = np.stack([w / 2 + fpx * p[:, 0] / -p[:, 2], h / 2 - fpx * p[:, 1] / -p[:, 2]], -1)
        np.testing.assert_allclose(f.project(p), expected, rtol=1e-12)
        xy = f.pixel_xy()
        pts = np.concatenate([xy, -np.ones((h, w, 1))], -1) * 2.5
        np.testing.assert_allclose(f.project(pts)[10, 20], [20.5, 10.5], atol=1e-9)

    def test_fit_modes_and_shift(self):
        portrait = pf.blender_frustum(2, 4, lens=36, sensor_width=36, sensor_height=24)  # AUTO: width spans height
        assert (portrait.half_width, portrait.half_height) == (0.25, 0.5)
        vert = pf.blender_frustum(4, 2, lens=24, sensor_width=36, sensor_height=24, sensor_fit="VERTICAL")
        assert (vert.half_width, vert.half_height) == (1.0, 0.5)
        shifted = pf.blender_frustum(4, 2, lens=36, sensor_width=36, sensor_height=24, shift_x=0.1, shift_y=-0.2)
        assert (shifted.center_x, shifted.center_y) == pytest.approx((0.1, -0.2))  # units of the 1.0-wide axis
        with pytest.raises(ValueError, match="sensor_fit"):
            pf.blender_frustum(4, 2, lens=36, sensor_width=36, sensor_height=24, sensor_fit="FILL")


class TestDepthMesh:
    def test_constant_depth_is_a_camera_facing_grid(self):
        f = pf.blender_frustum(6, 4, lens=50, sensor_width=36, sensor_height=24)
        v, faces, uv = pf.depth_mesh(np.full((4, 6), 3.0), np.ones((4, 6), bool), f)
        assert v.shape == (24, 3) and faces.shape == (2 * 3 * 5, 3)
        np.testing.assert_allclose(v[:, 2], -3.0)
        np.testing.assert_allclose(v[:, :2], f.pixel_xy().reshape(-1, 2) * 3.0)
        e1, e2 = v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]
        assert (np.cross(e1, e2)[:, 2] > 0).all()  # counter-clockwise seen from the camera: normals toward it
        np.testing.assert_allclose(uv[0], [0.5 / 6, 1 - 0.5 / 4])

    def test_holes_and_jumps(self):
        f = pf.blender_frustum(3, 3, lens=50, sensor_width=36, sensor_height=24)
        valid = np.ones((3, 3), bool)
        valid[0, 0] = False  # top-left block keeps one triangle
        d = np.full((3, 3), 1.0)
        d[:, 2] = 2.0  # right column far away: no triangles across the jump
        v, faces, _ = pf.depth_mesh(d, valid, f)
        assert len(v) == 8 and len(faces) == 1 + 2
        _, faces, _ = pf.depth_mesh(d, valid, f, max_jump=2.0)
        assert len(faces) == 1 + 2 + 2 + 2
