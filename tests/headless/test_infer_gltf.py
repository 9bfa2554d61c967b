"""headless/infer.py --gltf: the .glb beside the maps holds them (8-bit); its normal map gives the normals back."""

from pathlib import Path

import numpy as np

from pbrdf.io.exr import read_exr
from pbrdf.sensor.projection import camera_to_pixel
from tests.gltf_helpers import attributes, image, normal_map_error, read_glb, validate
from tests.headless.test_infer import _assert_one_error_line, _infer, toy  # noqa: F401 (toy: a toy model, a sample)

ROOT = Path(__file__).resolve().parents[2]


def test_example_capture_asset_holds_the_written_maps(tmp_path):
    out = tmp_path / "o"
    proc = _infer("--input", str(ROOT / "examples" / "capture"), "--out", str(out), "--gltf")
    assert proc.returncode == 0, proc.stderr
    assert "capture.glb" in proc.stdout
    doc, blob = read_glb((out / "capture.glb").read_bytes())
    assert validate(doc, blob) == [] and doc["asset"]["extras"]["mesh"] == "relief"
    y0, x0, y1, x1 = doc["asset"]["extras"]["texture_box_rows_cols"]
    maps = {k: read_exr(out / f"capture_{k}.exr") for k in ("normal", "roughness", "mask", "depth")}
    inside = maps["mask"]["mask.Y"][y0:y1, x0:x1] > 0
    normal = np.stack([maps["normal"][f"normal.{c}"] for c in "XYZ"], -1)
    covered, p99 = normal_map_error(doc, blob, normal, maps["mask"]["mask.Y"] > 0)
    assert covered > 0.99 and p99 < 2.0, p99
    mr = image(doc, blob, 1)[..., 1] / 255.0
    assert np.abs(mr[inside] - maps["roughness"]["roughness.Y"][y0:y1, x0:x1][inside]).max() <= 0.5 / 255 + 1e-6
    # the mesh lies on the written depth map, on the pixels of the written camera
    cam = doc["cameras"][0]["extras"]
    attrs, _ = attributes(doc, blob)
    pix, depth = camera_to_pixel(attrs["POSITION"], cam["intrinsics"])
    col, row = np.floor(pix).astype(int).T
    on_mask = maps["mask"]["mask.Y"][row, col] > 0
    np.testing.assert_allclose(depth[on_mask], maps["depth"]["depth.Y"][row, col][on_mask], rtol=1e-5)
    assert cam["capture_size"] == [maps["mask"]["mask.Y"].shape[1], maps["mask"]["mask.Y"].shape[0]]


def test_card_asset_and_a_relief_without_triangles(tmp_path, toy):  # noqa: F811
    ckpt, sample = toy
    proc = _infer("--checkpoint", str(ckpt), "--input", str(sample), "--out", str(tmp_path / "c"), "--gltf", "--card")
    assert proc.returncode == 0, proc.stderr
    doc, blob = read_glb((tmp_path / "c" / "000000.glb").read_bytes())
    attrs, faces = attributes(doc, blob)
    assert len(faces) == 2 and np.allclose(attrs["POSITION"][:, 2], -0.75)  # a sample has no distance_m: 0.75 m
    assert validate(doc, blob) == []
    # the toy model's random normals integrate to a relief whose every triangle crosses a > 5 % step:
    # one error line, and neither the maps nor the asset are written
    proc = _infer("--checkpoint", str(ckpt), "--input", str(sample), "--out", str(tmp_path / "r"), "--gltf")
    _assert_one_error_line(proc, "pred: depth: gives no triangle inside the mask")
    assert not (tmp_path / "r").exists()


def test_sequence_writes_one_asset_per_frame(tmp_path, toy):  # noqa: F811
    import shutil

    seq = tmp_path / "face"
    for frame in ("t000", "t001"):
        shutil.copytree(ROOT / "examples" / "capture", seq / frame)
    out = tmp_path / "o"
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(seq), "--out", str(out), "--card", "--gltf")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert sorted(p.name for p in out.glob("*.glb")) == ["face_0001.glb", "face_0002.glb"]
    for i in (1, 2):
        doc, blob = read_glb((out / f"face_{i:04d}.glb").read_bytes())
        assert validate(doc, blob) == [] and doc["nodes"][0]["name"] == f"face_{i:04d}"
