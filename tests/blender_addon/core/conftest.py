"""Fixtures shared by the scene-side tests."""

import pytest
import trimesh

from blender_addon.core import assets


@pytest.fixture(scope="session")
def slab_path(tmp_path_factory):
    """A 0.3 m square, 1 cm thick slab facing +z (toward the camera), finely subdivided so the
    front face's vertex normals are exactly +z."""
    box = trimesh.creation.box(extents=(0.3, 0.3, 0.01))
    for _ in range(4):
        box = box.subdivide()
    path = tmp_path_factory.mktemp("mesh") / "slab.ply"
    assets.write_ply(box, path)
    return str(path)
