"""Assets keep their materials: glTF 2.0 / MTL materials as MaterialSpec with textures, one mesh per material.

Every input is written by the test: glTF files as JSON + .bin (or GLB) built here from numpy
arrays, PNGs from Pillow, OBJ + MTL as text. Expected values come from the glTF 2.0 and MTL
definitions (sRGB decoding, channel layout, UV flip), the complex Fresnel reflectance, or the
file's own arrays, never from the reader's code.
"""

from __future__ import annotations

import base64
import json
import struct

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")
PIL = pytest.importorskip("PIL.Image")

from blender_addon.core import asset_materials as am  # noqa: E402
from blender_addon.core import assets, scenegen  # noqa: E402
from blender_addon.core.spec import MaterialSpec, SceneSpec  # noqa: E402
from blender_addon.core.textures import texture_array  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402


@pytest.fixture(autouse=True)
def cache_dir(tmp_path, monkeypatch):
    """Embedded images go to a folder of the test, never to the user's cache."""
    monkeypatch.setenv("PBRDF_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "gltf-images"


# --------------------------------------------------------------------------- files written by the tests


def _srgb_to_linear(c):  # IEC 61966-2-1
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def png(path, rgb) -> bytes:
    """Write an 8-bit RGB PNG from ``(H, W, 3)`` uint8 values; returns its bytes."""
    PIL.fromarray(np.asarray(rgb, dtype=np.uint8)).save(path)
    return path.read_bytes()


def box_triangles(rng):
    """A closed axis-aligned box as 12 separate triangles (36 vertices) with random UVs in [0, 1]."""
    box = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    v = np.asarray(box.vertices)[np.asarray(box.faces)].reshape(-1, 3)
    return v, rng.uniform(0.0, 1.0, size=(len(v), 2))


def write_gltf(folder, name, prims, *, glb=False, images=(), **doc_fields):
    """A glTF 2.0 file with one mesh of the given primitives, under a translated node.

    Args:
        prims: dicts with ``v`` (N, 3), optional ``uv``/``uv1`` (N, 2, glTF's v down) and ``material``.
        images: ``("uri", file name)``, ``("view", png bytes)`` or ``("data", png bytes)``.
        doc_fields: top-level fields (``materials``, ``textures``, ``samplers``, ``extensionsRequired``, ...).
    """
    blob, views, accessors = bytearray(), [], []

    def view(data: bytes) -> int:
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob.extend(data)
        return len(views) - 1

    def accessor(arr, comp, kind) -> int:
        acc = {"bufferView": view(arr.tobytes()), "componentType": comp, "count": len(arr), "type": kind}
        if kind == "VEC3":
            acc.update(min=arr.min(axis=0).tolist(), max=arr.max(axis=0).tolist())
        accessors.append(acc)
        return len(accessors) - 1

    primitives = []
    for p in prims:
        v = np.asarray(p["v"], dtype=np.float32)
        attrs = {"POSITION": accessor(v, 5126, "VEC3")}
        for key, attr in (("uv", "TEXCOORD_0"), ("uv1", "TEXCOORD_1")):
            if p.get(key) is not None:
                attrs[attr] = accessor(np.asarray(p[key], dtype=np.float32), 5126, "VEC2")
        prim = {"attributes": attrs, "indices": accessor(np.arange(len(v), dtype=np.uint32), 5125, "SCALAR")}
        if p.get("material") is not None:
            prim["material"] = p["material"]
        primitives.append(prim)
    imgs = []
    for kind, value in images:
        if kind == "uri":
            imgs.append({"uri": value})
        elif kind == "view":
            imgs.append({"bufferView": view(value), "mimeType": "image/png"})
        else:
            imgs.append({"uri": "data:image/png;base64," + base64.b64encode(value).decode()})
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0, "translation": [0.1, 0.0, 0.0]}], "meshes": [{"primitives": primitives}],
           "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(blob)}],
           **doc_fields}  # fmt: skip
    if imgs:
        doc["images"] = imgs
    if glb:  # the GLB container written from its definition: header, JSON chunk, BIN chunk
        js = json.dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        blob.extend(b"\0" * (-len(blob) % 4))
        body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
        path = folder / f"{name}.glb"
        path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
        return path
    doc["buffers"][0]["uri"] = f"{name}.bin"
    (folder / f"{name}.bin").write_bytes(bytes(blob))
    path = folder / f"{name}.gltf"
    path.write_text(json.dumps(doc))
    return path


