"""Crease-angle corner normals against geometry with known normals (cube, sphere, fold)."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from blender_addon.core import mesh_normals as mn  # noqa: E402
from tests.conftest import TOL  # noqa: E402


def _cube():
    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_cube_hard_edges_keep_face_normals():
    v, f = _cube()
    corner = mn.crease_corner_normals(v, f, crease_deg=30.0)
    fn, _ = mn.face_normals(v, f)
    np.testing.assert_allclose(corner, np.repeat(fn[:, None, :], 3, axis=1), atol=TOL.f64)
    # The six faces are axis-aligned: every corner normal is a signed unit axis.
    assert np.allclose(np.sort(np.abs(corner), axis=-1), [0, 0, 1])


def test_cube_smoothed_is_angle_weighted():
    # Fully smoothed, each cube corner sees 90 degrees of each of its three faces, however the
    # faces are triangulated: the angle-weighted normal is the diagonal (area weights are not).
    v, f = _cube()
    corner = mn.crease_corner_normals(v, f, crease_deg=180.0)
    expected = np.sign(v[f]) / np.sqrt(3.0)
    np.testing.assert_allclose(corner, expected, atol=TOL.f64)


def test_sphere_normals_are_radial():
    s = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    corner = mn.crease_corner_normals(v, f, crease_deg=30.0)
    radial = v[f] / np.linalg.norm(v[f], axis=-1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.einsum("fkj,fkj->fk", corner, radial), -1, 1)))
    assert angle.max() < 0.5  # icosphere vertices lie on the sphere; angle-weighting is near exact
    src, rf, rn = mn.split_by_corner_normals(f, corner)
    assert len(src) == len(v)  # nothing split on a smooth surface
    np.testing.assert_array_equal(np.sort(src), np.arange(len(v)))


def test_weld_joins_uv_seams():
    # A fold whose two halves do not share vertex indices (a UV seam) is still smoothed across
    # the seam when the weld map says the vertices coincide.
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [0, 1, 0], [-1, 0, 0.1]], dtype=float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    weld = np.array([0, 1, 2, 0, 2, 3])
    apart = mn.crease_corner_normals(v, f, crease_deg=30.0)
    joined = mn.crease_corner_normals(v, f, crease_deg=30.0, weld=weld)
    np.testing.assert_allclose(apart[0, 0], [0, 0, 1], atol=TOL.f64)  # no neighbour without the weld
    assert joined[0, 0, 0] > 0.01 and np.allclose(joined[0, 0], joined[1, 0])  # averaged with the tilted face


def test_fold_splits_only_above_the_crease():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0]], dtype=float)
    for tilt_deg, split in ((20.0, False), (40.0, True)):
        t = np.radians(tilt_deg)
        v[3] = [-np.cos(t), 0.0, np.sin(t)]
        f = np.array([[0, 1, 2], [0, 2, 3]])
        corner = mn.crease_corner_normals(v, f, crease_deg=30.0)
        src, _, _ = mn.split_by_corner_normals(f, corner)
        assert (len(src) > 4) == split


def test_zero_angle_corner_falls_back_to_the_face():
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], dtype=float)
    f = np.array([[0, 1, 3], [1, 2, 3]])
    corner = mn.crease_corner_normals(v, f)
    assert np.all(np.isfinite(corner))
    np.testing.assert_allclose(np.linalg.norm(corner, axis=-1), 1.0, atol=TOL.f64)


def test_chunked_pairs_match_one_chunk(monkeypatch):
    s = trimesh.creation.icosphere(subdivisions=2)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    whole = mn.crease_corner_normals(v, f, crease_deg=10.0)
    monkeypatch.setattr(mn, "_PAIR_CHUNK", 7)
    np.testing.assert_allclose(mn.crease_corner_normals(v, f, crease_deg=10.0), whole, atol=TOL.f64)
