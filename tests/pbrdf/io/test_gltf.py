"""The glTF 2.0 binary writer (pbrdf/io/gltf.py): container layout, validator rules, trimesh read-back, bad input."""

import numpy as np
import pytest

from pbrdf.io.gltf import GlbCamera, GlbMaterial, GlbMesh, encode_png, glb_bytes, write_glb
from tests.gltf_helpers import accessor, image, read_glb, validate


def _grid_mesh(n=5):
    """A camera-facing n x n vertex grid at z = -1 with glTF UVs (v down) and the matching frame."""
    ys, xs = np.mgrid[0:n, 0:n] / (n - 1)
    pos = np.stack([xs.ravel() - 0.5, 0.5 - ys.ravel(), -np.ones(n * n)], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([c, d, a], 1), np.stack([d, b, a], 1)])
    return GlbMesh(pos, np.tile([0.0, 0, 1], (n * n, 1)), np.tile([1.0, 0, 0, 1], (n * n, 1)),
                   np.stack([xs.ravel(), ys.ravel()], 1), faces)  # fmt: skip


def _material(rng):
    imgs = [rng.integers(0, 256, (3, 5, c), dtype=np.uint8) for c in (4, 3, 3)]
    return GlbMaterial(*(encode_png(i) for i in imgs)), imgs


def test_file_follows_the_spec_and_round_trips(rng):
    mesh, (material, imgs) = _grid_mesh(), _material(rng)
    cam = GlbCamera(0.7, 1.5, 0.01, 100.0, extras={"k": [1, 2]})
    data = glb_bytes(mesh, material, cam, name="grid", extras={"note": "x"})
    doc, blob = read_glb(data)
    assert validate(doc, blob) == []
    assert all(v["byteOffset"] % 4 == 0 for v in doc["bufferViews"])
    att = doc["meshes"][0]["primitives"][0]["attributes"]
    assert sorted(att) == ["NORMAL", "POSITION", "TANGENT", "TEXCOORD_0"]
    np.testing.assert_allclose(accessor(doc, blob, att["POSITION"]), mesh.positions, atol=1e-7)
    np.testing.assert_array_equal(accessor(doc, blob, att["TANGENT"]), mesh.tangents)
    idx = doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]
    assert (idx["componentType"], idx["count"]) == (5125, mesh.indices.size)  # uint32
    for i, want in enumerate(imgs):
        np.testing.assert_array_equal(image(doc, blob, i), want)
    mat = doc["materials"][0]
    assert mat["pbrMetallicRoughness"]["metallicRoughnessTexture"] == {"index": 1}
    assert mat["normalTexture"]["index"] == 2 and mat["alphaMode"] == "MASK" and mat["doubleSided"] is False
    assert doc["samplers"] == [{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}]
    assert doc["cameras"][0]["perspective"] == {"yfov": 0.7, "aspectRatio": 1.5, "znear": 0.01, "zfar": 100.0}
    assert doc["scenes"][0]["nodes"] == [0, 1] and doc["cameras"][0]["extras"] == {"k": [1, 2]}
    assert doc["asset"]["extras"] == {"note": "x"}
    no_cam, _ = read_glb(glb_bytes(mesh, material))
    assert "cameras" not in no_cam and no_cam["scenes"][0]["nodes"] == [0]


def test_trimesh_reads_geometry_uvs_and_textures(rng, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    mesh, (material, imgs) = _grid_mesh(), _material(rng)
    path = write_glb(tmp_path / "grid.glb", mesh, material, GlbCamera(0.7, 1.0, 0.01))
    scene = trimesh.load(path, process=False)
    got = next(iter(scene.geometry.values()))
    np.testing.assert_allclose(got.vertices, mesh.positions, atol=1e-7)
    np.testing.assert_array_equal(got.faces, mesh.indices)
    np.testing.assert_allclose(got.visual.uv[:, 1], 1 - np.asarray(mesh.uvs)[:, 1], atol=1e-7)  # trimesh: v up
    np.testing.assert_array_equal(np.asarray(got.visual.material.baseColorTexture), imgs[0])
    assert scene.has_camera and (got.face_normals[:, 2] > 0.999).all()  # counter-clockwise: facing +z


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"normals": np.tile([0.0, 0, 2], (25, 1))}, "^normals: xyz must be unit length"),
        ({"tangents": np.tile([1.0, 0, 0, 0], (25, 1))}, r"^tangents: w \(handedness\)"),
        ({"indices": np.array([[0, 1, 25]])}, r"^indices: must lie in \[0, 25\)"),
        ({"positions": np.full((25, 3), np.nan)}, r"^positions: expected a finite \(N, 3\)"),
        ({"uvs": np.zeros((24, 2))}, "need the same non-zero length"),
    ],
)
def test_bad_mesh_is_one_line_and_writes_nothing(change, message, rng, tmp_path):
    fields = {k: getattr(_grid_mesh(), k) for k in ("positions", "normals", "tangents", "uvs", "indices")}
    with pytest.raises(ValueError, match=message):
        write_glb(tmp_path / "bad.glb", GlbMesh(**{**fields, **change}), _material(rng)[0])
    assert not list(tmp_path.iterdir())


def test_bad_camera_and_image():
    with pytest.raises(ValueError, match="^camera:"):
        glb_bytes(_grid_mesh(), GlbMaterial(b"", b"", b""), GlbCamera(4.0, 1.0, 0.01))
    with pytest.raises(ValueError, match=r"^image: expected uint8"):
        encode_png(np.zeros((2, 2, 3), np.float32))
