"""headless/export_gltf.py: a prediction folder's maps as the glTF asset, one-line errors, nothing half-written."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from pbrdf.data.predictions import CameraRecord, write_predictions
from tests.gltf_helpers import attributes, normal_map_error, read_glb, sphere_prediction, validate

ROOT = Path(__file__).resolve().parents[2]
H, W = 36, 48
K = np.array([[56.0, 0.0, 24.0], [0.0, 56.0, 18.0], [0.0, 0.0, 1.0]])


def _export(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "headless/export_gltf.py", *args, "--quiet"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)  # fmt: skip


def test_prediction_folder_to_asset(tmp_path):
    pred = sphere_prediction(np.random.default_rng(7), K, H, W)
    write_predictions(tmp_path / "pred", "ball", pred, CameraRecord.of_maps(K, (H, W), 0.9))
    proc = _export("--input", str(tmp_path / "pred"), "--out", str(tmp_path / "ball.glb"))
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert proc.stdout.startswith(f"wrote {tmp_path / 'ball.glb'} (relief")
    doc, blob = read_glb((tmp_path / "ball.glb").read_bytes())
    assert validate(doc, blob) == []
    covered, p99 = normal_map_error(doc, blob, pred["normal"], pred["mask"][..., 0] > 0)
    assert covered > 0.99 and p99 < 2.0
    # --card: the quad at the camera file's distance
    proc = _export("--input", str(tmp_path / "pred"), "--out", str(tmp_path / "card.glb"), "--card")
    attrs, faces = attributes(*read_glb((tmp_path / "card.glb").read_bytes()))
    assert proc.returncode == 0 and len(faces) == 2 and np.allclose(attrs["POSITION"][:, 2], -0.9)


def test_missing_camera_file_is_one_line_and_writes_nothing(tmp_path):
    pred = sphere_prediction(np.random.default_rng(8), K, H, W)
    write_predictions(tmp_path / "pred", "ball", pred)  # no camera
    proc = _export("--input", str(tmp_path / "pred"), "--out", str(tmp_path / "out" / "ball.glb"))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"error: {tmp_path / 'pred'}: no <name>_camera.json beside the maps")
    assert not (tmp_path / "out").exists()


def test_unwritable_out_and_empty_mask_are_one_line_and_write_nothing(tmp_path):
    pred = sphere_prediction(np.random.default_rng(9), K, H, W)
    write_predictions(tmp_path / "pred", "ball", pred, CameraRecord.of_maps(K, (H, W), 0.9))
    (tmp_path / "a_file").write_text("x")
    before = sorted(tmp_path.rglob("*"))
    proc = _export("--input", str(tmp_path / "pred"), "--out", str(tmp_path / "a_file" / "ball.glb"))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.endswith(f"cannot write the glTF file: {tmp_path / 'a_file'} is a file, not a folder\n")
    assert sorted(tmp_path.rglob("*")) == before
    empty = {**pred, "mask": np.zeros_like(pred["mask"])}
    write_predictions(tmp_path / "empty", "ball", empty, CameraRecord.of_maps(K, (H, W), 0.9))
    proc = _export("--input", str(tmp_path / "empty"), "--out", str(tmp_path / "out" / "ball.glb"))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "mask" in proc.stderr and "empty" in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists()
