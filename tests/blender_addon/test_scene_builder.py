"""The Objaverse-like scene builder in real Blender: Blender's importers, placement, materials."""

import json
import math

import numpy as np
import pytest

# The add-on registered once per module (tests/conftest.py), an empty Blender file for each test.
pytestmark = [pytest.mark.bpy, pytest.mark.usefixtures("addon_registered", "empty_blend_file")]
bpy = pytest.importorskip("bpy")
trimesh = pytest.importorskip("trimesh")

from blender_addon import rig_bpy, scene_builder  # noqa: E402
from blender_addon.core import scenegen  # noqa: E402
from blender_addon.core.spec import MaterialSpec  # noqa: E402
from tests.helpers import world_matrix  # noqa: E402

# Source meshes with distinct bounding-box proportions (in their own units and placement).
SOURCES = {
    "box.glb": lambda: trimesh.creation.box(extents=(2.0, 1.0, 0.5)),
    "sphere.obj": lambda: trimesh.creation.icosphere(subdivisions=2, radius=3.0),
    "cylinder.ply": lambda: trimesh.creation.cylinder(radius=0.2, height=1.0, sections=24),
}


@pytest.fixture(scope="module")
def asset_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("assets")
    for name, make in SOURCES.items():
        mesh = make()
        mesh.apply_translation((5.0, -2.0, 1.0))  # off-centre: the importer result must be re-centred
        mesh.export(folder / name)
    (folder / "notes.txt").write_text("not an asset")
    return folder


@pytest.fixture(scope="module")
def library_dir(tmp_path_factory):
    from pbrdf.brdf import seeds, table

    folder = tmp_path_factory.mktemp("library")
    entries = []
    for mat, albedo, metallic in (
        (seeds.SEED_MATERIALS[3], (0.6, 0.05, 0.04), 0.0),
        (seeds.SEED_MATERIALS[14], (0.9, 0.7, 0.3), 1.0),
    ):
        table.save_table(folder / f"{mat.name}.pbsdf", seeds.seed_table(mat, grid=(4, 4, 6)))
        entries.append(
            {
                "name": mat.name,
                "table": f"{mat.name}.pbsdf",
                "albedo": list(albedo),
                "roughness": mat.roughness,
                "metallic": metallic,
            }
        )
    (folder / "materials.json").write_text(json.dumps(entries))
    return folder


def _rig_frame(root, obj):
    return np.linalg.inv(world_matrix(root)) @ world_matrix(obj)


def _principled(obj):
    mat = obj.material_slots[0].material
    return mat, next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")


def test_operator_builds_objects_in_view(asset_dir):
    assert bpy.ops.pdir.build_scene(folder=str(asset_dir), count=5, seed=11) == {"FINISHED"}
    scene = bpy.context.scene
    root = rig_bpy.find_rig_root(scene)  # the builder adds a default rig when there is none
    assert root is not None
    rig = rig_bpy.rig_from_blender(root)
    cam = rig.camera
    objs = [o for o in scene.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]
    assert len(objs) == 5
    for obj in objs:
        assert obj.parent == root
        assert obj["pdir_asset"].endswith(tuple(SOURCES))
        m = _rig_frame(root, obj)
        # Every corner of the object's bounding box projects inside the sensor, in front of the camera.
        corners = np.array([tuple(c) for c in obj.bound_box])
        pts = corners @ m[:3, :3].T + m[:3, 3]
        uv, depth = cam.project(pts)
        assert np.all(depth > 0)
        assert np.all((uv[:, 0] >= 0) & (uv[:, 0] <= cam.sensor_width_px)), uv
        assert np.all((uv[:, 1] >= 0) & (uv[:, 1] <= cam.sensor_height_px)), uv
        # The bounding-box centre is 0.5-1.0 m from the camera centre.
        centre = pts.mean(axis=0)
        dist = np.linalg.norm(centre - cam.camera_to_world()[:3, 3])
        assert 0.5 - 1e-6 <= dist <= 1.0 + 1e-6
        # Uniform scale = the bounding-box diagonal in metres, within the default 0.15-0.35 m.
        diag = np.linalg.norm(pts[6] - pts[0])
        assert 0.15 - 1e-6 <= diag <= 0.35 + 1e-6
        sx, sy, sz = obj.matrix_world.to_scale()
        assert sx == pytest.approx(sy, rel=1e-5) and sx == pytest.approx(sz, rel=1e-5)


