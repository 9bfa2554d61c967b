"""The reconstruction as a glTF asset (pbrdf/data/gltf_asset.py), read back independently (tests/gltf_helpers.py).

The physics check: a viewer rebuilds the shading normal as ``T x + B y + N z`` from the normal
map and the exported vertex frame interpolated over each triangle; done here with our own
barycentric interpolation at every texel centre on the mask, it must give the predicted
camera-space normals back (p99 within 2 degrees; 8-bit rounding alone allows about 0.4).
"""

import math

import numpy as np
import pytest

from pbrdf.data.gltf_asset import build_asset, capture_camera, write_gltf_asset
from pbrdf.sensor.projection import camera_to_pixel
from tests.gltf_helpers import attributes, image, read_glb, shading_normals, sphere_prediction, validate

H, W = 40, 56
# off-centre principal point and fx != fy: the camera must still put every vertex on its pixel
K = np.array([[64.0, 0.0, 30.0], [0.0, 60.0, 18.5], [0.0, 0.0, 1.0]])


def _srgb(x):
    """IEC 61966-2-1 encoding, written out independently of the module."""
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _srgb_to_linear(s):
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


@pytest.fixture(scope="module")
def relief(tmp_path_factory):
    pred = sphere_prediction(np.random.default_rng(3), K, H, W)
    path = write_gltf_asset(tmp_path_factory.mktemp("glb") / "sphere.glb", pred, K, name="sphere")
    return pred, path, read_glb(path.read_bytes())


@pytest.fixture(scope="module")
def card(tmp_path_factory):
    pred = sphere_prediction(np.random.default_rng(4), K, H, W)
    del pred["depth"]
    path = write_gltf_asset(tmp_path_factory.mktemp("glb") / "card.glb", pred, K, distance=0.8)
    return pred, path, read_glb(path.read_bytes())


def _box(doc):
    return doc["asset"]["extras"]["texture_box_rows_cols"]


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1, 1)))


@pytest.mark.parametrize("which", ["relief", "card"])
def test_normal_map_reproduces_the_predicted_normals(which, request):
    pred, _, (doc, blob) = request.getfixturevalue(which)
    y0, x0, y1, x1 = _box(doc)
    covered, n = shading_normals(doc, blob)
    inside = pred["mask"][y0:y1, x0:x1, 0] > 0
    # every mask texel lies on the mesh but where the relief drops triangles across steep depth
    # steps at the rim (pbrdf.geometry.relief: > 5 % within a triangle, as in the Blender import)
    assert covered[inside].mean() > 0.99
    on = inside & covered
    err = _angle_deg(n[on], pred["normal"][y0:y1, x0:x1][on])
    assert np.percentile(err, 99) < 2.0 and err.max() < 2.0, (np.percentile(err, 99), err.max())
    # not a trivial map: the ripples are in the map, not in the mesh's own normals
    ts = image(doc, blob, 2)[inside] / 255.0 * 2 - 1
    assert np.degrees(np.arccos(np.clip(ts[:, 2], -1, 1))).max() > 10


@pytest.mark.parametrize("which", ["relief", "card"])
def test_tangent_frames_follow_the_uvs(which, request):
    """T along dP/du, B = cross(N, T) w up the image (-dP/dv: glTF's v runs down), as MikkTSpace would make them."""
    _, _, (doc, blob) = request.getfixturevalue(which)
    attrs, faces = attributes(doc, blob)
    p, uv = attrs["POSITION"][faces], attrs["TEXCOORD_0"][faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    jac = np.linalg.solve(np.stack([d1, d2], 1), np.stack([e1, e2], 1))  # rows dP/du, dP/dv per face
    t = attrs["TANGENT"][faces].mean(1)
    n = attrs["NORMAL"][faces].mean(1)
    b = np.cross(n, t[:, :3]) * np.sign(t[:, 3:])
    cos_t = (t[:, :3] * jac[:, 0]).sum(1) / np.linalg.norm(t[:, :3], axis=1) / np.linalg.norm(jac[:, 0], axis=1)
    cos_b = -(b * jac[:, 1]).sum(1) / np.linalg.norm(b, axis=1) / np.linalg.norm(jac[:, 1], axis=1)
    assert np.percentile(cos_t, 5) > 0.95 and (cos_t > 0).all()
    # B is orthogonal to T, dP/dv need not be (a slanted surface): the handedness is what must agree
    assert np.median(cos_b) > 0.9 and (cos_b > 0).all()
    assert (np.abs((attrs["TANGENT"][:, :3] * attrs["NORMAL"]).sum(1)) < 1e-5).all()  # orthogonal to N


def test_textures_round_trip_within_8_bit(relief):
    pred, _, (doc, blob) = relief
    y0, x0, y1, x1 = _box(doc)
    inside = pred["mask"][y0:y1, x0:x1, 0] > 0
    mat = doc["materials"][0]
    base = image(doc, blob, mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]) / 255.0
    mr = image(doc, blob, mat["pbrMetallicRoughness"]["metallicRoughnessTexture"]["index"]) / 255.0
    albedo = pred["albedo"][y0:y1, x0:x1][inside]
    half = 0.5 / 255 + 1e-6
    assert np.abs(base[inside][:, :3] - _srgb(albedo)).max() <= half  # sRGB-encoded, rounded
    # decoded back to linear: off by at most half an 8-bit step times the slope of the sRGB decode
    slope = np.where(_srgb(albedo) <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((_srgb(albedo) + 0.055) / 1.055) ** 1.4)
    assert (np.abs(_srgb_to_linear(base[inside][:, :3]) - albedo) <= half * slope * 1.01 + 1e-7).all()
    np.testing.assert_array_equal(base[..., 3], inside.astype(float))  # alpha is the mask
    assert np.abs(mr[inside][:, 1] - pred["roughness"][y0:y1, x0:x1][inside][:, 0]).max() <= half
    assert np.abs(mr[inside][:, 2] - pred["metallic"][y0:y1, x0:x1][inside][:, 0]).max() <= half
    assert (mat["alphaMode"], mat["alphaCutoff"], mat["doubleSided"]) == ("MASK", 0.5, False)
    assert validate(doc, blob) == []


