"""Sequences that move: per-frame relief geometry (blender_addon/sequence_mesh.py via pbr_import) with the bpy wheel."""

import json

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy, pytest.mark.usefixtures("clean_file")]
bpy = pytest.importorskip("bpy")

from blender_addon import pbr_import  # noqa: E402
from blender_addon.core import map_io  # noqa: E402
from pbrdf.sensor import projection  # noqa: E402
from tests.helpers import add_camera, write_pbr_maps  # noqa: E402

H, W = 24, 32
K = np.array([[60.0, 0.0, 15.7], [0.0, 60.0, 12.4], [0.0, 0.0, 1.0]])  # the capture camera of every frame


def _disc(normal, point, radius=0.4, mask=None):
    """Normals, mask and depth of a tilted disc through ``point`` seen through ``K`` (``mask``: given instead)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    rays = projection.pixel_rays(K, H, W)
    depth = (n @ np.asarray(point)) / (rays @ n)  # ray-plane intersection: metres along the optical axis
    if mask is None:
        mask = np.linalg.norm(rays * depth[..., None] - point, axis=-1) < radius
    return np.where(mask[..., None], n, 0.0).astype(np.float32), mask, np.where(mask, depth, np.inf)


def _write_sequence(folder, frames, *, card=False):
    """``mov_NNNN_*`` maps, camera files and ``mov_sequence.json`` as ``headless/infer.py`` writes them (``--card``)."""
    for i, (n, mask, depth) in enumerate(frames, start=1):
        write_pbr_maps(folder, n, mask=mask, depth=None if card else depth, prefix=f"mov_{i:04d}")
        camera = {"intrinsics": K.tolist(), "width": W, "height": H, "distance_m": 2.0}
        (folder / f"mov_{i:04d}_camera.json").write_text(json.dumps(camera))
    doc = {"name": "mov", "frames": [{"frame": i, "prefix": f"mov_{i:04d}"} for i in range(1, len(frames) + 1)]}
    (folder / "mov_sequence.json").write_text(json.dumps(doc))
    return folder


def _shown(scene):
    """The mesh objects shown at the current frame, by name: in the viewport (the evaluated depsgraph), in renders."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    viewport = sorted(o.name for o in depsgraph.objects if o.type == "MESH")
    render = sorted(o.name for o in scene.objects if o.type == "MESH" and not o.evaluated_get(depsgraph).hide_render)
    return viewport, render, depsgraph


def _assert_relief(obj, cam, depsgraph, mask, depth):
    """The evaluated mesh's vertices lie on the frame's depth along each mask pixel's ray (camera frame)."""
    evaluated = obj.evaluated_get(depsgraph)
    v = np.array([tuple(x.co) for x in evaluated.data.vertices])
    m = np.array(cam.matrix_world.inverted() @ evaluated.matrix_world)
    v = v @ m[:3, :3].T + m[:3, 3]
    support = map_io.dilate(mask)  # the mesh goes one pixel past the outline (pbr_import module docstring)
    assert len(v) == support.sum()
    inside = v[mask[support]]
    rows, cols = np.nonzero(mask)
    z = -inside[:, 2]
    np.testing.assert_allclose(z, depth[mask], rtol=1e-5)  # float32 vertices
    pixel = np.stack([K[0, 0] * inside[:, 0] / z + K[0, 2], K[1, 2] - K[1, 1] * inside[:, 1] / z], -1)
    np.testing.assert_allclose(pixel, np.stack([cols + 0.5, rows + 0.5], -1), atol=1e-3)


def test_same_mask_moves_by_shape_keys(clean_file, tmp_path):
    scene = clean_file
    cam = add_camera(scene, (0.3, -1.0, 0.4), (1.1, 0.1, 0.2))
    _, mask, _ = _disc((0.0, 0.0, 1.0), (0.0, 0.0, -2.0))
    frames = [
        _disc((0.2, 0.1, 1.0), (0.0, 0.0, -2.0), mask=mask),
        _disc((-0.3, 0.2, 1.0), (0.0, 0.0, -1.7), mask=mask),
        _disc((0.1, -0.4, 1.0), (0.0, 0.0, -2.4), mask=mask),
    ]
    folder = _write_sequence(tmp_path / "seq", frames)
    obj = pbr_import.import_pbr_maps(bpy.context, folder, pbr_import.ImportOptions(normal_space="OBJECT"))
    assert (obj["pdir_geometry"], obj["pdir_frames"], obj["pdir_frame_objects"]) == ("shape_keys", 3, "mov")
    positions = {}
    for f in (1, 3, 2):
        scene.frame_set(f)
        viewport, render, depsgraph = _shown(scene)
        assert viewport == render == ["mov"]
        _assert_relief(obj, cam, depsgraph, mask, frames[f - 1][2])
        positions[f] = np.array([tuple(x.co) for x in obj.evaluated_get(depsgraph).data.vertices])
    assert np.abs(positions[1] - positions[3]).max() > 0.05  # the depth differs, so does the geometry
    # half-way between frames 2 and 3: still frame 2's relief, no blend of the two
    scene.frame_set(2, subframe=0.5)
    _assert_relief(obj, cam, bpy.context.evaluated_depsgraph_get(), mask, frames[1][2])


