"""PBR map file names (blender_addon/core/map_names.py): tokens, synonyms, matching a folder's files."""

import json
import re

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


class TestCameraFile:
    def test_camera_of_the_maps_prefix(self, tmp_path):
        _touch(tmp_path, "cap_normal.exr", "cap_albedo.png", "cap_camera.json", "other_camera.json", "ca_camera.json")
        files = {"normal": tmp_path / "cap_normal.exr", "albedo": tmp_path / "cap_albedo.png"}
        assert mn.camera_file(files) == tmp_path / "cap_camera.json"
        # a sequence frame's camera, not the sequence's first digits or another frame's
        _touch(tmp_path, "face_0001_normal.exr", "face_0001_camera.json", "face_0002_camera.json", "face_camera.json")
        assert mn.camera_file({"normal": tmp_path / "face_0001_normal.exr"}).name == "face_0001_camera.json"

    def test_absent_or_of_other_maps(self, tmp_path):
        _touch(tmp_path, "cap_normal.exr", "rock_albedo.png", "cap_camera.json")
        assert mn.camera_file({"normal": tmp_path / "cap_normal.exr", "albedo": tmp_path / "rock_albedo.png"}) is None
        _touch(tmp_path, "x_normal.exr")
        assert mn.camera_file({"normal": tmp_path / "x_normal.exr"}) is None
        assert mn.camera_file({}) is None


def _sequence(folder, n=2, kinds=("normal", "albedo", "mask"), name="face", prefixes=None):
    folder.mkdir(exist_ok=True)
    prefixes = prefixes or [f"{name}_{i:04d}" for i in range(1, n + 1)]
    for p in prefixes:
        _touch(folder, *(f"{p}_{k}.exr" for k in kinds), *(f"{p}_{k}.png" for k in kinds), f"{p}_camera.json")
    frames = [{"frame": i, "prefix": p, "capture": f"/c/{i}", "seconds": 0.5} for i, p in enumerate(prefixes, 1)]
    doc = {"name": name, "frames": frames, "frames_per_second": 2.0, "timed": "decode + prediction"}
    (folder / f"{name}_sequence.json").write_text(json.dumps(doc))
    return folder / f"{name}_sequence.json"


class TestSequence:
    def test_infer_sequence_folder(self, tmp_path):
        path = _sequence(tmp_path / "s", n=3)
        assert mn.find_sequence(tmp_path / "s") == path
        assert mn.find_sequence(path) == mn.find_sequence([path]) == path
        seq = mn.match_sequence_files(path)
        assert (seq.name, seq.frames, seq.path) == ("face", 3, path)
        assert {k: p.name for k, p in seq.first.files.items()} == {
            "normal": "face_0001_normal.exr",
            "albedo": "face_0001_albedo.exr",
            "mask": "face_0001_mask.exr",
        }
        assert seq.camera.name == "face_0001_camera.json"
        third = seq.frame(3).files  # frame 3's maps: the names Blender's image sequences read at frame 3
        assert {k: p.name for k, p in third.items()} == {k: f"face_0003_{k}.exr" for k in ("normal", "albedo", "mask")}
        assert all(p.is_file() for p in third.values())
        with pytest.raises(ValueError, match=r"frame must be in 1\.\.3, got 4"):
            seq.frame(4)

    def test_not_a_sequence(self, tmp_path):
        _touch(tmp_path, "cap_normal.exr")
        assert mn.find_sequence(tmp_path) is None
        assert mn.find_sequence(tmp_path / "cap_normal.exr") is None
        assert mn.find_sequence([tmp_path / "cap_normal.exr", tmp_path / "x"]) is None
        assert mn.find_sequence({"normal": tmp_path / "cap_normal.exr"}) is None
        _sequence(tmp_path, name="a")
        _sequence(tmp_path, name="b")
        with pytest.raises(ValueError, match=r"2 sequences \(a_sequence.json, b_sequence.json\)"):
            mn.find_sequence(tmp_path)

    def test_missing_frame_file(self, tmp_path):
        path = _sequence(tmp_path, n=3)
        (tmp_path / "face_0003_albedo.exr").unlink()
        with pytest.raises(FileNotFoundError, match=r"frame 3 has no face_0003_albedo.exr \(frame 1 has face_0001"):
            mn.match_sequence_files(path)

    def test_names_blender_cannot_number(self, tmp_path):
        # digits after the frame number: Blender would number the frames by "2"
        path = _sequence(tmp_path / "a", kinds=("normal_2k",))
        with pytest.raises(ValueError, match=r"face_0001_normal_2k.exr: Blender would read the frame number"):
            mn.match_sequence_files(path)
        path = _sequence(tmp_path / "b", prefixes=["face_0001", "face_0003"])
        with pytest.raises(
            ValueError, match=r"frames\[1\].prefix: 'face_0003', but Blender reads frame 2 from 'face_0002'"
        ):
            mn.match_sequence_files(path)
        path = _sequence(tmp_path / "c", prefixes=["face_0000", "face_0001"])
        with pytest.raises(ValueError, match=r"frames\[0\].prefix: 'face_0000' must end in frame number 1"):
            mn.match_sequence_files(path)

    @pytest.mark.parametrize(
        ("text", "match"),
        [
            ("{", "invalid JSON"),
            ("[]", "expected a JSON object; got list"),
            ('{"frames": []}', "frames: must be a non-empty list"),
            ('{"frames": [{"prefix": "a/b"}]}', r"frames\[0\].prefix: must be a file name prefix"),
            ('{"frames": [{"frame": 1}]}', r"frames\[0\].prefix: must be a file name prefix"),
        ],
    )
    def test_malformed_json(self, tmp_path, text, match):
        path = tmp_path / "face_sequence.json"
        path.write_text(text)
        with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: {match}"):
            mn.match_sequence_files(path)

    def test_frame_without_maps(self, tmp_path):
        path = _sequence(tmp_path, kinds=("albedo",))
        with pytest.raises(FileNotFoundError, match="no normal map"):
            mn.match_sequence_files(path)
        (tmp_path / "x_sequence.json").write_text('{"frames": [{"prefix": "x_0001"}]}')
        with pytest.raises(FileNotFoundError, match=r"frame 1 has no map files x_0001_\*"):
            mn.match_sequence_files(tmp_path / "x_sequence.json")
