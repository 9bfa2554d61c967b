"""Scene spec: materials, objects, JSON round trips and validation errors."""

import json

import numpy as np
import pytest
import trimesh

from blender_addon.core import assets, placement, procedural
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec
from pbrdf.sensor.rig import CameraSpec, Rig


def _pose(x=0.0, y=0.0, z=-0.7, scale=0.2):
    m = np.diag([scale, scale, scale, 1.0])
    m[:3, 3] = [x, y, z]
    return m


def _scene(tmp_path=None) -> SceneSpec:
    table = "tables/brass.pbrdf"
    if tmp_path is not None:
        (tmp_path / "brass.pbrdf").write_bytes(b"placeholder")
        table = str(tmp_path / "brass.pbrdf")
    materials = (
        MaterialSpec.plastic("red_plastic", (0.8, 0.1, 0.1), 0.3, ior=1.49),
        MaterialSpec.metal("gold", (0.16, 0.43, 1.38), (3.5, 2.4, 1.9), 0.2),
        MaterialSpec.measured("brass", table, albedo=(0.6, 0.5, 0.2), roughness=0.4, metallic=1.0),
    )
    objects = (
        ObjectSpec("ball", "builtin:sphere", _pose(-0.1), "gold"),
        ObjectSpec("ring", "builtin:torus?seed=3&minor=0.3", _pose(0.12, 0.05, -0.8), "red_plastic"),
    )
    return SceneSpec(rig=Rig(), objects=objects, materials=materials, seed=42, metadata={"assets": ["a", "b"]})


class TestMaterial:
    def test_plastic(self):
        m = MaterialSpec.plastic("p", (0.5, 0.5, 0.5), 0.2)
        assert (m.kind, m.metallic, m.ior, m.eta, m.table) == ("pplastic", 0.0, 1.5, None, None)

    def test_metal_albedo_is_normal_incidence_reflectance(self):
        # R0 = ((n-1)^2 + k^2) / ((n+1)^2 + k^2); n = 1.5, k = 0 gives 0.04 (glass, Hecht "Optics").
        m = MaterialSpec.metal("m", (1.5, 1.5, 1.5), (0.0, 0.0, 0.0), 0.1)
        np.testing.assert_allclose(m.albedo, 0.04, rtol=1e-12)
        assert m.metallic == 1.0
        # Gold, Johnson & Christy 1972 (rounded) at 650/550/450 nm: about (0.95, 0.78, 0.40).
        gold = MaterialSpec.metal("au", (0.16, 0.43, 1.38), (3.5, 2.4, 1.9), 0.1)
        np.testing.assert_allclose(gold.albedo, (0.9529, 0.7796, 0.4048), atol=1e-4)
        given = MaterialSpec.metal("m2", (0.2, 0.2, 0.2), (3.0, 3.0, 3.0), 0.1, albedo=(0.9, 0.9, 0.9))
        assert given.albedo == (0.9, 0.9, 0.9)

    @pytest.mark.parametrize(
        "kwargs,match",
        [
            ({"albedo": (1.2, 0.1, 0.1)}, "albedo must be in"),
            ({"albedo": (0.1, 0.1)}, "albedo must have 3"),
            ({"roughness": 1.5}, "roughness must be in"),
            ({"metallic": -0.1}, "metallic must be in"),
            ({"kind": "glass"}, "unknown kind 'glass'"),
            ({"eta": (1, 1, 1)}, "eta is not used by kind 'pplastic'"),
            ({"ior": 0.0}, "ior must be > 0"),
            ({"name": ""}, "name must be a non-empty string"),
        ],
    )
    def test_invalid(self, kwargs, match):
        base = {"name": "x", "kind": "pplastic", "albedo": (0.5, 0.5, 0.5), "roughness": 0.5, "metallic": 0.0}
        with pytest.raises(ValueError, match=match):
            MaterialSpec(**{**base, **kwargs})

    def test_kind_requirements(self):
        with pytest.raises(ValueError, match="requires eta"):
            MaterialSpec("c", "conductor", (0.9, 0.9, 0.9), 0.1, 1.0, k=(1, 1, 1))
        with pytest.raises(ValueError, match="k must be >= 0"):
            MaterialSpec("c", "conductor", (0.9, 0.9, 0.9), 0.1, 1.0, eta=(1, 1, 1), k=(1, -1, 1))
        with pytest.raises(ValueError, match="requires table"):
            MaterialSpec("t", "measured", (0.9, 0.9, 0.9), 0.1, 1.0)
        with pytest.raises(ValueError, match="ior is not used by kind 'measured'"):
            MaterialSpec("t", "measured", (0.9, 0.9, 0.9), 0.1, 1.0, table="x", ior=1.5)