def test_changing_mask_moves_by_one_object_per_frame(clean_file, tmp_path):
    scene = clean_file
    cam = add_camera(scene)
    frames = [
        _disc((0.2, 0.1, 1.0), (0.05, 0.0, -2.0)),
        _disc((0.0, 0.3, 1.0), (-0.1, 0.05, -1.8), radius=0.3),
        _disc((-0.2, 0.0, 1.0), (0.15, -0.05, -2.2)),
    ]
    assert not np.array_equal(frames[0][1], frames[2][1])
    folder = _write_sequence(tmp_path / "seq", frames)
    obj = pbr_import.import_pbr_maps(bpy.context, folder, pbr_import.ImportOptions(normal_space="OBJECT"))
    names = ["mov", "mov_0002", "mov_0003"]
    assert (obj["pdir_geometry"], obj["pdir_frame_objects"]) == ("objects", ",".join(names))
    material = obj.active_material
    for f in (1, 3, 2):
        scene.frame_set(f)
        viewport, render, depsgraph = _shown(scene)
        assert viewport == render == [names[f - 1]]  # exactly frame f's object, in the viewport and the render
        frame_obj = scene.objects[names[f - 1]]
        assert frame_obj.active_material == material and frame_obj.parent == cam
        _assert_relief(frame_obj, cam, depsgraph, frames[f - 1][1], frames[f - 1][2])
    assert (scene.frame_start, scene.frame_end) == (1, 3)


def test_card_sequence_keeps_one_plane(clean_file, tmp_path):
    frames = [_disc((0.2, 0.1, 1.0), (0.0, 0.0, -2.0)), _disc((0.0, 0.3, 1.0), (0.1, 0.0, -1.8))]
    folder = _write_sequence(tmp_path / "seq", frames, card=True)
    obj = pbr_import.import_pbr_maps(bpy.context, folder)
    assert (obj["pdir_geometry"], obj["pdir_frame_objects"], len(obj.data.vertices)) == ("plane", "mov", 4)
    assert obj.data.shape_keys is None and obj.animation_data is None


@pytest.mark.parametrize("card", [False, True])
def test_frames_of_another_size_are_refused(clean_file, tmp_path, card):
    disc = _disc((0.2, 0.1, 1.0), (0.0, 0.0, -2.0))
    folder = _write_sequence(tmp_path / "seq", [disc] * 2, card=card)
    small = [a[::2, ::2] for a in disc]
    write_pbr_maps(folder, small[0], mask=small[1], depth=None if card else small[2], prefix="mov_0002")
    with pytest.raises(ValueError, match=r"mov_0002_normal.exr: frame 2 is 16 x 12, but frame 1 is 32 x 24") as e:
        pbr_import.import_pbr_maps(bpy.context, folder)
    assert "\n" not in str(e.value)
    assert not [o for o in clean_file.objects if o.type == "MESH"]  # nothing half-built


def test_frame_with_another_camera_is_refused(clean_file, tmp_path):
    folder = _write_sequence(tmp_path / "seq", [_disc((0.2, 0.1, 1.0), (0.0, 0.0, -2.0))] * 2)
    camera = {"intrinsics": (K * [[1.1], [1.1], [1.0]]).tolist(), "width": W, "height": H}
    (folder / "mov_0002_camera.json").write_text(json.dumps(camera))
    with pytest.raises(ValueError, match=r"mov_0002_camera.json: intrinsics differ from frame 1's"):
        pbr_import.import_pbr_maps(bpy.context, folder)
    assert not [o for o in clean_file.objects if o.type == "MESH"]
    # without the capture camera the frames' camera files are not used, so not compared
    obj = pbr_import.import_pbr_maps(
        bpy.context, folder, pbr_import.ImportOptions(normal_space="OBJECT", use_camera_file=False)
    )
    assert obj["pdir_geometry"] == "shape_keys"
