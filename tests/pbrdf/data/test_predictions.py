"""pbrdf.data.predictions: the prediction folder's files, written and read by the same code."""

import json
import re

import numpy as np
import pytest

from pbrdf.data import predictions as pr
from pbrdf.io import exr

K = np.array([[90.5, 0.0, 35.3], [0.0, 90.5, 17.9], [0.0, 0.0, 1.0]])


def _pred(h=12, w=16):
    rng = np.random.default_rng(0)
    n = rng.normal(size=(h, w, 3))
    out = {
        "normal": (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32),
        "albedo": rng.uniform(0, 1, (h, w, 3)).astype(np.float32),
        "roughness": rng.uniform(0, 1, (h, w, 1)).astype(np.float32),
        "metallic": rng.uniform(0, 1, (h, w, 1)).astype(np.float32),
        "mask": np.ones((h, w, 1), np.float32),
    }
    assert set(out) <= set(pr.MAP_NAMES) and list(pr.OUTPUT_CHANNELS) == list(out)[:4]
    return out


def test_camera_record_round_trip(tmp_path):
    camera = pr.CameraRecord.of_maps(K, (12, 16), 0.8)
    paths = pr.write_predictions(tmp_path / "o", "cap", _pred(), camera)
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == sorted([p.name for p in paths] + ["cap_camera.json"])
    back = pr.CameraRecord.read(tmp_path / "o" / "cap_camera.json")
    np.testing.assert_array_equal(back.intrinsics, K)
    assert (back.width, back.height, back.distance_m) == (16, 12, 0.8)
    assert json.loads((tmp_path / "o" / "cap_camera.json").read_text())["distance_m"] == 0.8
    np.testing.assert_array_equal(exr.read_exr(paths[0])["normal.Z"], _pred()["normal"][..., 2])


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"width": 16, "height": 12}, "intrinsics: missing"),
        ({"intrinsics": [[1, 0, 0]], "width": 16, "height": 12}, "intrinsics: must be a finite 3x3 matrix"),
        ({"intrinsics": [[1, 0, "0"]], "width": 16, "height": 12}, "intrinsics: must be a 3x3 list of numbers"),
        ({"intrinsics": K.tolist(), "width": True, "height": 12}, "width: must be a positive integer"),
        ({"intrinsics": K.tolist(), "width": 16, "height": 12, "distance_m": 0}, "distance_m: must be null or"),
        ({"intrinsics": (-K).tolist(), "width": 16, "height": 12}, "intrinsics: focal lengths must be positive"),
    ],
)
def test_camera_record_names_the_file_and_field(tmp_path, doc, match):
    path = tmp_path / "cap_camera.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: {match}"):
        pr.CameraRecord.read(path)
    with pytest.raises(FileNotFoundError, match="camera file not found"):
        pr.CameraRecord.read(tmp_path / "none_camera.json")


def test_sequence_record_round_trip(tmp_path):
    frames = [tmp_path / "a", tmp_path / "b", tmp_path / "c"]
    record = pr.SequenceRecord.of_frames("face", frames, [2.0, 1.0, 1.0])
    path = pr.write_sequence(tmp_path / "o", record)
    assert path.name == "face_sequence.json"
    back = pr.SequenceRecord.read(path)
    assert back == record
    assert back.prefixes == ("face_0001", "face_0002", "face_0003")
    assert json.loads(path.read_text())["frames_per_second"] == 0.75  # 3 frames in 4 s
    # A hand-written file: only the prefixes are required, the name comes from the file name.
    path.write_text('{"frames": [{"prefix": "face_0001"}]}')
    assert pr.SequenceRecord.read(path) == pr.SequenceRecord("face", ("face_0001",), (None,), (None,))


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_pending_maps_are_written_as_if_given_with_the_others(tmp_path):
    # A map computed on another thread while the others are encoded gives the same files, byte for byte, as the
    # map passed with them (its PNG preview uses the mask of the others: the depth's range over the mask).
    from concurrent.futures import ThreadPoolExecutor

    pred = _pred()
    pred["mask"][:3] = 0
    depth = np.linspace(0.5, 0.9, 12 * 16, dtype=np.float32).reshape(12, 16, 1)
    cam = pr.CameraRecord.of_maps(K, (12, 16), 0.7)
    serial = pr.write_predictions(tmp_path / "serial", "x", dict(pred, depth=depth), cam)
    with ThreadPoolExecutor(1) as pool:
        later = pool.submit(lambda: {"depth": depth})
        overlapped = pr.write_predictions(tmp_path / "overlap", "x", pred, cam, pending=later)
    assert [p.name for p in overlapped] == [p.name for p in serial]
    assert _files(tmp_path / "overlap") == _files(tmp_path / "serial")


@pytest.mark.parametrize("result", ["raise", "nan"])
def test_failed_pending_maps_write_nothing(tmp_path, result):
    from concurrent.futures import Future

    later = Future()
    if result == "raise":
        later.set_exception(ValueError("the relief could not be integrated"))
    else:
        later.set_result({"depth": np.full((12, 16, 1), np.nan, np.float32)})
    with pytest.raises(ValueError, match="relief could not|depth map is not a finite"):
        pr.write_predictions(tmp_path / "o", "x", _pred(), pending=later)
    assert not (tmp_path / "o").exists() and not list(tmp_path.iterdir())
