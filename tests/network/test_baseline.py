"""Tests of network/baseline.py: the irradiance model against quadrature, the solve against its own
model, and the whole baseline against Mitsuba renders of Lambertian objects."""

import dataclasses

import numpy as np
import pytest

from network import baseline, metrics
from pbrdf.sensor import projection
from pbrdf.sensor.irradiance import irradiance_vectors
from pbrdf.sensor.rig import Rig


def _sphere(size=48, radius=0.15, centre=(0.03, -0.02, -0.7), focal=100.0):
    """Exact normals, depth and mask of a sphere seen by a pinhole ``K`` (size x size)."""
    k = projection.pinhole_intrinsics(focal, size, size)
    rays = projection.pixel_rays(k, size, size)
    d = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    c = np.asarray(centre)
    b = d @ c
    disc = b**2 - (c @ c - radius**2)
    mask = disc > 0
    t = b - np.sqrt(np.clip(disc, 0, None))
    p = d * t[..., None]
    n = (p - c) / radius
    n[~mask] = 0
    depth = np.where(mask, -p[..., 2], 0.0)
    return k, n, depth, mask


def _render_unpol(rig, k, normal, depth, mask, albedo):
    """``unpol`` of a Lambertian surface from the exact (horizon-clipped) model."""
    calib = baseline.calibrate(rig, k, mask.shape, np.where(mask, depth, 1.0))
    phi = irradiance_vectors(calib.vertices, calib.radiance, calib.points[mask], normal[mask])
    unpol = np.zeros(mask.shape + (3,))
    unpol[mask] = np.asarray(albedo) / np.pi * np.einsum("pck,pk->pc", phi, normal[mask])
    return unpol


def _all_regions_lit(rig, k, normal, depth, mask):
    """Pixels whose normal keeps every lit display patch above its horizon (at the true points)."""
    calib = baseline.calibrate(rig, k, mask.shape, np.where(mask, depth, 1.0))
    rel = calib.vertices[None] - calib.points[mask][:, None, None, :]
    ok = np.einsum("pqvk,pk->pqv", rel, normal[mask]).min(axis=(1, 2)) > 0
    out = np.zeros_like(mask)
    out[mask] = ok
    return out


def _angles(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1, 1)))


# --------------------------------------------------------------------------- geometry


def test_photometric_stereo_inverts_its_own_model_with_a_coloured_albedo():
    """Exact Lambertian shading (horizon included): normals everywhere, the albedo colour calibrated."""
    rig = Rig()
    k, normal, depth, mask = _sphere()
    albedo = (0.45, 0.72, 0.14)
    unpol = _render_unpol(rig, k, normal, depth, mask, albedo)
    calib = baseline.calibrate(rig, k, mask.shape, np.where(mask, depth, 1.0))
    out = baseline.photometric_stereo(unpol, mask, calib)
    # The grey prior of the colour calibration (chosen for real renders) biases exact data by < 0.5 %.
    np.testing.assert_allclose(out["albedo_rgb"][0], albedo, rtol=5e-3)
    err = _angles(out["normal"], normal)[mask]
    assert err.mean() < 0.5 and np.percentile(err, 99) < 1.0  # 0.05 / 0.5 without the prior
    lit = _all_regions_lit(rig, k, normal, depth, mask)
    assert lit.sum() < 0.8 * mask.sum()  # the horizon matters for many pixels of a sphere
    np.testing.assert_allclose(out["albedo"][lit], np.broadcast_to(albedo, (lit.sum(), 3)), atol=5e-3)