def two_material_box(folder, rng, materials, *, name="box", uv1=False, **kw):
    """A box whose first 6 triangles use material 0 and last 6 material 1 (two primitives)."""
    v, uv = box_triangles(rng)
    prims = [{"v": v[:18], "uv": uv[:18], "material": 0}, {"v": v[18:], "uv": uv[18:], "material": 1}]
    if uv1:
        for p in prims:
            p["uv1"] = 1.0 - p["uv"]
    return write_gltf(folder, name, prims, materials=materials, **kw), v, uv


def textured(base=None, mr=None, normal=None, **extra):
    pbr = {"metallicFactor": 0.0}
    if base is not None:
        pbr["baseColorTexture"] = base
    if mr is not None:
        pbr["metallicRoughnessTexture"] = mr
        pbr["metallicFactor"] = 1.0
    m = {"pbrMetallicRoughness": pbr, **extra}
    if normal is not None:
        m["normalTexture"] = normal
    return m


# --------------------------------------------------------------------------- glTF materials


class TestGltfMaterials:
    def test_factors_only_dielectric_and_default_metal(self, tmp_path, rng):
        plastic = {"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.1, 0.05, 1], "metallicFactor": 0,
                                                          "roughnessFactor": 0.25}}  # fmt: skip
        metal = {"pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.6, 0.3, 1]}}  # metallic and roughness default to 1
        path, *_ = two_material_box(tmp_path, rng, [plastic, metal])
        mats = am.read_materials(path).materials
        assert mats[0].kind == "pplastic" and mats[0].textures is None and mats[0].ior == 1.5
        assert mats[0].albedo == pytest.approx((0.8, 0.1, 0.05)) and mats[0].roughness == 0.25
        assert mats[1].kind == "conductor" and mats[1].metallic == 1.0 and mats[1].roughness == 1.0
        # The conductor reflects its base colour at normal incidence: the complex Fresnel |(n~ - 1)/(n~ + 1)|^2.
        n = np.asarray(mats[1].eta) - 1j * np.asarray(mats[1].k)
        np.testing.assert_allclose(np.abs((n - 1) / (n + 1)) ** 2, (0.9, 0.6, 0.3), atol=1e-9)
        assert MaterialSpec.metal("m", mats[1].eta, mats[1].k, 0.5).albedo == pytest.approx(mats[1].albedo, abs=1e-9)

    def test_textures_channels_means_and_transform(self, tmp_path, rng):
        base = rng.integers(0, 256, size=(4, 4, 3))
        mr = np.stack([np.full((4, 4), 200), rng.integers(0, 256, (4, 4)), rng.integers(0, 256, (4, 4))], -1)
        png(tmp_path / "base.png", base)
        png(tmp_path / "mr.png", mr)
        png(tmp_path / "n.png", np.full((4, 4, 3), (128, 128, 255)))
        transform = {"KHR_texture_transform": {"offset": [0.5, -0.25], "rotation": 0.3, "scale": [2.0, 3.0]}}
        m = textured(base={"index": 0, "extensions": transform}, mr={"index": 1}, normal={"index": 2, "scale": 0.6})
        m["pbrMetallicRoughness"].update(baseColorFactor=[0.5, 1.0, 0.8, 1.0], roughnessFactor=0.9, metallicFactor=0.7)
        images = [("uri", "base.png"), ("uri", "mr.png"), ("uri", "n.png")]
        textures = [{"source": 0}, {"source": 1}, {"source": 2}]
        path, *_ = two_material_box(tmp_path, rng, [m, textured()], images=images, textures=textures)
        mat = am.read_materials(path).materials[0]
        t = mat.textures
        assert mat.kind == "pplastic" and t.albedo.colorspace == "srgb" and t.roughness.colorspace == "linear"
        assert (t.roughness.channels, t.metallic.channels) == ((1,), (2,))  # glTF: roughness in G, metallic in B
        assert (t.albedo.offset, t.albedo.rotation, t.albedo.scale) == ((0.5, -0.25), 0.3, (2.0, 3.0))
        assert t.roughness.offset == (0.0, 0.0) and t.normal_scale == 0.6 and t.normal.channels == (0, 1, 2)
        expected = (_srgb_to_linear(base / 255.0) * (0.5, 1.0, 0.8)).mean(axis=(0, 1))
        np.testing.assert_allclose(mat.albedo, expected, atol=1e-6)
        assert mat.roughness == pytest.approx(0.9 * mr[..., 1].mean() / 255, abs=1e-6)
        assert mat.metallic == pytest.approx(0.7 * mr[..., 2].mean() / 255, abs=1e-6)
        np.testing.assert_allclose(texture_array(t.metallic)[..., 0], 0.7 * mr[..., 2] / 255, atol=1e-6)

    def test_notes_for_what_is_not_modelled(self, tmp_path, rng):
        mask = textured(alphaMode="MASK", alphaCutoff=0.3, extensions={"KHR_materials_sheen": {}})
        blend = textured(alphaMode="BLEND", emissiveFactor=[1, 0, 0], extensions={"KHR_materials_ior": {"ior": 1.7}})
        blend["pbrMetallicRoughness"]["metallicFactor"] = 0.3
        path, *_ = two_material_box(tmp_path, rng, [mask, blend], extensionsUsed=["KHR_materials_variants"])
        got = am.read_materials(path)
        notes = "\n".join(got.notes)
        assert "alphaMode MASK (alphaCutoff 0.3) rendered opaque (materials 0)" in notes
        assert "alphaMode BLEND rendered opaque (materials 1)" in notes
        assert "KHR_materials_sheen not modelled" in notes and "KHR_materials_variants not modelled" in notes
        assert "emission not modelled" in notes and "metallicFactor 0.3 without a texture rounded to 0" in notes
        assert "KHR_materials_ior" not in notes and got.materials[1].ior == 1.7 and got.materials[1].metallic == 0.0

    def test_required_extensions(self, tmp_path, rng):
        ok, *_ = two_material_box(tmp_path, rng, [textured(), textured()], extensionsRequired=["KHR_texture_transform"])
        assert am.read_materials(ok) is not None
        bad, *_ = two_material_box(tmp_path, rng, [textured(), textured()], name="bad",
                                   extensionsRequired=["KHR_materials_volume"])  # fmt: skip
        with pytest.raises(ValueError, match=rf"^{bad}: extensionsRequired names KHR_materials_volume"):
            am.read_materials(bad)

    def test_without_materials_is_none(self, tmp_path, rng):
        v, uv = box_triangles(rng)
        path = write_gltf(tmp_path, "plain", [{"v": v, "uv": uv}])
        assert am.read_materials(path) is None and am.asset_parts(path) is None
        ply = tmp_path / "box.ply"
        trimesh.creation.box().export(ply)
        assert am.read_materials(ply) is None

    @pytest.mark.parametrize("glb", [True, False])
    def test_embedded_images_are_extracted_once(self, tmp_path, rng, cache_dir, glb):
        data = png(tmp_path / "src.png", rng.integers(0, 256, size=(3, 5, 3)))
        kind = "view" if glb else "data"
        path, *_ = two_material_box(tmp_path, rng, [textured(base={"index": 0}), textured()], glb=glb,
                                    images=[(kind, data)], textures=[{"source": 0}])  # fmt: skip
        src = am.read_materials(path).materials[0].textures.albedo.source
        assert src.startswith(str(cache_dir)) and open(src, "rb").read() == data
        assert texture_array(am.read_materials(path).materials[0].textures.albedo).shape == (3, 5, 3)
        assert len(list(cache_dir.iterdir())) == 1

    def test_trimesh_export_with_a_pbr_texture(self, tmp_path):
        """A glTF another writer made (trimesh: PBRMaterial with a base-colour image, embedded in a GLB)."""
        img = np.zeros((2, 2, 3), np.uint8)
        img[0, 0] = (255, 255, 255)  # one white texel of four: mean linear albedo 0.25
        box = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=PIL.fromarray(img), metallicFactor=0.0)
        uv = np.random.default_rng(0).uniform(size=(len(box.vertices), 2))
        box.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
        path = tmp_path / "exported.glb"
        box.export(path)
        mat = am.read_materials(path).materials[0]
        assert mat.kind == "pplastic" and mat.albedo == pytest.approx((0.25, 0.25, 0.25), abs=1e-6)
        part = assets.load_mesh(f"{path}#material=0")
        got = np.unique(np.asarray(part.visual.uv).round(5), axis=0)  # hard edges split vertices, UVs repeat
        np.testing.assert_allclose(got, np.unique(uv.round(5), axis=0), atol=2e-5)


