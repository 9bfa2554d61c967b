"""Assets: mesh references, loading and cleaning files, UVs, PLY for Mitsuba."""

import numpy as np
import pytest
import trimesh

from blender_addon.core import assets
from blender_addon.core.procedural import procedural


class TestBuiltinStrings:
    def test_builtin_strings(self):
        assert assets.parse_builtin("builtin:torus?seed=3&minor=0.3&name=x") == (
            "torus",
            {"seed": 3, "minor": 0.3, "name": "x"},
        )
        assert assets.parse_builtin("builtin:sphere") == ("sphere", {})
        assert assets.parse_builtin("meshes/bunny.ply") is None
        a = assets.load_mesh("builtin:torus?seed=3")
        np.testing.assert_allclose(a.vertices, procedural("torus", seed=3).vertices, rtol=0, atol=1e-14)  # SIMD: 1 ulp


class TestLoad:
    def test_two_part_glb_merges_with_transforms(self, tmp_path):
        a = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
        b = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
        ta = trimesh.transformations.translation_matrix([5.0, 0.0, 0.0])
        tb = trimesh.transformations.rotation_matrix(0.5, [0, 0, 1], point=[0, 0, 0]) @ np.diag([2.0, 2, 2, 1])
        scene = trimesh.Scene()
        scene.add_geometry(a, node_name="a", transform=ta)
        scene.add_geometry(b, node_name="b", transform=tb)
        path = tmp_path / "two.glb"
        scene.export(path)
        m = assets.load_mesh(path)
        # Two boxes, 8 + 8 corners; hard edges split each corner into 3 render vertices.
        assert len(m.vertices) == 48 and len(m.faces) == 24 and m.metadata["bodies"] == 2
        expected = np.concatenate([trimesh.transform_points(a.vertices, ta), trimesh.transform_points(b.vertices, tb)])
        corners = np.unique(np.round(np.asarray(m.vertices), 5), axis=0)
        np.testing.assert_allclose(np.sort(corners, axis=0), np.sort(expected, axis=0), atol=1e-5)
        assert m.volume == pytest.approx(6.0 + 8.0, rel=1e-6)
        assert not m.metadata["two_sided"]

    @pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb", ".gltf"])
    def test_formats(self, tmp_path, suffix):
        box = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
        path = tmp_path / f"box{suffix}"
        if suffix == ".gltf":
            for name, data in trimesh.Scene(box).export(file_type="gltf").items():
                (tmp_path / name).write_bytes(data)
            path = tmp_path / "model.gltf"
        else:
            box.export(path)
        m = assets.load_mesh(path)
        assert len(np.unique(np.asarray(m.vertices), axis=0)) == 8 and len(m.faces) == 12
        assert not m.metadata["two_sided"] and m.volume == pytest.approx(0.006, rel=1e-6)

    def test_cleaning(self, tmp_path):
        box = trimesh.creation.box()
        # Unmerged triangle soup, a duplicate face, a degenerate face and an unused vertex.
        v = np.concatenate([box.vertices[box.faces].reshape(-1, 3), [[9.0, 9.0, 9.0]]])
        f = np.arange(36).reshape(12, 3)
        f = np.concatenate([f, f[:1], [[0, 0, 1]]])
        path = tmp_path / "soup.ply"
        trimesh.Trimesh(v, f, process=False).export(path)
        m = assets.load_mesh(path)
        # 8 corners x 3 faces meeting at hard edges = 24 render vertices; welded, the box is closed.
        assert (len(m.vertices), len(m.faces)) == (24, 12) and not m.metadata["two_sided"]

    def test_inside_out_mesh_is_flipped(self, tmp_path):
        box = trimesh.creation.box()
        box.invert()
        path = tmp_path / "inv.ply"
        box.export(path)
        assert assets.load_mesh(path).volume == pytest.approx(1.0)

    def test_degenerate_inputs(self, tmp_path):
        empty = tmp_path / "empty.ply"
        empty.write_bytes(b"")
        with pytest.raises(ValueError, match=r"empty.ply: degenerate mesh: empty file"):
            assets.load_mesh(empty)
        tri = tmp_path / "tri.ply"
        trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False).export(tri)
        with pytest.raises(ValueError, match=r"degenerate mesh: only 1 non-degenerate face "):
            assets.load_mesh(tri)
        flat = tmp_path / "flat.obj"
        box = trimesh.creation.box()
        box.vertices[:, 2] = 0.0
        trimesh.Trimesh(box.vertices, box.faces, process=False).export(flat)
        with pytest.raises(ValueError, match=r"degenerate mesh: flat: thickness along z is 0 "):
            assets.load_mesh(flat)
        nan = tmp_path / "nan.obj"
        v = np.array(trimesh.creation.box().vertices)
        v[0] = np.nan
        lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in box.faces]
        nan.write_text("\n".join(lines) + "\n")
        with pytest.raises(ValueError, match=r"degenerate mesh: 1 vertex with NaN"):
            assets.load_mesh(nan)
        lines_only = tmp_path / "lines.obj"
        lines_only.write_text("v 0 0 0\nv 1 0 0\nl 1 2\n")
        with pytest.raises(ValueError, match=r"degenerate mesh: no triangle geometry"):
            assets.load_mesh(lines_only)

    def test_file_errors(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="mesh file not found"):
            assets.load_mesh(tmp_path / "missing.glb")
        fbx = tmp_path / "x.fbx"  # FBX: only inside Blender
        fbx.write_text("x")
        with pytest.raises(ValueError, match=r"unsupported mesh type '.fbx'"):
            assets.load_mesh(fbx)
        stl = tmp_path / "x.stl"
        stl.write_text("solid x\nendsolid x\n")
        with pytest.raises(ValueError, match=r"x.stl: degenerate mesh: no triangle geometry"):
            assets.load_mesh(stl)
        junk = tmp_path / "junk.glb"
        junk.write_bytes(b"definitely not a glb")
        with pytest.raises(ValueError, match=r"junk.glb: cannot read mesh"):
            assets.load_mesh(junk)


