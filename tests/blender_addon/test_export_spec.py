"""Export of Blender scenes to specs and PLY (blender_addon/export_spec.py), checked against Cycles.

Cycles (bpy 5.0.1 wheel) is the independent reference: object masks and the brightness of a
grey Lambertian plane under each light type must match the Mitsuba render of the exported
scene. Renders are tiny (32-64 px) and use one thread.
"""

import math

import numpy as np
import pytest

from tests.helpers import add_light, add_render_camera

pytestmark = pytest.mark.bpy
mi = pytest.importorskip("mitsuba")


# --------------------------------------------------------------------------- helpers
# (the bpy and export_spec fixtures are in tests/conftest.py)


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


def _mitsuba(spec, tmp_path, spp: int, *, resolution=None):
    from blender_addon.core import render

    settings = render.PreviewSettings(resolution=resolution, spp=spp, display=False, max_depth=4, seed=1)
    return render.render_preview(spec, tmp_path / "mi_files", settings)


def _centre(img: np.ndarray, half: int = 4) -> np.ndarray:
    h, w = img.shape[:2]
    return img[h // 2 - half : h // 2 + half, w // 2 - half : w // 2 + half]


# --------------------------------------------------------------------------- export vs Cycles


@pytest.mark.mitsuba
def test_mask_matches_cycles(bpy, export_spec, tmp_path):
    """Object masks of Cycles and of Mitsuba on the exported scene agree (IoU > 0.95)."""
    add_render_camera(bpy, (0.3, -2.5, 1.1), (math.radians(70), 0.0, math.radians(8)), res=(64, 48), lens=40.0)
    bpy.ops.mesh.primitive_monkey_add(size=0.9, location=(0.1, 0.0, 0.6), rotation=(0.3, 0.2, 0.5))
    monkey = bpy.context.object
    monkey.modifiers.new("subsurf", "SUBSURF").levels = 1
    bpy.ops.mesh.primitive_cylinder_add(radius=0.3, depth=0.6, location=(-0.7, 0.4, 0.3))
    bpy.context.object.scale = (-1.0, 1.0, 1.0)  # mirrored: winding must be fixed on export
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.25, location=(0.8, -0.2, 0.9))
    bpy.ops.object.shade_smooth()
    ref = _cycles(bpy, tmp_path / "mask.exr", 16, transparent=True)[..., 3] >= 0.5
    spec = export_spec.export_scene(bpy.context.scene, tmp_path / "export", xml=False)
    assert len(spec.objects) == 3 and all(o.mesh.endswith(".ply") for o in spec.objects)
    ours = _mitsuba(spec, tmp_path, 16).mask
    assert ours.shape == ref.shape == (48, 64)
    iou = (ours & ref).sum() / (ours | ref).sum()
    assert 0.1 < ref.mean() < 0.6
    assert iou > 0.95, iou


@pytest.mark.mitsuba
@pytest.mark.parametrize(
    "kind",
    ["area", "area_disk_unnormalized", "point", "spot", "sun", "world"],
)
def test_brightness_matches_cycles(bpy, export_spec, tmp_path, kind):
    """A grey Lambertian plane under one light: Cycles and Mitsuba agree within 2 % at the centre."""
    _grey_plane(bpy, principled=kind == "point")
    add_render_camera(bpy, (0.0, 0.0, 0.9))  # below the lights, looking straight down at the plane
    scene = bpy.context.scene
    scene.world = None
    if kind == "area":
        add_light(bpy, "AREA", (0.1, 0.0, 1.0), (0.15, 0.0, 0.0), energy=10.0, size=0.5)
    elif kind == "area_disk_unnormalized":
        add_light(bpy, "AREA", (0.0, 0.1, 1.2), energy=4.0, shape="DISK", size=0.6, normalize=False)
    elif kind == "point":
        add_light(bpy, "POINT", (0.2, 0.0, 1.0), energy=30.0, shadow_soft_size=0.0)
    elif kind == "spot":
        add_light(bpy, "SPOT", (0.0, 0.0, 1.0), energy=30.0, spot_size=math.radians(60), spot_blend=0.1,
               shadow_soft_size=0.0)  # fmt: skip
    elif kind == "sun":
        add_light(bpy, "SUN", (0.0, 0.0, 3.0), (0.4, 0.0, 0.0), energy=2.0)
    else:
        world = bpy.data.worlds.new("w")
        world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.3, 0.5, 0.7, 1.0)
        world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.5
        scene.world = world
    ref = _cycles(bpy, tmp_path / "ref.exr", 256)[..., :3]
    spec = export_spec.export_scene(scene, tmp_path / "export", xml=False)
    assert len(spec.lights) == (0 if kind == "world" else 1)
    ours = _mitsuba(spec, tmp_path, 256).rgb
    a, b = _centre(ours).mean(axis=(0, 1)), _centre(ref).mean(axis=(0, 1))
    assert b.min() > 0.01
    np.testing.assert_allclose(a, b, rtol=0.02)
    if kind == "world":  # the plane under a uniform sky reflects albedo x sky radiance
        np.testing.assert_allclose(b, 0.5 * 1.5 * np.array([0.3, 0.5, 0.7]), rtol=0.02)


