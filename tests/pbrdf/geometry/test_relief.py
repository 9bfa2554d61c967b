"""Relief meshes and maps extended past a mask (pbrdf/geometry/relief.py; Blender's UVs: test_frustum.py)."""

import numpy as np

from pbrdf.geometry.relief import dilate, extend_maps, relief_mesh
from pbrdf.sensor.projection import camera_to_pixel


def test_vertices_lie_on_their_pixels_at_their_depth(rng):
    k = np.array([[40.0, 0, 13.0], [0, 44.0, 9.5], [0, 0, 1]])
    depth = rng.uniform(1.0, 1.02, (16, 24))
    valid = rng.uniform(size=depth.shape) > 0.2
    v, faces, pixels = relief_mesh(depth, valid, k)
    uv, d = camera_to_pixel(v, k)
    np.testing.assert_allclose(uv, pixels[:, ::-1] + 0.5, atol=1e-9)
    np.testing.assert_allclose(d, depth[valid], rtol=1e-12)
    assert len(v) == valid.sum() and faces.max() < len(v)
    tri = v[faces]
    assert (np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2] > 0).all()  # facing the camera


def test_extension_renormalises_normals_and_keeps_the_inside(rng):
    filled = np.zeros((9, 9), bool)
    filled[3:6, 3:6] = True
    n = rng.normal(size=(9, 9, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    out = extend_maps({"normal": n, "roughness": rng.uniform(size=(9, 9, 1))}, filled, 2)
    ring = dilate(filled, 2) & ~filled
    np.testing.assert_allclose(np.linalg.norm(out["normal"][ring], axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(out["normal"][filled], n[filled], atol=1e-6)
    assert (out["roughness"][~dilate(filled, 2)] == 0).all()
    assert extend_maps({"normal": n}, np.ones((9, 9), bool)) == {}