class TestMaterialSelectors:
    def test_split_mesh_ref(self, tmp_path):
        assert assets.split_mesh_ref(tmp_path / "a.gltf#material=12") == (str(tmp_path / "a.gltf"), 12)
        assert assets.split_mesh_ref("dir#material=1/a.obj") == ("dir#material=1/a.obj", None)  # not at the end
        assert assets.split_mesh_ref("builtin:torus?seed=3") == ("builtin:torus?seed=3", None)
        assert assets.mesh_file("x.glb#material=none") == "x.glb"
        with pytest.raises(ValueError, match="bad material selector"):
            assets.split_mesh_ref("x.glb#material=-2")

    def test_selector_needs_a_file_with_materials(self, tmp_path):
        path = tmp_path / "box.ply"
        trimesh.creation.box().export(path)
        with pytest.raises(ValueError, match=rf"^{path}: material selectors need a glTF/GLB or OBJ file"):
            assets.load_mesh(f"{path}#material=0")
        with pytest.raises(FileNotFoundError, match="mesh file not found"):
            assets.load_mesh(f"{tmp_path / 'gone.glb'}#material=0")

    def test_scene_validation_reads_the_file_of_a_selector(self, tmp_path):
        from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec

        mat = MaterialSpec.plastic("m", (0.5, 0.5, 0.5), 0.3)
        obj = ObjectSpec("o", f"{tmp_path / 'gone.gltf'}#material=0", material="m")
        with pytest.raises(FileNotFoundError, match=r"mesh file not found: .*gone.gltf#material=0"):
            SceneSpec(objects=(obj,), materials=(mat,)).validate()


class TestEnsureUV:
    def test_ensure_uv(self):
        m = procedural("sphere", subdivisions=2)
        out = assets.ensure_uv(m)
        uv = np.asarray(out.visual.uv)
        assert uv.shape == (len(out.vertices), 2)
        assert uv.min() >= 0.0 and uv.max() <= 1.0
        assert len(out.faces) == len(m.faces)
        # Seam vertices are copies of original vertices with the original normals.
        idx = np.array([np.argmin(np.linalg.norm(m.vertices - p, axis=1)) for p in out.vertices])
        np.testing.assert_array_equal(out.vertices, np.asarray(m.vertices)[idx])
        np.testing.assert_allclose(out.vertex_normals, np.asarray(m.vertex_normals)[idx], atol=1e-12)
        assert out.volume == pytest.approx(m.volume, rel=1e-12)
        assert assets.ensure_uv(out) is out  # already has UVs


class TestFiles:
    def test_list_assets(self, tmp_path):
        for name in ["b/z.GLB", "a.obj", "b/a.ply", "c.gltf", "notes.txt", "d.stl", "b/c/m.glb"]:
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name).write_bytes(b"x")
        found = [p.relative_to(tmp_path).as_posix() for p in assets.list_assets(tmp_path)]
        assert found == ["a.obj", "b/a.ply", "b/c/m.glb", "b/z.GLB", "c.gltf", "d.stl"]
        with pytest.raises(FileNotFoundError, match="asset folder not found"):
            assets.list_assets(tmp_path / "nope")

    def test_write_ply_round_trip(self, tmp_path):
        m = assets.ensure_uv(procedural("blob", seed=2, subdivisions=2))
        path = tmp_path / "out" / "blob.ply"
        assets.write_ply(m, path)
        assert [p.name for p in path.parent.iterdir()] == ["blob.ply"]  # no temporary file left
        back = trimesh.load(path, process=False)
        np.testing.assert_array_equal(back.vertices, np.asarray(m.vertices, dtype=np.float32))
        np.testing.assert_array_equal(back.faces, m.faces)
        assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")

    @pytest.mark.mitsuba
    def test_mitsuba_loads_the_ply(self, tmp_path, mitsuba_rgb):
        mi = mitsuba_rgb
        for name, mesh in [
            ("plain", procedural("torus", seed=1)),
            ("uv", assets.ensure_uv(procedural("sphere", subdivisions=2))),
        ]:
            path = tmp_path / f"{name}.ply"
            assets.write_ply(mesh, path)
            shape = mi.load_dict({"type": "ply", "filename": str(path)})
            assert shape.vertex_count() == len(mesh.vertices)
            assert shape.face_count() == len(mesh.faces)
            assert shape.has_vertex_normals()
            assert shape.has_vertex_texcoords() == (name == "uv")
            params = mi.traverse(shape)
            pos = np.asarray(params["vertex_positions"]).reshape(-1, 3)
            np.testing.assert_array_equal(pos, np.asarray(mesh.vertices, dtype=np.float32))
            nrm = np.asarray(params["vertex_normals"]).reshape(-1, 3)
            np.testing.assert_allclose(nrm, mesh.vertex_normals, atol=1e-6)