def test_same_seed_same_scene(asset_dir):
    scene = bpy.context.scene

    def snapshot():
        objs = scene_builder.build_scene(scene, asset_dir, 4, seed=5)
        return [(o["pdir_asset"], o["pdir_material"], np.array(o.matrix_basis)) for o in objs]

    first, second = snapshot(), snapshot()
    assert len([o for o in scene.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]) == 4  # replaced
    for a, b in zip(first, second, strict=True):
        assert a[:2] == b[:2]
        np.testing.assert_array_equal(a[2], b[2])
    other = scene_builder.build_scene(scene, asset_dir, 4, seed=6)
    assert not all(np.allclose(np.array(o.matrix_basis), s[2]) for o, s in zip(other, first, strict=True))
    assert scene["pdir_seed"] == 6
    kept = scene_builder.build_scene(scene, asset_dir, 2, seed=7, replace=False)
    assert len([o for o in scene.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]) == 6
    assert len(kept) == 2


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_import_normalises_each_format(asset_dir, name):
    mesh = scene_builder.import_asset(asset_dir / name)
    try:
        v = np.array([tuple(x.co) for x in mesh.vertices])
        lo, hi = v.min(axis=0), v.max(axis=0)
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
        assert np.linalg.norm(hi - lo) == pytest.approx(1.0, abs=1e-6)
        # Proportions survive the importer's axis conversion (compared sorted: axes may be swapped).
        src = SOURCES[name]()
        expected = np.sort(src.extents) / np.linalg.norm(src.extents)
        np.testing.assert_allclose(np.sort(hi - lo), expected, atol=1e-5)
        assert len(mesh.polygons) > 0 and len(mesh.materials) == 0
    finally:
        bpy.data.meshes.remove(mesh)
    # The importer's own objects and data are gone again.
    assert len(bpy.data.objects) == 0 and len(bpy.data.materials) == 0


def test_library_materials_are_principled_previews(asset_dir, library_dir):
    library = {m.name: m for m in scenegen.load_material_library(library_dir)}
    assert bpy.ops.pdir.build_scene(folder=str(asset_dir), count=6, seed=3, library=str(library_dir)) == {"FINISHED"}
    objs = [o for o in bpy.context.scene.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]
    used = set()
    for obj in objs:
        spec = library[obj["pdir_material"]]
        used.add(spec.name)
        mat, bsdf = _principled(obj)
        np.testing.assert_allclose(bsdf.inputs["Base Color"].default_value[:3], spec.albedo, atol=1e-6)
        assert bsdf.inputs["Roughness"].default_value == pytest.approx(spec.roughness, abs=1e-6)
        assert bsdf.inputs["Metallic"].default_value == pytest.approx(spec.metallic, abs=1e-6)
        assert scene_builder.material_spec_of(mat) == spec  # the exporter's source of truth
    # Objects sharing a library entry share one Blender material.
    assert len({o.material_slots[0].material.name for o in objs}) == len(used)


def test_default_materials_are_analytic(asset_dir):
    objs = scene_builder.build_scene(bpy.context.scene, asset_dir, 4, seed=2)
    for obj in objs:
        mat, bsdf = _principled(obj)
        spec = scene_builder.material_spec_of(mat)
        assert isinstance(spec, MaterialSpec) and spec.kind in ("pplastic", "conductor")
        assert spec.name == obj["pdir_material"]
        assert spec.metallic == (1.0 if spec.kind == "conductor" else 0.0)
        np.testing.assert_allclose(bsdf.inputs["Base Color"].default_value[:3], spec.albedo, atol=1e-6)
        assert bsdf.inputs["Roughness"].default_value == pytest.approx(spec.roughness, abs=1e-6)
        assert bsdf.inputs["Metallic"].default_value == pytest.approx(spec.metallic, abs=1e-6)
        if spec.kind == "conductor":  # metals carry the normal-incidence Fresnel reflectance as albedo
            n, k = np.asarray(spec.eta), np.asarray(spec.k)
            np.testing.assert_allclose(spec.albedo, ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), atol=1e-12)


def test_objects_follow_the_rig_root(asset_dir):
    scene = bpy.context.scene
    objs = scene_builder.build_scene(scene, asset_dir, 2, seed=4)
    root = rig_bpy.find_rig_root(scene)
    before = [_rig_frame(root, o) for o in objs]
    root.location = (1.0, 2.0, 0.5)
    root.rotation_euler = (math.pi / 2, 0.0, 0.7)
    for obj, m in zip(objs, before, strict=True):
        np.testing.assert_allclose(_rig_frame(root, obj), m, atol=1e-6)
        np.testing.assert_allclose(rig_bpy.to_rig_frame(root, obj), m, atol=1e-6)


