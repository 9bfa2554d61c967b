"""blender_addon/core/scenegen.py: random scenes with one or more objects, reproducible from a seed."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from blender_addon.core import assets, scenegen  # noqa: E402
from blender_addon.core.generated_shapes import GENERATED_SHAPES  # noqa: E402
from blender_addon.core.procedural import PROCEDURAL_SHAPES, diameter  # noqa: E402
from blender_addon.core.spec import MaterialSpec  # noqa: E402
from blender_addon.core.unseen_shapes import UNSEEN_SHAPES  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402

RIG = Rig()
FAST = ("gear", "l_block")  # quick to build: for tests of the drawing logic, not of the shapes


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """Three tabulated materials (the table files only need to exist here)."""
    folder = tmp_path_factory.mktemp("pbrdfs")
    (folder / "t.bin").write_bytes(b"x")
    return [MaterialSpec.measured(f"m{i}", str(folder / "t.bin"), (0.5, 0.4, 0.3), 0.3, 0.0) for i in range(3)]


@pytest.fixture(scope="module")
def asset_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("assets")
    trimesh.creation.icosphere(2).export(folder / "ball.glb")
    trimesh.creation.box().export(folder / "box.glb")
    return sorted(folder.glob("*.glb"))


def spheres(spec):
    """World centre and radius of every object's bounding sphere, from the meshes themselves."""
    out = []
    for obj in spec.objects:
        mesh = assets.load_mesh(obj.mesh)
        m = np.asarray(obj.to_world)
        v = np.asarray(mesh.vertices)
        centre = (v.min(axis=0) + v.max(axis=0)) / 2
        out.append((m[:3, :3] @ centre + m[:3, 3], np.cbrt(np.linalg.det(m[:3, :3])) * diameter(mesh) / 2))
    return out


def test_one_object_reproduces_the_single_object_scenes(library, asset_files):
    """Default arguments draw the random stream of the single-object scenes (existing datasets, splits)."""
    # Recorded from scenegen.random_scene before multi-object scenes existed.
    spec = scenegen.random_scene(RIG, 0)
    assert spec.objects[0].mesh == "builtin:bevel_box?seed=1367864807"
    assert spec.objects[0].name == "object" and [m.name for m in spec.materials] == ["material_plastic"]
    np.testing.assert_allclose(np.asarray(spec.objects[0].to_world)[:3, 3], [0.0350632186, 0.0396772493, -0.801570905])
    assert spec.objects[0].to_world[0][0] == pytest.approx(0.05942386393414665, abs=1e-15)
    assert scenegen.random_scene(RIG, 1).objects[0].mesh == "builtin:superquadric?seed=1099128569"
    assert scenegen.random_scene(RIG, 0, shapes=UNSEEN_SHAPES).objects[0].mesh == "builtin:thin_plate"
    assert scenegen.random_scene(RIG, 0, asset_files=asset_files).objects[0].mesh.endswith("box.glb")
    assert scenegen.random_scene(RIG, 0, materials=library).objects[0].material == "m1"
    # The explicit forms of the defaults draw the same.
    for seed in range(3):
        base = scenegen.random_scene(RIG, seed)
        assert scenegen.random_scene(RIG, seed, objects=(1, 1), table_fraction=0.0) == base
        assert scenegen.random_scene(RIG, seed, shapes=PROCEDURAL_SHAPES) == base
        tables = scenegen.random_scene(RIG, seed, materials=library)
        assert scenegen.random_scene(RIG, seed, materials=library, table_fraction=1.0) == tables
        assert scenegen.random_scene(RIG, seed, texture_fraction=0.0) == base