class TestObject:
    def test_invalid(self):
        with pytest.raises(ValueError, match="positive determinant"):
            ObjectSpec("o", "builtin:sphere", np.diag([-1.0, 1, 1, 1]), "m")
        with pytest.raises(ValueError, match="unknown builtin shape 'cone'"):
            ObjectSpec("o", "builtin:cone", np.eye(4), "m")
        with pytest.raises(ValueError, match="to_world must be a 4x4"):
            ObjectSpec("o", "builtin:sphere", np.eye(3), "m")
        with pytest.raises(ValueError, match="material must name"):
            ObjectSpec("o", "builtin:sphere", np.eye(4))

    def test_to_world_is_stored_as_nested_tuples(self):
        o = ObjectSpec("o", "builtin:sphere", _pose(), "m")
        assert isinstance(o.to_world, tuple) and all(isinstance(r, tuple) for r in o.to_world)
        np.testing.assert_array_equal(np.asarray(o.to_world), _pose())


class TestJson:
    def test_round_trip_exact(self):
        scene = _scene()
        d = json.loads(json.dumps(scene.to_dict()))
        back = SceneSpec.from_dict(d)
        assert back == scene
        assert back.to_dict() == scene.to_dict()

    def test_save_load(self, tmp_path):
        scene = _scene(tmp_path)
        path = tmp_path / "scene.json"
        scene.save(path)
        assert SceneSpec.load(path) == scene
        assert sorted(p.name for p in tmp_path.iterdir()) == ["brass.pbrdf", "scene.json"]

    def test_kind_fields_only(self):
        d = _scene().to_dict()["materials"]
        assert set(d[0]) == {"name", "kind", "albedo", "roughness", "metallic", "ior"}
        assert set(d[1]) == {"name", "kind", "albedo", "roughness", "metallic", "eta", "k"}
        assert set(d[2]) == {"name", "kind", "albedo", "roughness", "metallic", "table"}

    def test_partial_rig_and_defaults(self):
        scene = SceneSpec.from_dict({"rig": {"camera": {"focal_length": 0.012}}})
        assert scene.rig.camera.focal_length == 0.012 and scene.rig.display == Rig().display
        assert (scene.objects, scene.materials, scene.seed, scene.metadata) == ((), (), 0, {})

    def test_metadata_normalised_through_json(self):
        scene = SceneSpec(metadata={"ids": (1, 2)})
        assert scene.metadata == {"ids": [1, 2]}
        with pytest.raises(ValueError, match="JSON-serialisable"):
            SceneSpec(metadata={"x": object()})

    def test_errors(self, tmp_path):
        with pytest.raises(ValueError, match=r"unknown scene keys \['lamps'\]"):
            SceneSpec.from_dict({"lamps": []})
        with pytest.raises(ValueError, match=r"missing required keys \['material'\]"):
            SceneSpec.from_dict({"objects": [{"name": "o", "mesh": "builtin:sphere"}]})
        with pytest.raises(ValueError, match="unknown object keys"):
            SceneSpec.from_dict({"objects": [{"name": "o", "mesh": "m.ply", "material": "m", "pose": 1}]})
        with pytest.raises(ValueError, match="seed must be >= 0"):
            SceneSpec(seed=-1)
        with pytest.raises(ValueError, match="seed must be an integer"):
            SceneSpec.from_dict({"seed": "7"})
        with pytest.raises(FileNotFoundError, match="scene file not found"):
            SceneSpec.load(tmp_path / "none.json")
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({"materials": [{"name": "m", "kind": "pplastic"}]}))
        with pytest.raises(ValueError, match=r"bad.json: material 'm' is missing required keys"):
            SceneSpec.load(bad)