class TestBadInput:
    def _with_image(self, tmp_path, rng, images, textures, info=None):
        m = textured(base=info or {"index": 0})
        return two_material_box(tmp_path, rng, [m, textured()], images=images, textures=textures)[0]

    def test_missing_image_names_the_gltf_and_the_image(self, tmp_path, rng):
        path = self._with_image(tmp_path, rng, [("uri", "gone.png")], [{"source": 0}])
        with pytest.raises(ValueError, match=rf"^{path}: image 0 \(gone.png\): file not found"):
            am.read_materials(path)

    def test_not_an_image(self, tmp_path, rng):
        (tmp_path / "fake.png").write_bytes(b"GIF89a not a png")
        path = self._with_image(tmp_path, rng, [("uri", "fake.png")], [{"source": 0}])
        with pytest.raises(ValueError, match=rf"^{path}: image 0 .*not a PNG or JPEG"):
            am.read_materials(path)

    def test_truncated_png(self, tmp_path, rng):
        data = png(tmp_path / "full.png", rng.integers(0, 256, size=(64, 64, 3)))
        (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
        path = self._with_image(tmp_path, rng, [("uri", "cut.png")], [{"source": 0}])
        with pytest.raises(ValueError, match=rf"^{path}: texture image .*cut.png"):
            am.read_materials(path)

    def test_texture_and_image_index_out_of_range(self, tmp_path, rng):
        png(tmp_path / "a.png", np.zeros((2, 2, 3)))
        path = self._with_image(tmp_path, rng, [("uri", "a.png")], [{"source": 0}], info={"index": 5})
        with pytest.raises(ValueError, match=rf"^{path}: material 0: texture index 5 out of range \(the file has 1\)"):
            am.read_materials(path)
        path = self._with_image(tmp_path, rng, [("uri", "a.png")], [{"source": 3}])
        with pytest.raises(ValueError, match=rf"^{path}: image index 3 out of range \(the file has 1\)"):
            am.read_materials(path)

    def test_wrong_json_types_are_one_line(self, tmp_path, rng):
        path = self._with_image(tmp_path, rng, [], [], info=None)
        doc = json.loads(path.read_text())
        doc["materials"][0]["pbrMetallicRoughness"] = "zero"
        path.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=rf"^{path}: malformed material data"):
            am.read_materials(path)

    def test_nan_uvs_raise_and_huge_uvs_wrap(self, tmp_path, rng):
        v, uv = box_triangles(rng)
        nan = uv.copy()
        nan[3] = np.nan
        path = write_gltf(tmp_path, "nan", [{"v": v, "uv": nan, "material": 0}], materials=[textured()])
        with pytest.raises(ValueError, match=rf"^{path}: 1 UV coordinate NaN or infinite"):
            am.asset_parts(path)
        far = write_gltf(tmp_path, "far", [{"v": v, "uv": uv + 1e6, "material": 0}], materials=[textured()])
        part = assets.load_mesh(f"{far}#material=0")
        assert np.abs(part.visual.uv).max() <= 2 and "shifted by an integer" in part.metadata["uv_notes"][0]
        # An integer shift keeps every texel under REPEAT: the fractional parts are the file's.
        frac = np.sort(np.mod(np.asarray(part.visual.uv), 1.0), axis=0)
        expected = np.sort(np.mod(np.stack([uv[:, 0] + 1e6, 1 - (uv[:, 1] + 1e6)], -1).astype(np.float32), 1.0), 0)
        np.testing.assert_allclose(frac, expected, atol=1e-6)

    def test_bad_asset_is_left_out_of_a_pool(self, tmp_path, rng):
        good, *_ = two_material_box(tmp_path, rng, [textured(), textured()], name="good")
        bad = self._with_image(tmp_path, rng, [("uri", "gone.png")], [{"source": 0}])
        ok, refused = am.usable_textured_assets([good, bad])
        assert ok == [good] and list(refused) == [str(bad)] and "gone.png" in refused[str(bad)]


