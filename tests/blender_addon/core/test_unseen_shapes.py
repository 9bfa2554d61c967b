"""blender_addon/core/unseen_shapes.py: closed, outward, unit-size meshes outside the training shapes."""

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from blender_addon.core import assets, scenegen  # noqa: E402
from blender_addon.core.procedural import PROCEDURAL_SHAPES, diameter  # noqa: E402
from blender_addon.core.unseen_shapes import UNSEEN_SHAPES, unseen_shape  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402


@pytest.mark.parametrize("shape", UNSEEN_SHAPES)
def test_closed_outward_unit_diameter(shape):
    mesh = unseen_shape(shape)
    assert mesh.is_watertight and mesh.is_winding_consistent
    for part in mesh.split(only_watertight=False):
        assert part.volume > 0, f"{shape}: a part faces inward"
    assert diameter(mesh) == pytest.approx(1.0)
    # Outward: a point nudged along a face normal is outside (winding number 0), against it inside (1).
    rng = np.random.default_rng(0)
    faces = rng.choice(len(mesh.faces), size=min(100, len(mesh.faces)), replace=False)
    centre = mesh.triangles_center[faces]
    step = 1e-3 * mesh.face_normals[faces]
    np.testing.assert_allclose(winding_number(mesh, centre + step), 0.0, atol=0.05)
    np.testing.assert_allclose(winding_number(mesh, centre - step), 1.0, atol=0.05)


def winding_number(mesh, points):
    """Generalised winding number: the solid angle of the oriented triangles seen from each point / 4 pi
    (Van Oosterom & Strackee 1983), independent of the mesh code under test."""
    a, b, c = (mesh.vertices[mesh.faces[:, k]][None] - points[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
    den += np.einsum("pfi,pfi->pf", c, a) * lb
    return (2 * np.arctan2(det, den)).sum(axis=1) / (4 * np.pi)


def test_not_among_the_training_shapes_and_loadable_by_reference():
    assert not set(UNSEEN_SHAPES) & set(PROCEDURAL_SHAPES)
    mesh = assets.load_mesh("builtin:gear")
    assert len(mesh.faces) == len(unseen_shape("gear").faces)
    with pytest.raises(ValueError, match="takes no parameters"):
        assets.load_mesh("builtin:gear?seed=3")


def test_scenes_draw_only_from_the_given_shapes():
    rig = Rig()
    picked = {scenegen.random_scene(rig, s, shapes=UNSEEN_SHAPES).objects[0].mesh for s in range(12)}
    assert picked <= {f"builtin:{s}" for s in UNSEEN_SHAPES} and len(picked) >= 3
    default = {scenegen.random_scene(rig, s).objects[0].mesh.split("?")[0] for s in range(12)}
    assert default <= {f"builtin:{s}" for s in PROCEDURAL_SHAPES}