class TestValidate:
    def test_valid_scene(self, tmp_path):
        _scene(tmp_path).validate()

    def test_placed_objects_validate(self, rng):
        rig = Rig()
        objects = []
        for i, shape in enumerate(procedural.PROCEDURAL_SHAPES):
            mesh = f"builtin:{shape}?seed={i}"
            objects.append(ObjectSpec(f"o{i}", mesh, placement.place(assets.load_mesh(mesh), rig, rng), "p"))
        SceneSpec(rig=rig, objects=tuple(objects), materials=(MaterialSpec.plastic("p", (0.5,) * 3, 0.5),)).validate()

    def test_unknown_material(self):
        scene = _scene()
        bad = SceneSpec(objects=(ObjectSpec("o", "builtin:sphere", _pose(), "silver"),), materials=scene.materials)
        with pytest.raises(ValueError, match=r"object 'o' references unknown material 'silver'; known: \["):
            bad.validate()

    def test_duplicate_names(self):
        scene = _scene()
        dup = SceneSpec(objects=scene.objects + scene.objects[:1], materials=scene.materials)
        with pytest.raises(ValueError, match="duplicate object name 'ball'"):
            dup.validate()
        dup = SceneSpec(objects=scene.objects, materials=scene.materials + scene.materials[:1])
        with pytest.raises(ValueError, match="duplicate material name 'red_plastic'"):
            dup.validate()

    def test_missing_files(self, tmp_path):
        scene = _scene(tmp_path)
        missing_mesh = SceneSpec(
            objects=(ObjectSpec("o", str(tmp_path / "bunny.ply"), _pose(), "gold"),), materials=scene.materials
        )
        with pytest.raises(FileNotFoundError, match=r"object 'o': mesh file not found: .*bunny.ply"):
            missing_mesh.validate()
        missing_mesh.validate(check_files=False)  # file meshes are skipped without file checks
        with pytest.raises(FileNotFoundError, match="pBRDF table not found"):
            _scene().validate()  # relative table path that does not exist
        _scene().validate(check_files=False)

    def test_degenerate_mesh_file(self, tmp_path):
        path = tmp_path / "flat.obj"
        box = trimesh.creation.box()
        box.vertices[:, 2] = 0.0
        trimesh.Trimesh(box.vertices, box.faces, process=False).export(path)
        scene = SceneSpec(
            objects=(ObjectSpec("o", str(path), _pose(), "red_plastic"),), materials=(_scene().materials[0],)
        )
        with pytest.raises(ValueError, match="object 'o': .*degenerate mesh: flat"):
            scene.validate()

    def test_object_outside_the_view(self):
        mats = (_scene().materials[0],)
        # A unit-diameter sphere scaled to radius 0.1 m, its centre 0.7 m from the camera in the
        # horizontal plane at angle theta: its silhouette's right edge is at
        # u = W/2 + f tan(theta + asin(0.1 / 0.7)). Put that edge 100 px past the sensor edge.
        cam = CameraSpec()
        f = cam.focal_length_px
        theta = np.arctan((cam.sensor_width_px / 2 + 100) / f) - np.arcsin(0.1 / 0.7)
        x, z = 0.7 * np.sin(theta), -0.7 * np.cos(theta)
        scene = SceneSpec(
            objects=(ObjectSpec("ball", "builtin:sphere", _pose(x, 0, z), "red_plastic"),), materials=mats
        )
        with pytest.raises(ValueError, match=r"object 'ball' leaves the camera view by \d+\.\d px") as info:
            scene.validate()
        over = float(str(info.value).split(" by ")[1].split(" px")[0])
        assert 90 < over <= 100.05  # the mesh's vertices lie on the sphere, so inside its silhouette
        assert "\n" not in str(info.value)
        behind = SceneSpec(objects=(ObjectSpec("b", "builtin:sphere", _pose(z=0.7), "red_plastic"),), materials=mats)
        with pytest.raises(ValueError, match="object 'b' is not in front of the camera"):
            behind.validate()