def test_trimesh_reads_the_mesh_on_its_pixels(relief):
    trimesh = pytest.importorskip("trimesh")
    pred, path, (doc, blob) = relief
    scene = trimesh.load(path, process=False)
    mesh = next(iter(scene.geometry.values()))
    assert np.allclose(scene.graph[scene.graph.nodes_geometry[0]][0], np.eye(4))  # the camera frame itself
    y0, x0, y1, x1 = _box(doc)
    uv, depth_map = mesh.visual.uv, pred["depth"][..., 0]
    # trimesh flips v to OpenGL's (v up); texel centres are the vertices' pixels
    col = uv[:, 0] * (x1 - x0) - 0.5 + x0
    row = (1 - uv[:, 1]) * (y1 - y0) - 0.5 + y0
    np.testing.assert_allclose([col, row], np.rint([col, row]), atol=1e-4)
    pix, depth = camera_to_pixel(mesh.vertices, K)
    np.testing.assert_allclose(pix, np.stack([col, row], 1) + 0.5, atol=1e-4)
    inside = pred["mask"][np.rint(row).astype(int), np.rint(col).astype(int), 0] > 0
    np.testing.assert_allclose(depth[inside], depth_map[np.rint(row).astype(int), np.rint(col).astype(int)][inside],
                               rtol=1e-6)  # fmt: skip
    # one vertex per mask pixel (but a few at the rim whose triangles cross a steep step), plus the outline ring
    assert (pred["mask"] > 0).sum() - 5 < inside.sum() <= (pred["mask"] > 0).sum()
    faces_normals = mesh.face_normals
    assert (faces_normals[:, 2] > 0).mean() > 0.95  # counter-clockwise seen from the camera: facing it
    tex = mesh.visual.material.baseColorTexture
    np.testing.assert_array_equal(np.asarray(tex), image(doc, blob, 0))


