"""Scene spec -> Blender -> scene spec (blender_addon/build_spec.py and its inverse, export_spec.py)."""

import dataclasses

import numpy as np
import pytest

from blender_addon.core import assets, scenegen
from blender_addon.core.spec import EnvironmentSpec, LightSpec, MaterialSpec, ObjectSpec, SceneSpec
from pbrdf.sensor.rig import Rig
from tests.helpers import rigid_pose, rot_x

pytestmark = pytest.mark.bpy


def _full_spec(tmp_path) -> SceneSpec:
    from pbrdf.io.exr import write_exr

    spec = scenegen.random_scene(Rig(), 11)
    second = ObjectSpec("ring", "builtin:torus?seed=2", rigid_pose((0.05, -0.05, -0.8), rot_x(0.4) * 0.15), "chalk")
    sky = write_exr(tmp_path / "env.exr", {c: np.full((4, 8), 0.5, np.float32) for c in "RGB"})
    return dataclasses.replace(
        spec,
        objects=(*spec.objects, second),
        materials=(*spec.materials, MaterialSpec.diffuse("chalk", (0.9, 0.85, 0.8), 0.7)),
        lights=(
            LightSpec(
                "key", "area", rigid_pose((0.3, 0.4, -0.1), rot_x(-0.5)), (1.0, 0.95, 0.9), 40.0, size=(0.4, 0.3)
            ),
            LightSpec("fill", "point", rigid_pose((-0.4, 0.2, 0.0)), power=12.5),
            LightSpec(
                "cone", "spot", rigid_pose((0, 0.5, -0.5), rot_x(1.2)), power=80.0, spot_angle=0.9, spot_blend=0.3
            ),
            LightSpec("sun", "sun", rigid_pose(rot=rot_x(0.7)), (1.0, 0.9, 0.7), 2.5),
        ),
        environment=EnvironmentSpec(strength=0.7, image=str(sky), to_world=rigid_pose(rot=rot_x(0.25))),
        metadata={"source": "test", "tags": [1, 2]},
    )


def test_export_round_trip_spec_blender_spec(bpy, build_spec, export_spec, tmp_path):
    spec = _full_spec(tmp_path)
    scene = bpy.context.scene
    build_spec.build_from_spec(scene, spec)
    assert export_spec.export_scene(scene, tmp_path / "rt", xml=False) == spec
    assert (tmp_path / "rt" / "scene.json").is_file()
    assert SceneSpec.load(tmp_path / "rt" / "scene.json") == spec


def test_edited_scene_exports_live_values(bpy, build_spec, export_spec, tmp_path):
    """Edits in Blender win over the stored spec: moved light, edited mesh, edited material."""
    import trimesh
    from scipy.spatial import cKDTree

    spec = _full_spec(tmp_path)
    scene = bpy.context.scene
    build_spec.build_from_spec(scene, spec)
    ring = bpy.data.objects["ring"]
    ring.data.vertices[0].co.x += 0.5  # an edited mesh is exported as a PLY in rig coordinates
    bpy.data.objects["fill"].location.x += 0.1  # rig frame x = Blender x (root rotated about x)
    mat = ring.data.materials[0]
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    out = export_spec.export_scene(scene, tmp_path / "edited", xml=False)
    ring_out = next(o for o in out.objects if o.name == "ring")
    assert ring_out.mesh.endswith(".ply") and np.allclose(ring_out.to_world, np.eye(4))
    exported = trimesh.load(ring_out.mesh, process=False)
    tm = assets.load_mesh("builtin:torus?seed=2")
    m = np.asarray(spec.objects[1].to_world)
    expected = np.asarray(tm.vertices) @ m[:3, :3].T + m[:3, 3]
    # Every exported vertex is one of the mesh's (the first one moved by 0.5 m along object x).
    moved = expected.copy()
    moved[0] += 0.5 * m[:3, 0]
    d, _ = cKDTree(moved).query(np.asarray(exported.vertices))
    assert d.max() < 1e-5
    fill = next(light for light in out.lights if light.name == "fill")
    assert fill.to_world[0][3] == pytest.approx(-0.4 + 0.1, abs=1e-6)
    chalk = out.material(ring_out.material)
    assert chalk.albedo == pytest.approx((0.1, 0.2, 0.3), abs=1e-6)
    # Unedited parts still come back exactly.
    assert out.objects[0] == spec.objects[0] and out.environment == spec.environment and out.rig == spec.rig
