"""The "Export and Render" operators (blender_addon/render_operator.py): export files, polarized render routes."""

import dataclasses
import json
import math
import os
import sys

import numpy as np
import pytest

from blender_addon.core import scenegen
from blender_addon.core.spec import SceneSpec
from pbrdf.sensor.rig import Rig
from tests.helpers import add_light, add_render_camera, rigid_pose

pytestmark = [pytest.mark.bpy, pytest.mark.mitsuba]
mi = pytest.importorskip("mitsuba")


# --------------------------------------------------------------------------- operators


def test_export_operator_writes_spec_ply_and_xml(bpy, tmp_path):
    add_render_camera(bpy, (0.0, -3.0, 0.5), (math.radians(85), 0.0, 0.0))
    bpy.ops.mesh.primitive_cube_add(size=0.5)
    add_light(bpy, "POINT", (1.0, -1.0, 2.0), energy=100.0)
    bpy.context.scene.pdir_export.output_dir = str(tmp_path / "out")
    assert bpy.ops.pdir.export_scene() == {"FINISHED"}
    spec = SceneSpec.load(tmp_path / "out" / "scene.json")
    assert [o.name for o in spec.objects] == ["Cube"] and spec.lights[0].kind == "point"
    assert os.path.isfile(spec.objects[0].mesh)
    mi.set_variant("scalar_rgb")
    img = np.asarray(mi.render(mi.load_file(str(tmp_path / "out" / "scene.xml"), resx=24, resy=16, spp=2)))
    assert img.shape == (16, 24, 4) and img[8, 12, 3] == 1.0 and img[8, 12, :3].sum() > 0  # lit cube at the centre


def _rig_scene(bpy, build_spec, seed: int = 4) -> SceneSpec:
    spec = scenegen.random_scene(Rig(), seed)
    build_spec.build_from_spec(bpy.context.scene, spec)
    return spec


def test_render_operator_creates_images(bpy, build_spec, render_operator, tmp_path):
    from blender_addon.core import generate, render

    spec = _rig_scene(bpy, build_spec)
    settings = bpy.context.scene.pdir_export
    settings.output_dir, settings.resolution, settings.spp = str(tmp_path / "r"), 16, 2
    assert bpy.ops.pdir.render_polarized() == {"FINISHED"}
    images = {name: bpy.data.images[name] for name in render_operator.IMAGE_NAMES}
    assert len(images) == 14 and all(tuple(img.size) == (16, 16) for img in images.values())
    # The images hold exactly what the bpy-free pipeline renders for the same spec and seeds.
    sample, _, _ = generate.render_sample(
        spec, render.RenderSettings(resolution=16, spp=2), sample_seed=scenegen.sample_seed(spec.seed, 0),
        keep_stokes=True,
    )  # fmt: skip

    def pixels(name):
        a = np.empty(16 * 16 * 4, np.float32)
        images[name].pixels.foreach_get(a)
        return a.reshape(16, 16, 4)[::-1]  # Blender row 0 is the bottom

    np.testing.assert_allclose(pixels("PDIR G_LP")[..., 0], sample["maps"][..., 4], atol=1e-6)
    np.testing.assert_allclose(pixels("PDIR S1")[..., :3], sample["stokes"][..., :, 1], atol=1e-6)
    assert (pixels("PDIR mask")[..., 0] == sample["mask"]).all() and sample["mask"].any()


def test_render_through_external_python_equals_in_process(bpy, build_spec, render_operator, tmp_path, monkeypatch):
    """The subprocess route (PDIR_PYTHON, headless/render.py --scene --npz) gives the in-process sample."""
    _rig_scene(bpy, build_spec, seed=9)
    monkeypatch.setenv(render_operator.PYTHON_ENV, sys.executable)
    scene = bpy.context.scene
    ours, route = render_operator.render_polarized(scene, tmp_path / "a", resolution=16, spp=2, route="subprocess")
    assert route == "subprocess" and (tmp_path / "a" / "polarized" / "samples" / "000000.exr").is_file()
    ref, route = render_operator.render_polarized(scene, tmp_path / "b", resolution=16, spp=2, route="auto")
    assert route == "inprocess"
    assert set(ref) <= set(ours)
    for key in ref:
        np.testing.assert_allclose(ours[key], ref[key], atol=1e-5, err_msg=key)
    meta = json.loads(str(np.load(tmp_path / "a" / "polarized" / "arrays" / "000000.npz")["metadata"]))
    assert meta["seed"] == SceneSpec.load(tmp_path / "a" / "scene" / "scene.json").seed


def test_render_operator_reports_invalid_scene(bpy, build_spec, tmp_path):
    spec = scenegen.random_scene(Rig(), 4)
    far = dataclasses.replace(
        spec.objects[0], to_world=rigid_pose((5.0, 0.0, -0.5)) @ np.asarray(spec.objects[0].to_world)
    )
    build_spec.build_from_spec(bpy.context.scene, dataclasses.replace(spec, objects=(far,)))
    bpy.context.scene.pdir_export.output_dir = str(tmp_path)
    with pytest.raises(RuntimeError, match="leaves the camera view"):
        bpy.ops.pdir.render_polarized()