def test_the_camera_frame_is_used():
    """A rotated camera: the patches move into the camera frame and normals stay camera-frame."""
    rot = np.eye(4)
    a = np.radians(20.0)
    rot[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    rot[:3, 3] = [0.02, 0.03, 0.0]
    rig = Rig.from_dict({"camera": {"to_world": rot.tolist()}})
    k, normal, depth, mask = _sphere()
    unpol = _render_unpol(rig, k, normal, depth, mask, (0.5, 0.5, 0.5))
    points_depth = np.where(mask, depth, 1.0)
    good = baseline.photometric_stereo(unpol, mask, baseline.calibrate(rig, k, mask.shape, points_depth))
    wrong = baseline.photometric_stereo(unpol, mask, baseline.calibrate(Rig(), k, mask.shape, points_depth))
    assert metrics.normal_mae_deg(good["normal"], normal, mask) < 0.1
    assert metrics.normal_mae_deg(wrong["normal"], normal, mask) > 2.0


def test_depth_from_the_centre_plane_and_integration():
    """From the centre plane alone the points are 0.1 m off; one integration pass recovers them."""
    rig = Rig()
    k, normal, depth, mask = _sphere()
    unpol = _render_unpol(rig, k, normal, depth, mask, (0.6, 0.6, 0.6))
    centre = 0.7
    flat = baseline.predict(unpol, mask, rig, k, centre, depth_passes=0)
    full = baseline.predict(unpol, mask, rig, k, centre, depth_passes=1)
    assert np.abs(full["depth"] - depth)[mask].mean() < 0.5 * np.abs(centre - depth)[mask].mean()
    assert metrics.normal_mae_deg(full["normal"], normal, mask) < metrics.normal_mae_deg(flat["normal"], normal, mask)
    assert metrics.normal_mae_deg(full["normal"], normal, mask) < 2.0


def test_flat_object_keeps_a_grey_albedo_and_specular_regions_face_the_camera():
    rig = Rig()
    size = 24
    k = projection.pinhole_intrinsics(900.0, size, size)
    mask = np.zeros((size, size), bool)
    mask[6:18, 6:18] = True
    normal = np.zeros((size, size, 3))
    normal[mask] = [0.0, 0.0, 1.0]
    depth = np.full((size, size), 0.7)
    unpol = _render_unpol(rig, k, normal, depth, mask, (0.3, 0.3, 0.3))
    calib = baseline.calibrate(rig, k, mask.shape, depth)
    out = baseline.photometric_stereo(unpol, mask, calib)
    k_rgb = out["albedo_rgb"][0]
    assert np.ptp(k_rgb) < 0.02 * k_rgb.mean()
    assert metrics.normal_mae_deg(out["normal"], normal, mask) < 1.0
    lp = 20.0 * unpol  # the light is mostly polarized: a metal, not a Lambertian surface
    spec = baseline.photometric_stereo(0.05 * unpol, mask, calib, lp=lp)
    view = -calib.points[mask].mean(0)
    np.testing.assert_allclose(spec["normal"][mask], np.broadcast_to(view / np.linalg.norm(view), (mask.sum(), 3)),
                               atol=1e-6)  # fmt: skip


# --------------------------------------------------------------------------- against Mitsuba


def _render(spec, resolution=64, spp=32):
    from blender_addon.core import render

    result = render.render_stokes(spec, render.RenderSettings(resolution=resolution, spp=spp))
    return render.synthesize_sample(spec, result, rng=np.random.default_rng(spec.seed), noise=True)


def _diffuse_scene(spec, albedo):
    from blender_addon.core.spec import MaterialSpec

    mat = MaterialSpec.diffuse("lambert", albedo)
    return dataclasses.replace(
        spec, materials=(mat,), objects=(dataclasses.replace(spec.objects[0], material=mat.name),)
    )


@pytest.mark.mitsuba
def test_grey_lambertian_sphere_rendered_by_mitsuba():
    """Real renders through the camera model and decoder: <= 5 deg on pixels lit by all three regions."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec

    rig = Rig()
    to_world = np.diag([0.3, 0.3, 0.3, 1.0])
    to_world[:3, 3] = (0.0, 0.0, -0.7)
    obj = ObjectSpec(name="ball", mesh="builtin:sphere", to_world=to_world.tolist(), material="grey")
    spec = SceneSpec(rig=rig, objects=(obj,), materials=(MaterialSpec.diffuse("grey", (0.6, 0.6, 0.6)),), seed=3)
    sample, meta = _render(spec)
    mask = sample["mask"].astype(bool)
    gt = sample["normal"]
    pred = baseline.predict_sample(sample["maps"], mask, meta)
    k = np.asarray(meta["intrinsics"])
    lit = _all_regions_lit(rig, k, gt, sample["depth"], mask)
    assert lit.sum() > 0.4 * mask.sum()
    err_lit = metrics.normal_mae_deg(pred["normal"], gt, lit)
    err_all = metrics.normal_mae_deg(pred["normal"], gt, mask)
    constant = np.zeros_like(gt)
    constant[..., 2] = 1.0
    assert err_lit <= 5.0, err_lit
    assert err_all <= 0.25 * metrics.normal_mae_deg(constant, gt, mask), err_all
    # The unpol map of a depolarizing surface is its whole radiance: the albedo comes out absolute.
    np.testing.assert_allclose(np.median(pred["albedo"][lit], axis=0), 0.6, rtol=0.1)


@pytest.mark.mitsuba
def test_beats_a_constant_normal_on_lambertian_procedural_shapes():
    pytest.importorskip("mitsuba")
    from blender_addon.core import scenegen

    rig = Rig()
    rng = np.random.default_rng(11)
    for seed in (1000, 1002, 1007):
        albedo = tuple(float(v) for v in rng.uniform(0.1, 0.9, 3))
        sample, meta = _render(_diffuse_scene(scenegen.random_scene(rig, seed), albedo), spp=16)
        mask = sample["mask"].astype(bool)
        pred = baseline.predict_sample(sample["maps"], mask, meta)
        constant = np.zeros_like(sample["normal"])
        constant[..., 2] = 1.0
        ours = metrics.normal_mae_deg(pred["normal"], sample["normal"], mask)
        const = metrics.normal_mae_deg(constant, sample["normal"], mask)
        assert ours < 10.0 and ours < 0.3 * const, (seed, albedo, ours, const)
        colour = pred["albedo_rgb"][0] / np.sum(pred["albedo_rgb"][0])
        np.testing.assert_allclose(colour, np.asarray(albedo) / sum(albedo), atol=0.05)


def test_lit_points_sit_at_the_mesh_centre_not_the_pose_origin():
    # An asset file need not be centred: its pose's translation can be far from the object. The
    # sidecar's "centre" (world bounding-box centre) is the depth the baseline must use.
    rig = Rig()
    k = np.array([[100.0, 0, 16], [0, 100.0, 16], [0, 0, 1]])
    pose = np.eye(4)
    pose[:3, 3] = rig.camera.camera_to_world()[:3, 3] + rig.camera.camera_to_world()[:3, :3] @ [0, 0, -3.0]
    centre = rig.camera.camera_to_world()[:3, 3] + rig.camera.camera_to_world()[:3, :3] @ np.array([0, 0, -0.6])
    meta = {"rig": rig.to_dict(), "intrinsics": k.tolist(), "objects": [{"to_world": pose.tolist()}]}
    _, _, depth = baseline.sample_geometry(meta, (32, 32))
    assert np.allclose(depth, 3.0)  # an old sidecar: the pose's translation
    meta["objects"][0]["centre"] = centre.tolist()
    _, _, depth = baseline.sample_geometry(meta, (32, 32))
    assert np.allclose(depth, 0.6)


@pytest.mark.mitsuba
@pytest.mark.xfail(
    strict=True,
    reason="open (docs/measurements/evaluation.md, test-scenes): on hard-edged boxes the baseline is no better "
    "than 0.7 x the constant normal (mean 36.7 against 48.9 deg here, one box at 63 deg)",
)
def test_beats_a_constant_normal_on_coloured_plastic_boxes(tmp_path):
    # A box shows at most three normals: its albedo colour is barely identifiable from shading
    # (the grey prior of the calibration helps on tuning renders, not enough here).
    pytest.importorskip("mitsuba")
    trimesh = pytest.importorskip("trimesh")
    from blender_addon.core import assets, placement
    from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec

    path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.0, 0.8, 0.6)).export(path)
    rig = Rig()
    rng = np.random.default_rng(5)
    ours, const = [], []
    for seed in range(4):
        albedo = tuple(float(v) for v in rng.uniform(0.2, 0.8, 3))
        pose = placement.place(assets.load_mesh(str(path)), rig, rng, distance=(0.5, 0.7), size=(0.2, 0.3))
        mat = MaterialSpec.plastic("p", albedo, roughness=float(rng.uniform(0.15, 0.4)))
        spec = SceneSpec(rig=rig, objects=(ObjectSpec("box", str(path), pose.tolist(), "p"),), materials=(mat,),
                         seed=seed)  # fmt: skip
        sample, meta = _render(spec, spp=16)
        mask = sample["mask"].astype(bool)
        pred = baseline.predict_sample(sample["maps"], mask, meta)
        constant = np.zeros_like(sample["normal"])
        constant[..., 2] = 1.0
        ours.append(metrics.normal_mae_deg(pred["normal"], sample["normal"], mask))
        const.append(metrics.normal_mae_deg(constant, sample["normal"], mask))
    assert np.mean(ours) < 0.7 * np.mean(const), (ours, const)
