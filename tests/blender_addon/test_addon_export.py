"""Export of Blender scenes to specs, PLY and Mitsuba, checked against Cycles; the polarized render operator.

Cycles (bpy 5.0.1 wheel) is the independent reference: object masks and the brightness of a
grey Lambertian plane under each light type must match the Mitsuba render of the exported
scene. Renders are tiny (32-64 px) and use one thread.
"""

import dataclasses
import json
import math
import os
import sys

import numpy as np
import pytest

from blender_addon.core import assets, mitsuba_scene, scenegen
from blender_addon.core.spec import EnvironmentSpec, LightSpec, MaterialSpec, ObjectSpec, SceneSpec
from pbrdf.sensor.rig import Rig

mi = pytest.importorskip("mitsuba")


# --------------------------------------------------------------------------- fixtures and helpers


@pytest.fixture(scope="module")
def addon(addon_registered):
    """The add-on registered in the bpy wheel (skips without bpy); unregistered afterwards."""
    return addon_registered


@pytest.fixture
def bpy(addon):
    """bpy with an empty scene."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy


@pytest.fixture(scope="module")
def export(addon):
    from blender_addon import export

    return export


def _pose(t=(0.0, 0.0, 0.0), rot=None) -> np.ndarray:
    m = np.eye(4)
    if rot is not None:
        m[:3, :3] = rot
    m[:3, 3] = t
    return m


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=float)


def _cycles(bpy, path, samples: int, *, transparent: bool = False) -> np.ndarray:
    """Render the context scene with Cycles (CPU, 1 thread) to a linear EXR; returns (H, W, 4)."""
    from pbrdf.io.exr import read_exr

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device, cyc.samples, cyc.seed = "CPU", samples, 1
    cyc.use_adaptive_sampling = cyc.use_denoising = False
    cyc.filter_width = 1.0
    scene.view_settings.view_transform = "Standard"  # never Filmic/AgX (EXR stays linear anyway)
    scene.render.film_transparent = transparent
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth, settings.color_mode = "OPEN_EXR", "32", "RGBA"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    ch = read_exr(path)
    return np.stack([ch[c] for c in "RGBA"], axis=-1)


def _camera(bpy, location, rotation=(0.0, 0.0, 0.0), *, res=(32, 32), lens=50.0):
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location, cam.rotation_euler = location, rotation
    cam.data.lens = lens
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    return cam


def _grey_plane(bpy, albedo=0.5, size=4.0, principled=False):
    """A grey Lambertian plane at z = 0 facing +z."""
    bpy.ops.mesh.primitive_plane_add(size=size)
    plane = bpy.context.object
    mat = bpy.data.materials.new("grey")
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    if principled:  # Principled without specular is Lambertian too
        bsdf = nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (albedo, albedo, albedo, 1.0)
        bsdf.inputs["Specular IOR Level"].default_value = 0.0
    else:
        nodes.remove(nodes["Principled BSDF"])
        bsdf = nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Color"].default_value = (albedo, albedo, albedo, 1.0)
        links.new(bsdf.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
    plane.data.materials.append(mat)
    return plane


def _light(bpy, kind: str, location, rotation=(0.0, 0.0, 0.0), **props):
    data = bpy.data.lights.new(kind.lower(), kind)
    for k, v in props.items():
        setattr(data, k, v)
    obj = bpy.data.objects.new(kind.lower(), data)
    bpy.context.scene.collection.objects.link(obj)
    obj.location, obj.rotation_euler = location, rotation
    return obj


def _mitsuba(spec, tmp_path, spp: int, *, resolution=None):
    from blender_addon.core import render

    settings = render.PreviewSettings(resolution=resolution, spp=spp, display=False, max_depth=4, seed=1)
    return render.render_preview(spec, tmp_path / "mi_files", settings)


def _centre(img: np.ndarray, half: int = 4) -> np.ndarray:
    h, w = img.shape[:2]
    return img[h // 2 - half : h // 2 + half, w // 2 - half : w // 2 + half]


# --------------------------------------------------------------------------- bpy-free spec parts


def test_light_and_environment_specs_round_trip_and_validate(tmp_path):
    lights = (
        LightSpec("key", "area", _pose((0.1, 0.2, 0.3)), (1.0, 0.9, 0.8), 25.0, size=(0.3, 0.2), shape="ellipse",
                  normalize=False),
        LightSpec("bulb", "point", power=5.0),
        LightSpec("cone", "spot", _pose(rot=_rot_x(0.3)), power=100.0, spot_angle=0.8, spot_blend=0.2),
        LightSpec("sun", "sun", power=3.0),
    )  # fmt: skip
    env = EnvironmentSpec(strength=0.5, image="sky.exr", to_world=_pose(rot=_rot_x(math.pi / 2)))
    spec = SceneSpec(lights=lights, environment=env, materials=(MaterialSpec.diffuse("d", (0.2, 0.3, 0.4)),))
    spec.save(tmp_path / "s.json")
    assert SceneSpec.load(tmp_path / "s.json") == spec
    # Scenes without lights serialise exactly as before this feature.
    assert set(SceneSpec().to_dict()) == {"rig", "objects", "materials", "seed", "metadata"}
    # Unit conversions (Cycles conventions, see LightSpec): L = P / (pi A), I = P / (4 pi).
    assert lights[0].area == pytest.approx(math.pi * 0.3 * 0.2 / 4)
    assert lights[0].radiance()[0] == pytest.approx(25.0 / math.pi)  # not normalized: per square metre
    normalized = dataclasses.replace(lights[0], normalize=True, shape="rectangle")
    assert normalized.radiance()[1] == pytest.approx(25.0 * 0.9 / (math.pi * 0.06))
    assert lights[1].intensity() == pytest.approx((5 / (4 * math.pi),) * 3)
    with pytest.raises(ValueError, match="power must be >= 0"):
        LightSpec("x", "point", power=-1)
    with pytest.raises(ValueError, match="field size is not used by kind 'point'"):
        LightSpec("x", "point", size=(1, 1))
    with pytest.raises(ValueError, match="unknown kind 'laser'"):
        LightSpec("x", "laser")
    with pytest.raises(ValueError, match="rigid transform"):
        LightSpec("x", "point", to_world=np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="pure rotation"):
        EnvironmentSpec(to_world=_pose((0, 0, 1)))
    with pytest.raises(ValueError, match="duplicate light name 'bulb'"):
        SceneSpec(lights=(lights[1], lights[1])).validate()
    with pytest.raises(FileNotFoundError, match="environment image not found"):
        spec.validate()


def test_preview_xml_loads_and_renders_like_the_dict(tmp_path):
    mi.set_variant("scalar_rgb")
    spec = scenegen.random_scene(Rig(), 3)
    spec = dataclasses.replace(spec, lights=(LightSpec("p", "point", _pose((0, 0.3, -0.2)), power=30.0),))
    scene = mitsuba_scene.preview_scene_dict(spec, tmp_path, resolution=24, spp=4)
    mitsuba_scene.write_xml(scene, tmp_path / "scene.xml")
    a = np.asarray(mi.render(mi.load_dict(scene), seed=3))
    b = np.asarray(mi.render(mi.load_file(str(tmp_path / "scene.xml")), seed=3))
    assert a.shape == (20, 24, 4) and a[..., 3].max() == 1.0  # sensor aspect kept; the object is seen
    np.testing.assert_allclose(b, a, atol=1e-5)


def test_diffuse_material_depolarizes_the_display_light():
    """A Lambertian object in the polarized pipeline: lit (unpol > 0) but no linear polarization left."""
    from blender_addon.core import render

    spec = scenegen.random_scene(Rig(), 5)
    spec = dataclasses.replace(
        spec,
        materials=(MaterialSpec.diffuse("chalk", (0.8, 0.5, 0.3)),),
        objects=(dataclasses.replace(spec.objects[0], material="chalk"),),
    )
    result = render.render_stokes(spec, render.RenderSettings(resolution=16, spp=8))
    s = result.stokes[result.mask]  # (N, 3, 4)
    lit = s[..., 0] > 1e-3
    assert lit[:, 0].mean() > 0.3  # the red half of the display lights the object
    dolp = np.hypot(s[..., 1], s[..., 2])[lit] / s[..., 0][lit]
    assert np.median(dolp) < 1e-3


# --------------------------------------------------------------------------- export vs Cycles


def test_mask_matches_cycles(bpy, export, tmp_path):
    """Object masks of Cycles and of Mitsuba on the exported scene agree (IoU > 0.95)."""
    _camera(bpy, (0.3, -2.5, 1.1), (math.radians(70), 0.0, math.radians(8)), res=(64, 48), lens=40.0)
    bpy.ops.mesh.primitive_monkey_add(size=0.9, location=(0.1, 0.0, 0.6), rotation=(0.3, 0.2, 0.5))
    monkey = bpy.context.object
    monkey.modifiers.new("subsurf", "SUBSURF").levels = 1
    bpy.ops.mesh.primitive_cylinder_add(radius=0.3, depth=0.6, location=(-0.7, 0.4, 0.3))
    bpy.context.object.scale = (-1.0, 1.0, 1.0)  # mirrored: winding must be fixed on export
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.25, location=(0.8, -0.2, 0.9))
    bpy.ops.object.shade_smooth()
    ref = _cycles(bpy, tmp_path / "mask.exr", 16, transparent=True)[..., 3] >= 0.5
    spec = export.export_scene(bpy.context.scene, tmp_path / "export", xml=False)
    assert len(spec.objects) == 3 and all(o.mesh.endswith(".ply") for o in spec.objects)
    ours = _mitsuba(spec, tmp_path, 16).mask
    assert ours.shape == ref.shape == (48, 64)
    iou = (ours & ref).sum() / (ours | ref).sum()
    assert 0.1 < ref.mean() < 0.6
    assert iou > 0.95, iou


@pytest.mark.parametrize(
    "kind",
    ["area", "area_disk_unnormalized", "point", "spot", "sun", "world"],
)
def test_brightness_matches_cycles(bpy, export, tmp_path, kind):
    """A grey Lambertian plane under one light: Cycles and Mitsuba agree within 2 % at the centre."""
    _grey_plane(bpy, principled=kind == "point")
    _camera(bpy, (0.0, 0.0, 0.9))  # below the lights, looking straight down at the plane
    scene = bpy.context.scene
    scene.world = None
    if kind == "area":
        _light(bpy, "AREA", (0.1, 0.0, 1.0), (0.15, 0.0, 0.0), energy=10.0, size=0.5)
    elif kind == "area_disk_unnormalized":
        _light(bpy, "AREA", (0.0, 0.1, 1.2), energy=4.0, shape="DISK", size=0.6, normalize=False)
    elif kind == "point":
        _light(bpy, "POINT", (0.2, 0.0, 1.0), energy=30.0, shadow_soft_size=0.0)
    elif kind == "spot":
        _light(bpy, "SPOT", (0.0, 0.0, 1.0), energy=30.0, spot_size=math.radians(60), spot_blend=0.1,
               shadow_soft_size=0.0)  # fmt: skip
    elif kind == "sun":
        _light(bpy, "SUN", (0.0, 0.0, 3.0), (0.4, 0.0, 0.0), energy=2.0)
    else:
        world = bpy.data.worlds.new("w")
        world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.3, 0.5, 0.7, 1.0)
        world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.5
        scene.world = world
    ref = _cycles(bpy, tmp_path / "ref.exr", 256)[..., :3]
    spec = export.export_scene(scene, tmp_path / "export", xml=False)
    assert len(spec.lights) == (0 if kind == "world" else 1)
    ours = _mitsuba(spec, tmp_path, 256).rgb
    a, b = _centre(ours).mean(axis=(0, 1)), _centre(ref).mean(axis=(0, 1))
    assert b.min() > 0.01
    np.testing.assert_allclose(a, b, rtol=0.02)
    if kind == "world":  # the plane under a uniform sky reflects albedo x sky radiance
        np.testing.assert_allclose(b, 0.5 * 1.5 * np.array([0.3, 0.5, 0.7]), rtol=0.02)


def test_environment_map_orientation_matches_cycles(bpy, export, tmp_path):
    """An equirectangular map seen through a tilted camera: same background in Cycles and Mitsuba."""
    from pbrdf.io.exr import write_exr

    h, w = 64, 128
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)  # row 0 = top of the image
    sky = {"R": 0.5 + 0.5 * np.cos(2 * np.pi * uu), "G": 1.0 - vv, "B": 0.5 + 0.5 * np.sin(2 * np.pi * uu)}
    path = write_exr(tmp_path / "sky.exr", {k: v.astype(np.float32) for k, v in sky.items()})
    scene = bpy.context.scene
    world = bpy.data.worlds.new("sky")
    nodes, links = world.node_tree.nodes, world.node_tree.links
    tex = nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(str(path))
    links.new(tex.outputs["Color"], nodes["Background"].inputs["Color"])
    mapping, coords = nodes.new("ShaderNodeMapping"), nodes.new("ShaderNodeTexCoord")
    mapping.inputs["Rotation"].default_value = (0.3, -0.2, 0.9)
    links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    nodes["Background"].inputs["Strength"].default_value = 2.0
    world.cycles.sampling_method = "NONE"  # only seen directly: skip building the importance map
    scene.world = world
    _camera(bpy, (0.0, 0.0, 0.0), (math.radians(60), 0.0, math.radians(-30)), res=(48, 32), lens=18.0)
    ref = _cycles(bpy, tmp_path / "sky_ref.exr", 16)[..., :3]
    spec = export.export_scene(scene, tmp_path / "export", xml=False)
    assert spec.environment.image == str(path) and spec.environment.strength == 2.0
    ours = _mitsuba(spec, tmp_path, 16).rgb
    err = np.abs(ours - ref)
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.05, (np.median(err), np.percentile(err, 95))
    # A wrong axis convention (e.g. the map mirrored left-right) is far off.
    assert np.median(np.abs(ours[:, ::-1] - ref)) > 0.05


# --------------------------------------------------------------------------- round trips and materials


def _full_spec(tmp_path) -> SceneSpec:
    from pbrdf.io.exr import write_exr

    spec = scenegen.random_scene(Rig(), 11)
    second = ObjectSpec("ring", "builtin:torus?seed=2", _pose((0.05, -0.05, -0.8), _rot_x(0.4) * 0.15), "chalk")
    sky = write_exr(tmp_path / "env.exr", {c: np.full((4, 8), 0.5, np.float32) for c in "RGB"})
    return dataclasses.replace(
        spec,
        objects=(*spec.objects, second),
        materials=(*spec.materials, MaterialSpec.diffuse("chalk", (0.9, 0.85, 0.8), 0.7)),
        lights=(
            LightSpec("key", "area", _pose((0.3, 0.4, -0.1), _rot_x(-0.5)), (1.0, 0.95, 0.9), 40.0, size=(0.4, 0.3)),
            LightSpec("fill", "point", _pose((-0.4, 0.2, 0.0)), power=12.5),
            LightSpec("cone", "spot", _pose((0, 0.5, -0.5), _rot_x(1.2)), power=80.0, spot_angle=0.9, spot_blend=0.3),
            LightSpec("sun", "sun", _pose(rot=_rot_x(0.7)), (1.0, 0.9, 0.7), 2.5),
        ),
        environment=EnvironmentSpec(strength=0.7, image=str(sky), to_world=_pose(rot=_rot_x(0.25))),
        metadata={"source": "test", "tags": [1, 2]},
    )


def test_export_round_trip_spec_blender_spec(bpy, export, tmp_path):
    spec = _full_spec(tmp_path)
    scene = bpy.context.scene
    export.build_from_spec(scene, spec)
    assert export.export_scene(scene, tmp_path / "rt", xml=False) == spec
    assert (tmp_path / "rt" / "scene.json").is_file()
    assert SceneSpec.load(tmp_path / "rt" / "scene.json") == spec


def test_edited_scene_exports_live_values(bpy, export, tmp_path):
    """Edits in Blender win over the stored spec: moved light, edited mesh, edited material."""
    import trimesh
    from scipy.spatial import cKDTree

    spec = _full_spec(tmp_path)
    scene = bpy.context.scene
    export.build_from_spec(scene, spec)
    ring = bpy.data.objects["ring"]
    ring.data.vertices[0].co.x += 0.5  # an edited mesh is exported as a PLY in rig coordinates
    bpy.data.objects["fill"].location.x += 0.1  # rig frame x = Blender x (root rotated about x)
    mat = ring.data.materials[0]
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    out = export.export_scene(scene, tmp_path / "edited", xml=False)
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


def test_scene_builder_scene_exports_in_the_rig_frame(bpy, export, tmp_path):
    """Objects placed in view by the scene builder are in view in the exported spec (rig frame)."""
    import trimesh

    from blender_addon import scene_builder

    folder = tmp_path / "assets"
    folder.mkdir()
    trimesh.creation.icosphere(1).export(folder / "ball.glb")
    trimesh.creation.box((1.0, 0.5, 0.3)).export(folder / "box.ply")
    objs = scene_builder.build_scene(bpy.context.scene, folder, 3, 7)
    spec = export.export_scene(bpy.context.scene, tmp_path / "out", xml=False)
    assert len(spec.objects) == 3
    for o in spec.objects:
        v = np.asarray(trimesh.load(o.mesh, process=False).vertices)
        assert spec.rig.in_view(v)
        depth = spec.rig.camera.project(v)[1]
        assert 0.3 < depth.min() and depth.max() < 1.3  # placed 50-100 cm from the camera
    stored = {scene_builder.material_spec_of(ob.data.materials[0]) for ob in objs}
    assert set(spec.materials) == stored


def test_principled_materials_map_to_specs(bpy, export):
    def principled(name, **inputs):
        mat = bpy.data.materials.new(name)
        node = mat.node_tree.nodes["Principled BSDF"]
        for k, v in inputs.items():
            node.inputs[k].default_value = v
        return mat

    metal = export.material_spec_from_blender(principled("m", **{"Base Color": (0.9, 0.6, 0.2, 1), "Metallic": 1.0}))
    assert metal.kind == "conductor"
    n, k = np.asarray(metal.eta), np.asarray(metal.k)
    r0 = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)  # normal-incidence Fresnel reflectance
    np.testing.assert_allclose(r0, (0.9, 0.6, 0.2), atol=1e-6)
    plastic = export.material_spec_from_blender(principled("p", IOR=1.6, Roughness=0.3))
    assert (plastic.kind, plastic.ior, plastic.roughness) == ("pplastic", pytest.approx(1.6), pytest.approx(0.3))
    matte = export.material_spec_from_blender(principled("d", **{"Specular IOR Level": 0.0}))
    assert matte.kind == "diffuse"
    assert export.material_spec_from_blender(None).kind == "diffuse"


# --------------------------------------------------------------------------- operators


def test_export_operator_writes_spec_ply_and_xml(bpy, export, tmp_path):
    _camera(bpy, (0.0, -3.0, 0.5), (math.radians(85), 0.0, 0.0))
    bpy.ops.mesh.primitive_cube_add(size=0.5)
    _light(bpy, "POINT", (1.0, -1.0, 2.0), energy=100.0)
    bpy.context.scene.pdir_export.output_dir = str(tmp_path / "out")
    assert bpy.ops.pdir.export_scene() == {"FINISHED"}
    spec = SceneSpec.load(tmp_path / "out" / "scene.json")
    assert [o.name for o in spec.objects] == ["Cube"] and spec.lights[0].kind == "point"
    assert os.path.isfile(spec.objects[0].mesh)
    mi.set_variant("scalar_rgb")
    img = np.asarray(mi.render(mi.load_file(str(tmp_path / "out" / "scene.xml"), resx=24, resy=16, spp=2)))
    assert img.shape == (16, 24, 4) and img[8, 12, 3] == 1.0 and img[8, 12, :3].sum() > 0  # lit cube at the centre


def _rig_scene(bpy, export, seed: int = 4) -> SceneSpec:
    spec = scenegen.random_scene(Rig(), seed)
    export.build_from_spec(bpy.context.scene, spec)
    return spec


def test_render_operator_creates_images(bpy, export, tmp_path):
    from blender_addon.core import generate, render

    spec = _rig_scene(bpy, export)
    settings = bpy.context.scene.pdir_export
    settings.output_dir, settings.resolution, settings.spp = str(tmp_path / "r"), 16, 2
    assert bpy.ops.pdir.render_polarized() == {"FINISHED"}
    images = {name: bpy.data.images[name] for name in export.IMAGE_NAMES}
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


def test_render_through_external_python_equals_in_process(bpy, export, tmp_path, monkeypatch):
    """The subprocess route (PDIR_PYTHON, headless/render.py --scene --npz) gives the in-process sample."""
    _rig_scene(bpy, export, seed=9)
    monkeypatch.setenv(export.PYTHON_ENV, sys.executable)
    scene = bpy.context.scene
    ours, route = export.render_polarized(scene, tmp_path / "a", resolution=16, spp=2, route="subprocess")
    assert route == "subprocess" and (tmp_path / "a" / "polarized" / "samples" / "000000.exr").is_file()
    ref, route = export.render_polarized(scene, tmp_path / "b", resolution=16, spp=2, route="auto")
    assert route == "inprocess"
    assert set(ref) <= set(ours)
    for key in ref:
        np.testing.assert_allclose(ours[key], ref[key], atol=1e-5, err_msg=key)
    meta = json.loads(str(np.load(tmp_path / "a" / "polarized" / "arrays" / "000000.npz")["metadata"]))
    assert meta["seed"] == SceneSpec.load(tmp_path / "a" / "scene" / "scene.json").seed


def test_render_operator_reports_invalid_scene(bpy, export, tmp_path):
    spec = scenegen.random_scene(Rig(), 4)
    far = dataclasses.replace(spec.objects[0], to_world=_pose((5.0, 0.0, -0.5)) @ np.asarray(spec.objects[0].to_world))
    export.build_from_spec(bpy.context.scene, dataclasses.replace(spec, objects=(far,)))
    bpy.context.scene.pdir_export.output_dir = str(tmp_path)
    with pytest.raises(RuntimeError, match="leaves the camera view"):
        bpy.ops.pdir.render_polarized()
