"""The add-on's "Export glTF" button (blender_addon/gltf_export_operator.py) on an imported reconstruction."""

import sys

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy, pytest.mark.usefixtures("clean_file")]
bpy = pytest.importorskip("bpy")

from blender_addon import gltf_export_operator, pbr_import  # noqa: E402
from pbrdf.data.predictions import CameraRecord, write_predictions  # noqa: E402
from tests.gltf_helpers import normal_map_error, read_glb, sphere_prediction, validate  # noqa: E402

H, W = 30, 40
K = np.array([[48.0, 0.0, 20.0], [0.0, 48.0, 15.0], [0.0, 0.0, 1.0]])


@pytest.fixture
def imported(tmp_path, monkeypatch):
    monkeypatch.setenv("PDIR_PYTHON", sys.executable)  # the project's Python runs the export
    pred = sphere_prediction(np.random.default_rng(9), K, H, W, centre=(0.0, 0.0, -0.9), radius=0.2)
    write_predictions(tmp_path / "maps", "ball", pred, CameraRecord.of_maps(K, (H, W), 0.9))
    obj = pbr_import.import_pbr_maps(bpy.context, tmp_path / "maps", name="ball")
    bpy.context.view_layer.objects.active = obj
    return pred, obj


def test_button_writes_the_relief_asset(imported, tmp_path):
    pred, _ = imported
    out = tmp_path / "ball.glb"
    assert bpy.ops.pdir.export_gltf(filepath=str(out)) == {"FINISHED"}
    doc, blob = read_glb(out.read_bytes())
    assert validate(doc, blob) == [] and doc["asset"]["extras"]["mesh"] == "relief"
    covered, p99 = normal_map_error(doc, blob, pred["normal"], pred["mask"][..., 0] > 0)
    assert covered > 0.99 and p99 < 2.0


def test_gone_maps_and_no_selection_are_refused(imported, tmp_path):
    _, obj = imported
    (tmp_path / "maps" / "ball_albedo.exr").unlink()
    with pytest.raises(RuntimeError, match="ball_albedo.exr: the map file 'ball' was imported from is gone"):
        bpy.ops.pdir.export_gltf(filepath=str(tmp_path / "x.glb"))
    assert not (tmp_path / "x.glb").exists()
    bpy.context.view_layer.objects.active = None
    assert not gltf_export_operator.PDIR_OT_export_gltf.poll(bpy.context)