def test_trimesh_decodes_the_three_textures_to_the_predicted_maps(relief):
    """Through trimesh's loader: at every mask vertex (a texel centre) each texture gives its map back to 8 bits.

    trimesh keeps no TANGENT, so the normal map is decoded with trimesh's vertex normals and the
    file's TANGENT accessor (same vertex order: process=False), ``n = T x + cross(N, T) w y + N z``.
    """
    trimesh = pytest.importorskip("trimesh")
    pred, path, (doc, blob) = relief
    scene = trimesh.load(path, process=False)
    mesh = next(iter(scene.geometry.values()))
    attrs, _ = attributes(doc, blob)
    np.testing.assert_allclose(mesh.vertices, attrs["POSITION"], atol=1e-7)  # same vertices, same order
    y0, x0, y1, x1 = _box(doc)
    row = np.rint((1 - mesh.visual.uv[:, 1]) * (y1 - y0) - 0.5).astype(int)  # trimesh flips v to OpenGL's
    col = np.rint(mesh.visual.uv[:, 0] * (x1 - x0) - 0.5).astype(int)
    on = pred["mask"][row + y0, col + x0, 0] > 0
    row, col = row[on], col[on]
    want = {k: pred[k][row + y0, col + x0] for k in ("albedo", "roughness", "metallic", "normal")}
    mat = mesh.visual.material
    base = np.asarray(mat.baseColorTexture.convert("RGBA"), float)[row, col] / 255
    mr = np.asarray(mat.metallicRoughnessTexture.convert("RGB"), float)[row, col] / 255
    half = 0.5 / 255 + 1e-6
    # sRGB decode of the 8-bit value: half a step times the decode's slope (and at most half a step near 0)
    s = _srgb(want["albedo"])
    slope = np.where(s <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((s + half + 0.055) / 1.055) ** 1.4)
    assert (np.abs(_srgb_to_linear(base[:, :3]) - want["albedo"]) <= half * slope + 1e-7).all()
    assert (base[:, 3] == 1).all()
    assert np.abs(mr[:, 1] - want["roughness"][:, 0]).max() <= half  # glTF: roughness in G
    assert np.abs(mr[:, 2] - want["metallic"][:, 0]).max() <= half  # metallic in B
    ts = np.asarray(mat.normalTexture.convert("RGB"), float)[row, col] / 255 * 2 - 1
    n, t = mesh.vertex_normals[on], attrs["TANGENT"][on]
    b = np.cross(n, t[:, :3]) * t[:, 3:]
    shading = t[:, :3] * ts[:, :1] + b * ts[:, 1:2] + n * ts[:, 2:]
    err = _angle_deg(shading / np.linalg.norm(shading, axis=1, keepdims=True), want["normal"])
    assert err.max() < 2.0, np.percentile(err, [50, 99, 100])
    # the camera as trimesh reads it: the vertical field of view the capture's fy and frame give
    hy = max(K[1, 2], H - K[1, 2])
    assert scene.camera.fov[1] == pytest.approx(math.degrees(2 * math.atan(hy / K[1, 1])), rel=1e-6)


def test_camera_puts_every_vertex_on_its_pixel(relief):
    pred, _, (doc, blob) = relief
    cam = doc["cameras"][0]
    p = cam["perspective"]
    assert doc["nodes"][1] == {"name": "capture camera", "camera": 0}  # at the origin, no transform
    extras = cam["extras"]
    vw, vh = extras["viewport_px"]
    attrs, _ = attributes(doc, blob)
    v = attrs["POSITION"]
    # the glTF projection (symmetric frustum) mapped onto a vw x vh viewport
    ndc_x = v[:, 0] / (-v[:, 2] * math.tan(p["yfov"] / 2) * p["aspectRatio"])
    ndc_y = v[:, 1] / (-v[:, 2] * math.tan(p["yfov"] / 2))
    viewport = np.stack([(ndc_x + 1) / 2 * vw, (1 - ndc_y) / 2 * vh], 1)
    capture_px, _ = camera_to_pixel(v, K)
    np.testing.assert_allclose(viewport, capture_px + extras["capture_offset_px"], atol=1e-6)
    assert extras["capture_offset_px"] == [0.0, 3.0]  # hx = cx = 30 >= 56 - 30; hy = 40 - 18.5 = 21.5
    np.testing.assert_allclose(extras["intrinsics"], K)


def test_centred_camera_is_the_capture_frame():
    cam = capture_camera([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]], (48, 64))
    assert cam.extras["viewport_px"] == [64.0, 48.0] and cam.extras["capture_offset_px"] == [0.0, 0.0]
    assert cam.yfov == pytest.approx(2 * math.atan(24 / 50)) and cam.aspect_ratio == pytest.approx(64 / 48)


def test_card_is_a_camera_facing_quad_at_the_distance(card):
    pred, _, (doc, blob) = card
    attrs, faces = attributes(doc, blob)
    assert len(attrs["POSITION"]) == 4 and len(faces) == 2
    np.testing.assert_allclose(attrs["POSITION"][:, 2], -0.8, rtol=1e-6)
    np.testing.assert_allclose(attrs["NORMAL"], [[0, 0, 1]] * 4, atol=1e-7)
    np.testing.assert_allclose(attrs["TANGENT"], [[1, 0, 0, 1]] * 4, atol=1e-7)
    y0, x0, y1, x1 = _box(doc)
    pix, _ = camera_to_pixel(attrs["POSITION"], K)  # the quad's corners are the textures' outer pixel edges
    np.testing.assert_allclose(np.sort(pix[:, 0]), [x0, x0, x1, x1], atol=1e-6)
    np.testing.assert_allclose(np.sort(pix[:, 1]), [y0, y0, y1, y1], atol=1e-6)
    assert doc["asset"]["extras"]["mesh"] == "card" and validate(doc, blob) == []


