"""Placement in view: poses inside the view at the drawn distance and size, seeded, uniform rotations."""

import numpy as np
import pytest
import trimesh

from blender_addon.core import placement
from blender_addon.core.procedural import PROCEDURAL_SHAPES, diameter, procedural
from pbrdf.sensor.rig import CameraSpec, Rig
from tests.conftest import TOL

SHAPES = PROCEDURAL_SHAPES


def _bbox_centre(v):
    return (v.min(axis=0) + v.max(axis=0)) / 2


class TestPlace:
    def test_in_view_at_distance_and_size_for_200_seeds(self):
        rig = Rig()
        cam = rig.camera
        margin_px = 0.03 * min(cam.sensor_width_px, cam.sensor_height_px)
        meshes = [procedural(s, seed=1) for s in SHAPES]
        for seed in range(200):
            mesh = meshes[seed % len(meshes)]
            m = placement.place(mesh, rig, np.random.default_rng(seed))
            v = np.asarray(mesh.vertices)
            world = v @ m[:3, :3].T + m[:3, 3]
            assert rig.in_view(world, margin_px=margin_px - 1e-6)
            centre = m[:3, :3] @ _bbox_centre(v) + m[:3, 3]
            assert 0.5 - 1e-12 <= np.linalg.norm(centre) <= 1.0 + 1e-12
            scale = np.cbrt(np.linalg.det(m[:3, :3]))
            np.testing.assert_allclose(m[:3, :3].T @ m[:3, :3], scale**2 * np.eye(3), atol=TOL.f64)  # similarity
            assert 0.15 - 1e-12 <= scale * diameter(mesh) <= 0.35 + 1e-12
            np.testing.assert_array_equal(m[3], [0, 0, 0, 1])

    def test_seeded(self):
        mesh = procedural("blob")
        a = placement.place(mesh, Rig(), np.random.default_rng(5))
        b = placement.place(mesh, Rig(), np.random.default_rng(5))
        c = placement.place(mesh, Rig(), np.random.default_rng(6))
        np.testing.assert_array_equal(a, b)
        assert not np.allclose(a, c)

    def test_posed_camera_and_unnormalised_mesh(self):
        pose = np.eye(4)
        pose[:3, :3] = trimesh.transformations.rotation_matrix(2.0, [0, 1, 0])[:3, :3]
        pose[:3, 3] = [0.3, 0.1, -0.2]
        rig = Rig(camera=CameraSpec(to_world=pose))
        mesh = trimesh.creation.box(extents=(40.0, 10.0, 20.0))  # centimetres, off-centre
        mesh.apply_translation([100.0, 0.0, 0.0])
        for seed in range(20):
            m = placement.place(mesh, rig, np.random.default_rng(seed), distance=(0.6, 0.7))
            world = trimesh.transform_points(mesh.vertices, m)
            assert rig.in_view(world, margin_px=61.0)
            centre = trimesh.transform_points([_bbox_centre(np.asarray(mesh.vertices))], m)[0]
            assert 0.6 - 1e-12 <= np.linalg.norm(centre - pose[:3, 3]) <= 0.7 + 1e-12

    def test_rotation_is_uniform(self):
        # Haar measure on SO(3): E[R] = 0 entry-wise; each entry has variance 1/3.
        rng = np.random.default_rng(0)
        rs = np.stack([placement.random_rotation(rng) for _ in range(3000)])
        np.testing.assert_allclose(rs.mean(axis=0), 0.0, atol=0.05)  # 5 sigma = 5 / sqrt(3 * 3000) = 0.053
        np.testing.assert_allclose((rs**2).mean(axis=0), 1 / 3, atol=0.03)
        np.testing.assert_allclose(np.linalg.det(rs), 1.0, atol=TOL.f64)

    def test_impossible(self):
        with pytest.raises(ValueError, match="no pose inside the view after 5 tries"):
            placement.place(procedural("sphere"), Rig(), np.random.default_rng(0), size=(2, 2), max_tries=5)
        with pytest.raises(ValueError, match="distance must be"):
            placement.place(procedural("sphere"), Rig(), np.random.default_rng(0), distance=(1.0, 0.5))