def test_texture_fraction_textures_drawn_materials_reproducibly(tmp_path):
    """Every drawn material textured at fraction 1, half at 0.5; the same seed gives the same textures."""
    tabs = [MaterialSpec.measured(f"t{i}", str(tmp_path / f"t{i}.bin"), (0.6, 0.5, 0.4), 0.2 + 0.2 * i, i / 3)
            for i in range(3)]  # fmt: skip
    for t in tabs:
        Path(t.table).write_bytes(b"x")
    kinds = set()
    for seed in range(6):
        spec = scenegen.random_scene(RIG, seed, shapes=FAST, objects=(1, 3), materials=tabs, table_fraction=0.5,
                                     texture_fraction=1.0)  # fmt: skip
        assert spec == scenegen.random_scene(RIG, seed, shapes=FAST, objects=(1, 3), materials=tabs,
                                             table_fraction=0.5, texture_fraction=1.0)  # fmt: skip
        for m in spec.materials:
            kinds.add(m.kind)
            assert m.textures is not None and m.textures.albedo is not None, m
            assert all(0.0 <= a <= 1.0 for a in m.albedo) and 0.0 <= m.roughness <= 1.0 and 0.0 <= m.metallic <= 1.0
            if m.kind == "measured" and m.textures.tables:  # a mixture: its constants lie between the tables'
                assert 0.2 - 1e-9 <= m.roughness <= 0.6 + 1e-9 and m.textures.weights is not None
        assert type(spec).from_dict(spec.to_dict()) == spec  # the textures travel in the sidecar's spec
    assert {"measured"} < kinds  # analytic and table materials both got textures
    half = [scenegen.random_scene(RIG, s, shapes=FAST, texture_fraction=0.5).materials[0].textures for s in range(40)]
    assert 8 <= sum(t is not None for t in half) <= 32


@pytest.mark.parametrize("seed", range(5))
def test_objects_do_not_interpenetrate_and_have_their_own_materials(seed):
    spec = scenegen.random_scene(RIG, seed, objects=(2, 3))
    spec.validate()
    assert 1 <= len(spec.objects) <= 3
    names = [o.name for o in spec.objects]
    assert len(set(names)) == len(names) and names[0] == "object"
    assert len(spec.materials) == len(spec.objects)
    assert len({o.material for o in spec.objects}) == len(spec.objects)  # one material each
    balls = spheres(spec)
    for i in range(len(balls)):
        for j in range(i):
            assert np.linalg.norm(balls[i][0] - balls[j][0]) >= balls[i][1] + balls[j][1] - 1e-9
    # Every object 50-100 cm from the camera, 15-35 cm across.
    cam = np.asarray(RIG.camera.camera_to_world())[:3, 3]
    for centre, radius in balls:
        assert 0.5 - 1e-9 <= np.linalg.norm(centre - cam) <= 1.0 + 1e-9
        assert 0.15 - 1e-9 <= 2 * radius <= 0.35 + 1e-9


def test_object_count_covers_the_range_and_is_reproducible():
    counts = [len(scenegen.random_scene(RIG, s, shapes=FAST, objects=(2, 4)).objects) for s in range(16)]
    assert set(counts) == {2, 3, 4}
    assert scenegen.random_scene(RIG, 3, objects=(2, 4)) == scenegen.random_scene(RIG, 3, objects=(2, 4))


def test_crowded_scenes_leave_objects_out_but_keep_one():
    """Large objects close by: poses run out, objects are dropped, the rest stay disjoint."""
    counts = []
    for seed in range(6):
        spec = scenegen.random_scene(
            RIG, seed, shapes=FAST, objects=(8, 8), size=(0.3, 0.35), distance=(0.5, 0.55), pose_tries=2
        )
        counts.append(len(spec.objects))
        balls = spheres(spec)
        for i in range(len(balls)):
            for j in range(i):
                assert np.linalg.norm(balls[i][0] - balls[j][0]) >= balls[i][1] + balls[j][1] - 1e-9
    assert min(counts) >= 1 and max(counts) < 8