def test_bad_maps_are_one_line_errors(tmp_path):
    pred = sphere_prediction(np.random.default_rng(0), K, H, W)
    with pytest.raises(ValueError, match="^pred: albedo: missing$"):
        build_asset({k: v for k, v in pred.items() if k != "albedo"}, K)
    with pytest.raises(ValueError, match="^pred: mask: empty"):
        build_asset({**pred, "mask": np.zeros_like(pred["mask"])}, K)
    with pytest.raises(ValueError, match="^pred: normal: expected a finite"):
        build_asset({**pred, "normal": np.full_like(pred["normal"], np.nan)}, K)
    with pytest.raises(ValueError, match="^intrinsics:"):
        build_asset(pred, np.eye(2))
    with pytest.raises(ValueError, match="^pred: depth: must be positive"):
        write_gltf_asset(tmp_path / "x.glb", {**pred, "depth": np.zeros_like(pred["depth"])}, K)
    assert not list(tmp_path.iterdir())  # nothing written


def test_unwritable_paths_leave_nothing_behind(tmp_path, monkeypatch):
    """A parent that is a file, a target that is a folder, a failing rename: OSError, no temporary, old file kept."""
    pred = sphere_prediction(np.random.default_rng(1), K, H, W)
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(OSError, match=r"x.glb: cannot write the glTF file: .*a_file is a file, not a folder$"):
        write_gltf_asset(tmp_path / "a_file" / "x.glb", pred, K)
    (tmp_path / "taken.glb").mkdir()
    with pytest.raises(IsADirectoryError, match="taken.glb: cannot write the glTF file: Is a directory$"):
        write_gltf_asset(tmp_path / "taken.glb", pred, K)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a_file", "taken.glb"]
    (tmp_path / "old.glb").write_bytes(b"old")

    def disk_full(*_args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("pbrdf.io.atomic.os.replace", disk_full)
    with pytest.raises(OSError, match="old.glb: cannot write the glTF file: No space left on device$"):
        write_gltf_asset(tmp_path / "old.glb", pred, K)
    assert (tmp_path / "old.glb").read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a_file", "old.glb", "taken.glb"]


def test_edge_inputs_give_valid_files(tmp_path):
    """A one-pixel mask, a mask over the whole frame, values past [0, 1], normals facing away: valid, finite files."""
    pred = sphere_prediction(np.random.default_rng(2), K, H, W)
    speck = np.zeros_like(pred["mask"])
    speck[20, 30] = 1
    doc, blob = read_glb(write_gltf_asset(tmp_path / "speck.glb", {**pred, "mask": speck}, K).read_bytes())
    attrs, faces = attributes(doc, blob)
    assert validate(doc, blob) == [] and len(attrs["POSITION"]) == 9 and len(faces) == 8  # the 3 x 3 grown mask
    plane = {**pred, "mask": np.ones_like(pred["mask"]), "depth": np.full_like(pred["depth"], 0.8)}
    plane["normal"] = np.broadcast_to(np.float32([0, 0.6, 0.8]), pred["normal"].shape)
    doc, blob = read_glb(write_gltf_asset(tmp_path / "plane.glb", plane, K).read_bytes())
    assert validate(doc, blob) == [] and _box(doc) == [0, 0, H, W]  # nothing to extend, the box is the frame
    covered, n = shading_normals(doc, blob)
    assert covered.all() and _angle_deg(n, plane["normal"]).max() < 1.0
    wild = {**pred, "albedo": pred["albedo"] * 3 - 0.5, "roughness": pred["roughness"] - 0.5,
            "metallic": pred["metallic"] + 0.7}  # fmt: skip
    away = pred["normal"] * [1, 1, 0] - [0, 0, 0.3]  # every normal tilted past the horizon, away from the camera
    wild["normal"] = np.where(pred["mask"] > 0, away / np.linalg.norm(away, axis=-1, keepdims=True), 0)
    doc, blob = read_glb(write_gltf_asset(tmp_path / "wild.glb", wild, K).read_bytes())
    y0, x0, y1, x1 = _box(doc)
    inside = pred["mask"][y0:y1, x0:x1, 0] > 0
    mr = image(doc, blob, 1)[inside] / 255.0
    np.testing.assert_allclose(mr[:, 1:], np.clip(np.concatenate([wild["roughness"], wild["metallic"]], -1)
                                                  [y0:y1, x0:x1][inside], 0, 1), atol=0.5 / 255 + 1e-6)  # fmt: skip
    covered, n = shading_normals(doc, blob)
    on = inside & covered
    assert on.mean() > 0.95 * inside.mean() and _angle_deg(n[on], wild["normal"][y0:y1, x0:x1][on]).max() < 2.0