def test_errors_are_one_line_reports(tmp_path, asset_dir):
    with pytest.raises(RuntimeError, match="no assets"):
        bpy.ops.pdir.build_scene(folder=str(tmp_path), count=1, seed=0)
    with pytest.raises(RuntimeError, match="asset folder not found"):
        bpy.ops.pdir.build_scene(folder=str(tmp_path / "missing"), count=1, seed=0)
    with pytest.raises(RuntimeError, match="Choose an asset folder"):
        bpy.ops.pdir.build_scene(folder="", count=1, seed=0)
    with pytest.raises(FileNotFoundError, match="materials.json"):
        scene_builder.build_scene(bpy.context.scene, asset_dir, 1, 0, library=tmp_path)
    with pytest.raises(ValueError, match="count"):
        scene_builder.build_scene(bpy.context.scene, asset_dir, 0, 0)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n")
    with pytest.raises(ValueError, match="bad.ply"):
        scene_builder.import_asset(bad)
    # Nothing was left behind by the failures.
    assert not [o for o in bpy.data.objects if o.get(rig_bpy.ROLE_KEY) == "scene_object"]


def test_hard_edges_survive_as_custom_split_normals(tmp_path):
    path = tmp_path / "cube.stl"  # STL has no normals: the pipeline's crease-angle normals apply
    trimesh.creation.box(extents=(1.0, 2.0, 3.0)).export(path)
    mesh = scene_builder.import_asset(path)
    try:
        assert len(mesh.vertices) == 8 and len(mesh.polygons) == 12  # welded topology
        corner = np.empty(3 * len(mesh.loops), dtype=np.float32)
        mesh.corner_normals.foreach_get("vector", corner)
        face = np.empty(3 * len(mesh.polygons), dtype=np.float32)
        mesh.polygons.foreach_get("normal", face)
        loop_face = np.repeat(np.arange(len(mesh.polygons)), 3)
        cos = np.einsum("ij,ij->i", corner.reshape(-1, 3), face.reshape(-1, 3)[loop_face])
        assert cos.min() > np.cos(np.radians(0.5))  # every corner keeps its flat face's normal
    finally:
        bpy.data.meshes.remove(mesh)


def test_bad_files_are_skipped_not_fatal(tmp_path, asset_dir):
    folder = tmp_path / "mixed"
    folder.mkdir()
    (folder / "good.glb").write_bytes((asset_dir / "box.glb").read_bytes())
    (folder / "empty.obj").write_bytes(b"")
    (folder / "card.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\nf 1 2 4\nf 2 3 4\n")
    skipped: dict = {}
    objs = scene_builder.build_scene(bpy.context.scene, folder, 6, seed=1, skipped=skipped)
    assert len(objs) == 6 and all(o["pdir_asset"].endswith("good.glb") for o in objs)
    assert set(map(lambda p: p.rsplit("/", 1)[-1], skipped)) <= {"empty.obj", "card.obj"} and skipped
    for reason in skipped.values():
        assert "degenerate mesh" in reason and "\n" not in reason
    (folder / "good.glb").unlink()
    with pytest.raises(ValueError, match="every asset file was refused"):
        scene_builder.build_scene(bpy.context.scene, folder, 1, seed=1)


def test_fbx_goes_through_blender_then_the_shared_pipeline(tmp_path):
    # An FBX written by Blender itself: read back by Blender's importer, then cleaned and shaded by
    # core.assets.build_render_mesh (a hard-edged box keeps its flat faces, welded to 8 vertices).
    import addon_utils

    addon_utils.enable("io_scene_fbx", default_set=True)
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    path = tmp_path / "cube.fbx"
    bpy.ops.export_scene.fbx(filepath=str(path), use_selection=True)
    bpy.data.objects.remove(bpy.context.active_object)
    mesh = scene_builder.import_asset(path)
    try:
        assert len(mesh.vertices) == 8 and len(mesh.polygons) == 12
        corner = np.empty(3 * len(mesh.loops), dtype=np.float32)
        mesh.corner_normals.foreach_get("vector", corner)
        assert np.allclose(np.sort(np.abs(corner.reshape(-1, 3)), axis=1), [0, 0, 1], atol=1e-4)
    finally:
        bpy.data.meshes.remove(mesh)