@pytest.mark.mitsuba
def test_environment_map_orientation_matches_cycles(bpy, export_spec, tmp_path):
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
    add_render_camera(bpy, (0.0, 0.0, 0.0), (math.radians(60), 0.0, math.radians(-30)), res=(48, 32), lens=18.0)
    ref = _cycles(bpy, tmp_path / "sky_ref.exr", 16)[..., :3]
    spec = export_spec.export_scene(scene, tmp_path / "export", xml=False)
    assert spec.environment.image == str(path) and spec.environment.strength == 2.0
    ours = _mitsuba(spec, tmp_path, 16).rgb
    err = np.abs(ours - ref)
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.05, (np.median(err), np.percentile(err, 95))
    # A wrong axis convention (e.g. the map mirrored left-right) is far off.
    assert np.median(np.abs(ours[:, ::-1] - ref)) > 0.05


# --------------------------------------------------------------------------- scene builder and materials


def test_scene_builder_scene_exports_in_the_rig_frame(bpy, export_spec, tmp_path):
    """Objects placed in view by the scene builder are in view in the exported spec (rig frame)."""
    import trimesh

    from blender_addon import scene_builder

    folder = tmp_path / "assets"
    folder.mkdir()
    trimesh.creation.icosphere(1).export(folder / "ball.glb")
    trimesh.creation.box((1.0, 0.5, 0.3)).export(folder / "box.ply")
    objs = scene_builder.build_scene(bpy.context.scene, folder, 3, 7)
    spec = export_spec.export_scene(bpy.context.scene, tmp_path / "out", xml=False)
    assert len(spec.objects) == 3
    for o in spec.objects:
        v = np.asarray(trimesh.load(o.mesh, process=False).vertices)
        assert spec.rig.in_view(v)
        depth = spec.rig.camera.project(v)[1]
        assert 0.3 < depth.min() and depth.max() < 1.3  # placed 50-100 cm from the camera
    stored = {scene_builder.material_spec_of(ob.data.materials[0]) for ob in objs}
    assert set(spec.materials) == stored


def test_principled_materials_map_to_specs(bpy, export_spec):
    def principled(name, **inputs):
        mat = bpy.data.materials.new(name)
        node = mat.node_tree.nodes["Principled BSDF"]
        for k, v in inputs.items():
            node.inputs[k].default_value = v
        return mat

    metal = export_spec.material_spec_from_blender(
        principled("m", **{"Base Color": (0.9, 0.6, 0.2, 1), "Metallic": 1.0})
    )
    assert metal.kind == "conductor"
    n, k = np.asarray(metal.eta), np.asarray(metal.k)
    r0 = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)  # normal-incidence Fresnel reflectance
    np.testing.assert_allclose(r0, (0.9, 0.6, 0.2), atol=1e-6)
    plastic = export_spec.material_spec_from_blender(principled("p", IOR=1.6, Roughness=0.3))
    assert (plastic.kind, plastic.ior, plastic.roughness) == ("pplastic", pytest.approx(1.6), pytest.approx(0.3))
    matte = export_spec.material_spec_from_blender(principled("d", **{"Specular IOR Level": 0.0}))
    assert matte.kind == "diffuse"
    assert export_spec.material_spec_from_blender(None).kind == "diffuse"
