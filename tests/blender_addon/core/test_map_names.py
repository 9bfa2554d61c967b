"""PBR map file names (blender_addon/core/map_names.py): tokens, synonyms, matching a folder's files."""

import pytest

from blender_addon.core import map_names as mn


def _touch(folder, *names):
    for n in names:
        (folder / n).write_bytes(b"")
    return folder


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
        assert mn.match_kinds(mn.filename_tokens(name)) == (kind,)

    @pytest.mark.parametrize("name", ["dialbedo.png", "metalnessy.png", "abnormal.png", "roughly.png", "colormap.png"])
    def test_token_boundaries(self, name):
        assert mn.match_kinds(mn.filename_tokens(name)) == ()

    def test_tokens_split_case_digits_separators(self):
        assert mn.filename_tokens("x/chart01_BaseColor.PNG") == ("chart", "01", "base", "color")
        assert mn.filename_tokens("RGBNormal-v2.exr") == ("rgb", "normal", "v", "2")


class TestMatch:
    def test_infer_folder_prefers_exr(self, tmp_path):
        names = [f"cap_{k}.{e}" for k in ("normal", "albedo", "roughness", "metallic", "mask") for e in ("exr", "png")]
        _touch(tmp_path, *names, "notes.txt", "capture.json", ".cap_normal.exr.tmp-1-ab")
        m = mn.match_map_files(tmp_path)
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
        m = mn.match_map_files(tmp_path)
        assert {k: p.name for k, p in m.files.items()} == {
            "normal": "color_metal_chart_normal.exr",
            "albedo": "color_metal_chart_albedo.exr",
            "roughness": "color_metal_chart_rough.png",
        }

    def test_two_files_for_one_kind_are_ambiguous(self, tmp_path):
        _touch(tmp_path, "a_normal.exr", "a_albedo.png", "a_diffuse.png")
        with pytest.raises(ValueError, match=r"ambiguous.*2 files match albedo \(a_albedo.png, a_diffuse.png\)"):
            mn.match_map_files(tmp_path)

    def test_file_matching_two_kinds_is_ambiguous(self, tmp_path):
        _touch(tmp_path, "x_normal.exr", "y_rough_metal.png")
        with pytest.raises(ValueError, match=r"y_rough_metal.png matches several maps \(roughness, metallic\)"):
            mn.match_map_files(tmp_path)

    def test_missing_required_map(self, tmp_path):
        _touch(tmp_path, "a_albedo.png", "a_rough.png")
        with pytest.raises(FileNotFoundError, match=r"no normal map in .*normal, normals, nrm"):
            mn.match_map_files(tmp_path, required=("normal",))
        m = mn.match_map_files(tmp_path, required=())
        assert m.missing == ("normal", "metallic", "mask", "depth")

    def test_explicit_files_and_mapping(self, tmp_path):
        _touch(tmp_path, "a_normal.exr", "a_albedo.png", "weird.png")
        m = mn.match_map_files([tmp_path / "a_normal.exr", tmp_path / "weird.png"])
        assert list(m.files) == ["normal"] and [p.name for p in m.unmatched] == ["weird.png"]
        m = mn.match_map_files({"albedo": tmp_path / "weird.png", "normal": tmp_path / "a_normal.exr"})
        assert m.files["albedo"].name == "weird.png"
        with pytest.raises(ValueError, match="unknown map kinds"):
            mn.match_map_files({"colour": tmp_path / "weird.png"})
        m = mn.match_map_files(iter([tmp_path]))  # folders inside a list are expanded
        assert {k: p.name for k, p in m.files.items()} == {"normal": "a_normal.exr", "albedo": "a_albedo.png"}

    def test_bad_sources(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="no such folder"):
            mn.match_map_files(tmp_path / "nope")
        _touch(tmp_path, "a_normal.tga")
        with pytest.raises(ValueError, match="unsupported map format '.tga'"):
            mn.match_map_files([tmp_path / "a_normal.tga"])
        with pytest.raises(FileNotFoundError, match="map file not found"):
            mn.match_map_files([tmp_path / "gone_normal.exr"])