# --------------------------------------------------------------------------- one mesh per material


class TestParts:
    def test_two_materials_keep_their_uvs_and_make_up_the_whole(self, tmp_path, rng):
        path, v, uv = two_material_box(tmp_path, rng, [textured(), textured()])
        whole = assets.load_mesh(path)
        assert not assets._has_uv(whole)  # merged parts without a selector: as before, no UVs
        assert assets.material_keys(path) == [0, 1]
        parts = [assets.load_mesh(f"{path}#material={k}") for k in (0, 1)]
        shifted = v + (0.1, 0.0, 0.0)  # the node's translation
        for k, part in enumerate(parts):
            assert len(part.faces) == 6 and part.metadata["material"] == k
            # Each corner keeps the UV the file gave it, with glTF's v (down) turned into OpenGL's (up).
            corners = np.asarray(part.vertices)[part.faces].reshape(-1, 3)
            got = np.asarray(part.visual.uv)[part.faces].reshape(-1, 2)
            mine = slice(18 * k, 18 * k + 18)
            for p, t in zip(corners, got, strict=True):
                match = np.all(np.abs(shifted[mine] - p) < 1e-6, axis=1) & np.all(
                    np.abs(uv[mine] * (1, -1) + (0, 1) - t) < 1e-6, axis=1
                )
                assert match.any()
        union = np.concatenate([np.asarray(p.vertices)[p.faces] for p in parts]).reshape(-1, 9)
        plain = np.asarray(whole.vertices)[whole.faces].reshape(-1, 9)
        np.testing.assert_allclose(np.unique(union.round(6), axis=0), np.unique(plain.round(6), axis=0), atol=1e-9)
        assert all(p.metadata["two_sided"] == whole.metadata["two_sided"] for p in parts)

    def test_every_parts_uv_notes_are_kept_once(self, tmp_path, rng):
        v, uv = box_triangles(rng)
        prims = [{"v": v[:18], "uv": uv[:18] + 1e6, "material": 0}, {"v": v[18:], "uv": uv[18:] + 1e6, "material": 1}]
        path = write_gltf(tmp_path, "far2", prims, materials=[textured(), textured()])
        notes = [n for n in am.asset_parts(path).notes if "UVs beyond" in n]
        assert sorted(n[-12:] for n in notes) == ["(material 0)", "(material 1)"]

    def test_cleaning_keeps_each_face_with_its_material(self, tmp_path, rng):
        v, uv = box_triangles(rng)

        def junk(k):  # a degenerate face and a duplicate face before the primitive's own 6
            return np.concatenate([np.repeat(v[18 * k : 18 * k + 1], 3, axis=0), v[18 * k + 3 : 18 * k + 6]])

        prims = [{"v": np.concatenate([junk(k), v[18 * k : 18 * k + 18]]), "uv": np.concatenate([uv[:6], uv[:18]]),
                  "material": k} for k in (0, 1)]  # fmt: skip
        path = write_gltf(tmp_path, "junk", prims, materials=[textured(), textured()])
        assert len(assets.load_mesh(path).faces) == 12
        for k in (0, 1):  # each part has exactly its primitive's 6 faces
            part = assets.load_mesh(f"{path}#material={k}")
            centroid = np.asarray(part.vertices)[part.faces].mean(axis=1)
            own = v[18 * k : 18 * k + 18].reshape(-1, 3, 3).mean(axis=1) + (0.1, 0, 0)
            np.testing.assert_allclose(np.sort(centroid, axis=0), np.sort(own, axis=0), atol=1e-6)

    def test_textures_on_uv_set_1_read_texcoord_1(self, tmp_path, rng):
        png(tmp_path / "a.png", np.zeros((2, 2, 3)))
        m = textured(base={"index": 0, "texCoord": 1})
        path, v, uv = two_material_box(tmp_path, rng, [m, textured()], uv1=True, images=[("uri", "a.png")],
                                       textures=[{"source": 0}])  # fmt: skip
        part = assets.load_mesh(f"{path}#material=0")
        got = np.sort(np.asarray(part.visual.uv), axis=0)
        np.testing.assert_allclose(got, np.sort((1.0 - uv[:18]) * (1, -1) + (0, 1), axis=0), atol=1e-6)
        mixed = textured(base={"index": 0, "texCoord": 1}, normal={"index": 0})
        path2, *_ = two_material_box(tmp_path, rng, [mixed, textured()], name="mixed", uv1=True,
                                     images=[("uri", "a.png")], textures=[{"source": 0}])  # fmt: skip
        got = am.read_materials(path2)
        assert got.materials[0].textures.albedo is None and got.materials[0].textures.normal is not None
        assert any("UV set 1 dropped" in n for n in got.notes)

    def test_triangles_without_material_and_bad_selectors(self, tmp_path, rng):
        v, uv = box_triangles(rng)
        prims = [{"v": v[:18], "uv": uv[:18], "material": 0}, {"v": v[18:], "uv": uv[18:]}]
        path = write_gltf(tmp_path, "half", prims, materials=[textured()])
        parts = am.asset_parts(path).parts
        assert [(p.key, p.mesh.endswith(s)) for p, s in zip(parts, ("#material=0", "#material=none"), strict=True)] == [
            (0, True), (assets.MATERIAL_NONE, True)]  # fmt: skip
        assert parts[0].material is not None and parts[1].material is None
        assert len(assets.load_mesh(parts[1].mesh).faces) == 6
        with pytest.raises(ValueError, match=r"no triangles with material 7; materials with triangles: \[0, -1\]"):
            assets.load_mesh(f"{path}#material=7")
        with pytest.raises(ValueError, match="bad material selector"):
            assets.load_mesh(f"{path}#material=x")

    def test_random_scene_places_one_object_per_material(self, tmp_path, rng):
        blue = {"pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.2, 0.9, 1], "metallicFactor": 0}}
        path, *_ = two_material_box(tmp_path, rng, [blue, {"alphaMode": "BLEND"}])
        rig = Rig()
        plain = scenegen.random_scene(rig, 3, asset_files=[path], objects=(2, 2))
        assert scenegen.random_scene(rig, 3, asset_files=[path], objects=(2, 2), asset_materials=False) == plain
        assert [o.mesh for o in plain.objects] == [str(path)] * 2 and plain.metadata == {}
        spec = scenegen.random_scene(rig, 3, asset_files=[path], objects=(2, 2), asset_materials=True)
        names = [o.name for o in spec.objects]
        assert names == ["object_part0", "object_part1", "object_2_part0", "object_2_part1"]
        assert [o.mesh.rsplit("#", 1)[1] for o in spec.objects] == ["material=0", "material=1"] * 2
        assert spec.objects[0].to_world == spec.objects[1].to_world != spec.objects[2].to_world
        first = spec.material(spec.objects[0].material)
        assert first.albedo == pytest.approx((0.1, 0.2, 0.9)) and first.kind == "pplastic"
        assert spec.material(spec.objects[1].material).kind == "conductor"  # glTF's default metallic 1
        assert spec.metadata["asset_notes"][str(path)] == ["alphaMode BLEND rendered opaque (materials 1)"]
        assert SceneSpec.from_dict(json.loads(json.dumps(spec.to_dict()))) == spec
        spec.validate(check_files=True)  # the selector's file exists, every part is in view


@pytest.mark.mitsuba
def test_parts_render_the_geometry_of_the_whole(tmp_path, rng):
    """One object per material covers the pixels of the asset as one object, with the depth and normals."""
    from blender_addon.core import placement, render
    from blender_addon.core.spec import ObjectSpec

    path, *_ = two_material_box(tmp_path, rng, [textured(), textured()])
    rig = Rig()
    pose = tuple(map(tuple, placement.place(assets.load_mesh(path), rig, np.random.default_rng(4), distance=(0.6, 0.6),
                                            size=(0.3, 0.3))))  # fmt: skip
    grey = MaterialSpec.plastic("grey", (0.5, 0.5, 0.5), roughness=0.3)
    whole = SceneSpec(rig=rig, objects=(ObjectSpec("o", str(path), pose, "grey"),), materials=(grey,), seed=1)
    parts = (ObjectSpec("a", f"{path}#material=0", pose, "grey"), ObjectSpec("b", f"{path}#material=1", pose, "grey"))
    split = SceneSpec(rig=rig, objects=parts, materials=(grey,), seed=1)
    settings = render.RenderSettings(resolution=64, spp=4)
    one, two = render.render_stokes(whole, settings), render.render_stokes(split, settings)
    assert np.array_equal(one.mask, two.mask) and one.mask.sum() > 100
    assert set(np.unique(two.object_index[two.mask])) == {0, 1}  # the ground truth tells the parts apart
    np.testing.assert_allclose(two.depth[two.mask], one.depth[one.mask], atol=1e-4)
    inner = one.mask & (np.abs(np.diff(np.pad(two.object_index, 1, mode="edge"), axis=1))[1:-1, 1:] == 0)
    np.testing.assert_allclose(two.normal[inner], one.normal[inner], atol=1e-3)


# --------------------------------------------------------------------------- OBJ + MTL


def test_obj_mtl_map_kd_and_kd(tmp_path, rng):
    img = rng.integers(0, 256, size=(4, 4, 3))
    png(tmp_path / "wood.png", img)
    v, uv = box_triangles(rng)
    lines = ["mtllib box.mtl"] + [f"v {x} {y} {z}" for x, y, z in v] + [f"vt {a} {b}" for a, b in uv]
    for k, mat in ((0, "plain"), (1, "wood")):
        lines.append(f"usemtl {mat}")
        lines += [
            f"f {3 * i + 1}/{3 * i + 1} {3 * i + 2}/{3 * i + 2} {3 * i + 3}/{3 * i + 3}"
            for i in range(6 * k, 6 * k + 6)
        ]
    (tmp_path / "box.obj").write_text("\n".join(lines) + "\n")
    mtl = ["newmtl plain", "Kd 0.2 0.4 0.6", "Ks 0.5 0.5 0.5", "Ns 50", "Ka 1 1 1",
           "newmtl wood", "Kd 0.5 0.5 0.5", "map_Kd -s 2 4 1 -o 0.25 0.5 0 -bm 1 .\\wood.png"]  # fmt: skip
    (tmp_path / "box.mtl").write_text("\n".join(mtl) + "\n")
    got = am.read_materials(tmp_path / "box.obj")
    plain, wood = got.materials
    assert plain.kind == "pplastic" and plain.albedo == pytest.approx((0.2, 0.4, 0.6)) and plain.textures is None
    tex = wood.textures.albedo
    assert tex.colorspace == "srgb" and tex.factor == (0.5, 0.5, 0.5)  # map_Kd times Kd, as MTL defines
    np.testing.assert_allclose(wood.albedo, 0.5 * _srgb_to_linear(img / 255).mean(axis=(0, 1)), atol=1e-6)
    # MTL's -s/-o act on OpenGL UVs: uv' = s uv + o.
    np.testing.assert_allclose(tex.uv_matrix() @ [0.3, 0.7, 1.0], [2 * 0.3 + 0.25, 4 * 0.7 + 0.5, 1.0], atol=1e-12)
    notes = "\n".join(got.notes)
    assert "Ks not modelled" in notes and "Ns not modelled" in notes and "-bm ignored" in notes and "Ka" not in notes
    parts = am.asset_parts(tmp_path / "box.obj").parts
    assert [p.key for p in parts] == [0, 1] and parts[1].material == wood
    part = assets.load_mesh(parts[1].mesh)
    np.testing.assert_allclose(np.sort(part.visual.uv, axis=0), np.sort(uv[18:], axis=0), atol=1e-6)  # OBJ: v up
    (tmp_path / "wood.png").unlink()
    (tmp_path / "box.obj").touch()  # a new modification time: read again
    with pytest.raises(ValueError, match=r"box.obj: MTL material 'wood': map_Kd file not found"):
        am.read_materials(tmp_path / "box.obj")


def test_a_factor_only_metal_reflects_its_base_colour(tmp_path):
    """metallicFactor 1 without a texture: a conductor whose normal-incidence Fresnel reflectance is the base colour."""
    colour = [0.91, 0.5, 0.04]
    m = am._metal("m", tuple(colour), 0.3, None)
    eta = np.asarray(m.eta) - 1j * np.asarray(m.k)
    r0 = np.abs((eta - 1) / (eta + 1)) ** 2  # complex Fresnel at normal incidence, an independent formula
    np.testing.assert_allclose(r0, colour, atol=1e-12)
    assert m.kind == "conductor" and m.metallic == 1.0