def test_table_fraction_mixes_tables_and_analytic_materials(library):
    kinds = []
    for seed in range(8):
        spec = scenegen.random_scene(RIG, seed, shapes=FAST, objects=(3, 3), materials=library, table_fraction=0.5)
        spec.validate(check_files=False)
        kinds += [m.kind for m in spec.materials]
    measured = kinds.count("measured") / len(kinds)
    assert 0.2 < measured < 0.8  # 24 draws of p = 0.5
    all_tables = scenegen.random_scene(RIG, 0, objects=(3, 3), materials=library, table_fraction=1.0)
    assert {m.kind for m in all_tables.materials} == {"measured"}
    analytic = scenegen.random_scene(RIG, 0, objects=(3, 3), materials=library, table_fraction=0.0)
    assert "measured" not in {m.kind for m in analytic.materials}


def test_a_table_drawn_twice_gets_distinct_names(library):
    spec = scenegen.random_scene(RIG, 0, objects=(3, 3), materials=library[:1])
    assert [m.name for m in spec.materials] == ["m0", "m0_2", "m0_3"][: len(spec.objects)]
    assert len(spec.objects) >= 2
    assert all(dataclasses.replace(m, name="m0") == library[0] for m in spec.materials)


def test_pool_mixes_asset_files_and_builtin_shapes(asset_files):
    scenes = [
        scenegen.random_scene(RIG, s, asset_files=asset_files, shapes=UNSEEN_SHAPES, objects=(2, 2)) for s in range(8)
    ]
    refs = {o.mesh for spec in scenes for o in spec.objects}
    assert {r for r in refs if r.startswith("builtin:")} and {r for r in refs if r.endswith(".glb")}
    files_only = {scenegen.random_scene(RIG, s, asset_files=asset_files).objects[0].mesh for s in range(6)}
    assert all(r.endswith(".glb") for r in files_only)


def test_generated_shapes_are_drawn_with_a_seed():
    """Needs ``builtin:<generated shape>?seed=N`` in :func:`assets.load_mesh`."""
    refs = [scenegen.random_scene(RIG, s, shapes=GENERATED_SHAPES).objects[0].mesh for s in range(8)]
    assert all(r.split("?")[0].removeprefix("builtin:") in GENERATED_SHAPES and "?seed=" in r for r in refs)
    assert len({r.split("?")[0] for r in refs}) >= 3


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"objects": (0, 2)}, r"objects must be \(min, max\) integers with 1 <= min <= max"),
        ({"objects": (3, 2)}, r"objects must be \(min, max\)"),
        ({"objects": 2}, r"objects must be \(min, max\)"),
        ({"table_fraction": 1.5}, r"table_fraction must be in \[0, 1\]"),
        ({"table_fraction": 0.5}, "needs a pBRDF table library"),
        ({"shapes": ()}, "no shapes to draw from"),
        ({"pose_tries": 0}, "pose_tries must be >= 1"),
        ({"texture_fraction": -0.1}, r"texture_fraction must be in \[0, 1\]"),
    ],
)
def test_bad_arguments_raise_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message) as info:
        scenegen.random_scene(RIG, 0, **kwargs)
    assert "\n" not in str(info.value)


def test_crop_of_objects_spread_wider_than_the_sensor_height_stays_square():
    # Multi-object scenes can span more than the sensor's shorter side: the crop must still be
    # R x R (the camera model's mosaic needs it), centred where it does not fit.
    from blender_addon.core import mitsuba_scene as ms

    cam = Rig().camera
    w, h = cam.sensor_width_px, cam.sensor_height_px
    uv = np.array([[0.1 * w, h / 2], [0.9 * w, h / 2 + 1]])  # 80 % of the width, more than the height
    win = ms.crop_window(cam, uv, 64)
    assert win.size == (64, 64) and win.offset[1] < 0 <= win.offset[0]
    k = win.intrinsics(cam)
    x = uv[:, 0] / win.binning - win.offset[0]  # sensor pixel -> crop pixel
    assert np.all((x >= 0) & (x <= 64)) and k[0, 2] == pytest.approx(win.film_size[0] / 2 - win.offset[0], abs=1)
