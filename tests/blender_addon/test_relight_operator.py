"""Relighting of imported assets (blender_addon/relight_operator.py) with the real bpy 5.0 wheel and Cycles."""

import math
import warnings

import numpy as np
import pytest

# clean_file (tests/conftest.py): the registered add-on and a fresh scene set up for Cycles.
pytestmark = [pytest.mark.bpy, pytest.mark.usefixtures("clean_file")]
bpy = pytest.importorskip("bpy")

from blender_addon import pbr_import, relight_operator  # noqa: E402
from blender_addon.core.frustum import blender_frustum  # noqa: E402
from blender_addon.core.map_io import dilate as map_io_dilate  # noqa: E402
from pbrdf.io.exr import read_exr, write_exr  # noqa: E402
from tests.helpers import add_camera, write_pbr_maps  # noqa: E402

H, W = 24, 32


def _principled(obj):
    return next(n for n in obj.active_material.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")


def _flat_plane(scene, tmp_path, albedo=0.5, distance=1.0):
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = 1
    folder = write_pbr_maps(tmp_path / "flat", normal, albedo=np.full((H, W, 3), albedo, np.float32))
    obj = pbr_import.import_pbr_maps(bpy.context, folder, pbr_import.ImportOptions(distance=distance))
    _principled(obj).inputs["Specular IOR Level"].default_value = 0.0  # pure Lambert
    return obj


def _keyframe_counts(obj):
    from bpy_extras import anim_utils

    bag = anim_utils.action_get_channelbag_for_slot(obj.animation_data.action, obj.animation_data.action_slot)
    return {(fc.data_path, fc.array_index): len(fc.keyframe_points) for fc in bag.fcurves}


def test_orbit_keyframes_on_circle(clean_file, tmp_path):
    scene = clean_file
    add_camera(scene, (0.0, -1.0, 0.3), (1.4, 0.0, 0.1))
    plane = _flat_plane(scene, tmp_path, distance=1.2)
    bpy.context.view_layer.objects.active = plane
    scene.pdir_relight.radius, scene.pdir_relight.height, scene.pdir_relight.frames = 0.5, 0.3, 12
    assert bpy.ops.pdir.add_light_orbit() == {"FINISHED"}
    light = bpy.data.objects[relight_operator.ORBIT_LIGHT_NAME]
    assert _keyframe_counts(light) == {("location", i): 12 for i in range(3)}
    assert (scene.frame_start, scene.frame_end) == (1, 12)
    mw = plane.matrix_world
    axis = np.array(mw.to_3x3().col[2]).ravel()
    axis /= np.linalg.norm(axis)
    centre = np.array(mw.translation) + 0.3 * axis
    cam_pos = np.array(scene.camera.matrix_world.translation)
    assert np.dot(cam_pos - np.array(mw.translation), axis) > 0  # the axis points toward the camera
    angles = []
    for f in range(1, 13):
        scene.frame_set(f)
        d = np.array(light.matrix_world.translation) - centre
        assert np.linalg.norm(d) == pytest.approx(0.5, abs=1e-6)
        assert np.dot(d, axis) == pytest.approx(0.0, abs=1e-6)
        angles.append(d)
    steps = [
        math.degrees(math.acos(np.clip(np.dot(a, b) / 0.25, -1, 1)))
        for a, b in zip(angles[:-1], angles[1:], strict=True)
    ]
    np.testing.assert_allclose(steps, 30.0, atol=1e-4)
    # re-running replaces the light
    relight_operator.add_point_light_orbit(scene, plane, radius=1.0, height=0.0, frames=3, energy=5.0)
    assert sum(o.type == "LIGHT" for o in scene.objects) == 1 and scene.frame_end == 3
    with pytest.raises(ValueError, match="frames must be an integer >= 1"):
        relight_operator.add_point_light_orbit(scene, plane, radius=1.0, height=0.0, frames=0, energy=5.0)


def test_point_light_relight_matches_lambert(clean_file, tmp_path):
    scene = clean_file
    albedo, power = 0.5, 20.0
    _flat_plane(scene, tmp_path, albedo=albedo, distance=1.0)  # a new camera at the origin, plane at z = -1
    plane = next(o for o in scene.objects if o.type == "MESH")
    light = relight_operator.add_point_light_orbit(scene, plane, radius=0.3, height=0.4, frames=4, energy=power)
    (out,) = relight_operator.render_relit(scene, tmp_path / "relit", samples=8, frames=[2], file_format="OPEN_EXR")
    assert out.name == "relit_0002.exr"
    img = read_exr(out)
    rgb = np.stack([img[c] for c in "RGB"], -1)
    # analytic: L (frame 2, quarter turn) = (0, 0.3, -0.6); I = P / (4 pi); E = I cos / r^2; radiance = a / pi E
    scene.frame_set(2)
    lpos = np.array(light.matrix_world.translation)
    np.testing.assert_allclose(lpos, (0.0, 0.3, -0.6), atol=1e-6)
    fr = blender_frustum(W, H, lens=50.0, sensor_width=36.0, sensor_height=24.0)
    p = np.concatenate([fr.pixel_xy(), -np.ones((H, W, 1))], -1)
    to_light = lpos - p
    r = np.linalg.norm(to_light, axis=-1)
    expected = albedo / np.pi * power / (4 * np.pi) * (to_light[..., 2] / r) / r**2
    ratio = rgb / expected[..., None]
    # measured: median ratio 1.0000, max deviation 0.35 %
    assert np.median(ratio) == pytest.approx(1.0, abs=0.01)
    assert np.abs(ratio - 1).max() < 0.03


def test_constant_environment_is_a_white_furnace(clean_file, tmp_path):
    scene = clean_file
    albedo, env, strength = 0.5, 0.8, 1.5
    _flat_plane(scene, tmp_path, albedo=albedo)
    hdr = tmp_path / "const.exr"
    write_exr(hdr, {c: np.full((8, 16), env, np.float32) for c in "RGB"})
    world = relight_operator.add_environment(scene, hdr_path=hdr, strength=strength)
    assert scene.world == world and any(n.bl_idname == "ShaderNodeTexEnvironment" for n in world.node_tree.nodes)
    (out,) = relight_operator.render_relit(scene, tmp_path / "env", samples=64, frames=[1], file_format="OPEN_EXR")
    rgb = np.stack([read_exr(out)[c] for c in "RGB"], -1)
    # a Lambertian plane seeing a constant sky: radiance = albedo * L_env * strength
    expected = albedo * env * strength
    # measured (64 spp): median ratio 0.9998, max deviation 1.7 %
    assert np.median(rgb) == pytest.approx(expected, rel=0.01)
    assert np.abs(rgb / expected - 1).max() < 0.05
    with pytest.raises(FileNotFoundError, match="environment file not found"):
        relight_operator.add_environment(scene, hdr_path=tmp_path / "missing.hdr")


def test_sky_environment_and_render_operator(clean_file, tmp_path):
    scene = clean_file
    _flat_plane(scene, tmp_path)
    plane = next(o for o in scene.objects if o.type == "MESH")
    bpy.context.view_layer.objects.active = plane
    s = scene.pdir_relight
    s.strength, s.frames, s.samples, s.out_dir = 0.01, 2, 1, str(tmp_path / "frames")
    assert bpy.ops.pdir.add_environment() == {"FINISHED"}
    sky = next(n for n in scene.world.node_tree.nodes if n.bl_idname == "ShaderNodeTexSky")
    assert sky.sky_type == "MULTIPLE_SCATTERING"
    assert bpy.ops.pdir.add_light_orbit() == {"FINISHED"}
    assert bpy.ops.pdir.render_relit() == {"FINISHED"}
    files = sorted(p.name for p in (tmp_path / "frames").iterdir())
    assert files == ["relit_0001.png", "relit_0002.png"]  # no temporary leftovers
    # the sky lights the plane: linear EXR values finite and positive
    (out,) = relight_operator.render_relit(scene, tmp_path / "sky", samples=1, frames=[1], file_format="OPEN_EXR")
    rgb = np.stack([read_exr(out)[c] for c in "RGB"], -1)
    assert np.isfinite(rgb).all() and rgb.mean() > 0


def test_gpu_request_falls_back_or_uses_gpu(clean_file, tmp_path):
    scene = clean_file
    _flat_plane(scene, tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        files = relight_operator.render_relit(scene, tmp_path / "gpu", device="GPU", samples=1, frames=[1])
    used = scene.cycles.device
    fallback = [w for w in caught if issubclass(w.category, relight_operator.RelightWarning)]
    assert (used == "CPU") == bool(fallback)
    assert not fallback or "rendering on the CPU" in str(fallback[0].message)
    assert files[0].is_file()
    scene.camera = None
    with pytest.raises(ValueError, match="has no camera"):
        relight_operator.render_relit(scene, tmp_path / "x")
    with pytest.raises(ValueError, match="device must be"):
        relight_operator.select_device(scene, "TPU")


def test_log_names_no_temporary_file(clean_file, tmp_path, capfd):
    """Frames are written through temporary siblings, but Blender's log never names one (no `Saved: '.x.tmp-...'`)."""
    scene = clean_file
    _flat_plane(scene, tmp_path)
    capfd.readouterr()
    files = relight_operator.render_relit(scene, tmp_path / "frames", samples=1, frames=[1, 2], prefix="point_")
    out, err = capfd.readouterr()
    assert ".tmp-" not in out + err
    assert [f.name for f in files] == ["point_0001.png", "point_0002.png"]
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["point_0001.png", "point_0002.png"]


# --------------------------------------------------------------------------- relief assets: outline, facets, sky

SH, SW = 48, 64  # the relief sphere's maps (and renders: one render pixel per map pixel)


def _relief_sphere(tmp_path, *, pits=0.0, albedo=0.5):
    """A sphere cap (normals within 60 deg of the view axis) imported as a relief by the default camera.

    Returns the object, the mask, the true normals and the camera-frame points of the pixels.
    ``pits`` moves every 6th pixel of every 6th row that fraction of its depth back (0.004: a
    third of a pixel's width): the triangles around it tilt by about 20 deg, too little to shadow
    anything under a light 45 deg or more above the surface, while the normal map stays the sphere's.
    """
    fr = blender_frustum(SW, SH, lens=50.0, sensor_width=36.0, sensor_height=24.0)
    d = np.concatenate([fr.pixel_xy(), -np.ones((SH, SW, 1))], -1)
    c, radius = np.array([0.03, -0.02, -2.0]), 0.45
    dc, dd = (d * c).sum(-1), (d * d).sum(-1)
    disc = dc**2 - dd * (c @ c - radius**2)
    t = (dc - np.sqrt(np.maximum(disc, 0))) / dd
    p = t[..., None] * d
    n = (p - c) / radius
    mask = (disc > 0) & (n[..., 2] > 0.5)
    yy, xx = np.mgrid[0:SH, 0:SW]
    t = t * (1 + pits * ((yy % 6 == 3) & (xx % 6 == 3)))
    p = t[..., None] * d
    folder = write_pbr_maps(tmp_path / "sphere", np.where(mask[..., None], n, 0).astype(np.float32),
                            albedo=np.full((SH, SW, 3), albedo, np.float32), mask=mask,
                            depth=np.where(mask, t, 0).astype(np.float32))  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", pbr_import.PBRImportWarning)  # OBJECT space on a relief
        obj = pbr_import.import_pbr_maps(bpy.context, folder)
    _principled(obj).inputs["Specular IOR Level"].default_value = 0.0  # pure Lambert
    return obj, mask, n, p


def _point_light(scene, location, power):
    light = bpy.data.objects.new("key", bpy.data.lights.new("key", "POINT"))
    light.data.energy, light.data.shadow_soft_size = power, 0.0
    light.location = location
    scene.collection.objects.link(light)
    return light


def _lambert_ratio(scene, tmp_path, mask, n, p, albedo=0.5, power=300.0, lpos=(0.9, 0.7, -0.9)):
    """Rendered / analytic Lambert radiance at every pixel centre, and ``n . l``."""
    _point_light(scene, lpos, power)
    (out,) = relight_operator.render_relit(scene, tmp_path / "relit", samples=16, frames=[1], file_format="OPEN_EXR")
    img = read_exr(out)
    rgb = np.stack([img[c] for c in "RGB"], -1).mean(-1)
    to_light = np.asarray(lpos) - p
    r = np.linalg.norm(to_light, axis=-1)
    cos = (n * to_light).sum(-1) / r
    expected = albedo / np.pi * power / (4 * np.pi) * np.clip(cos, 0, None) / r**2
    return rgb / np.maximum(expected, 1e-12), cos


def _erode(mask, rings):
    return ~map_io_dilate(~mask, rings)


def test_relief_outline_relights_like_its_interior(clean_file, tmp_path):
    """Pixels within 2 px of the mask edge match the analytic Lambert render as well as the interior.

    The relief mesh used to end at the edge pixels' centres, so each edge pixel was half background.
    """
    scene = clean_file
    _, mask, n, p = _relief_sphere(tmp_path)
    ratio, cos = _lambert_ratio(scene, tmp_path, mask, n, p)
    lit = mask & (cos > 0.2)
    inner = _erode(mask, 2)
    edge, interior = lit & ~inner, lit & inner
    assert edge.sum() > 40 and interior.sum() > 400
    for region in (interior, edge):
        # measured (16 spp): median 1.0000 in both; edge pixels 0.994-1.029 (half of them about 0.5 when
        # the mesh ended at the edge pixels' centres)
        assert np.median(ratio[region]) == pytest.approx(1.0, abs=0.01)
        assert np.abs(ratio[region] - 1).max() < 0.05


def test_relief_shading_follows_the_normals_not_the_triangles(clean_file, tmp_path):
    """A relief whose triangles tilt away from the normal map still shades like the normals (no dark blotches).

    Through a Normal Map node Cycles takes the normals for bump detail on the flat triangles and
    darkens them by its bump-shadowing term where a triangle turns away from the light.
    """
    scene = clean_file
    _, mask, n, p = _relief_sphere(tmp_path, pits=0.004)
    ratio, cos = _lambert_ratio(scene, tmp_path, mask, n, p)
    region = _erode(mask, 2) & (cos > 0.4)
    assert region.sum() > 300
    # measured (16 spp): median 1.0000, 1st percentile 0.999 (0.95 through the Normal Map node), lowest 0.998
    assert np.median(ratio[region]) == pytest.approx(1.0, abs=0.01)
    assert np.percentile(ratio[region], 1) > 0.97 and ratio[region].min() > 0.95


def test_sky_frame_has_no_sun_band(clean_file, tmp_path):
    """The default sky lights a relief without a clipped, sunlit half behind a hard terminator."""
    scene = clean_file
    _, mask, _, _ = _relief_sphere(tmp_path)
    world = relight_operator.add_environment(scene, strength=0.3)
    (out,) = relight_operator.render_relit(scene, tmp_path / "sky", samples=16, frames=[1], file_format="OPEN_EXR")
    y = np.stack([read_exr(out)[c] for c in "RGB"], -1).mean(-1)[_erode(mask, 1)]
    # measured (16 spp): brightest 0.79, p95 / p5 1.7; with the sun disc 60 % of the pixels above 1 (clipped
    # in a PNG), brightest 4.9, p95 / p5 10.5
    assert y.max() < 1.0
    assert np.percentile(y, 95) / np.percentile(y, 5) < 3.0
    assert not next(x for x in world.node_tree.nodes if x.bl_idname == "ShaderNodeTexSky").sun_disc
    world = relight_operator.add_environment(scene, strength=0.3, sun=True)  # rebuilt: a new Sky Texture node
    assert next(x for x in world.node_tree.nodes if x.bl_idname == "ShaderNodeTexSky").sun_disc
