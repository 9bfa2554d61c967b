"""headless/_overlap.py: the model loads while a capture decodes, the relief integrates while the maps are written.

The overlapped route must give what the serial one did: the decoded input of ``load_input``, and a depth map that
is the integral of the normals written beside it (recomputed here from the files).
"""

import threading
from pathlib import Path

import numpy as np
import pytest

from headless import _overlap
from headless.infer import main
from pbrdf.data.predictions import CameraRecord
from pbrdf.io.exr import read_exr

ROOT = Path(__file__).resolve().parents[2]
CAPTURE = ROOT / "examples" / "capture"


def test_decode_while_loading_gives_load_inputs_input_and_overlaps(monkeypatch):
    from network.infer import load_input

    decoding = threading.Event()
    decode = _overlap._decode

    def signalling_decode(*args):
        decoding.set()
        return decode(*args)

    def load():  # finishes only once the capture is being decoded: a serial route would time out here
        assert threading.current_thread() is not threading.main_thread()
        assert decoding.wait(timeout=30)
        return "model"

    monkeypatch.setattr(_overlap, "_decode", signalling_decode)
    loaded, inp = _overlap.decode_while_loading(CAPTURE, None, load)
    want = load_input(CAPTURE, require_object=True)
    assert loaded == "model"
    for field in ("maps", "mask", "intrinsics"):
        np.testing.assert_array_equal(getattr(inp, field), getattr(want, field))
    assert (inp.radiance, inp.distance_m, inp.rig) == (want.radiance, want.distance_m, want.rig)


def test_decode_while_loading_reports_the_checkpoint_first(tmp_path):
    # Both bad: the serial route read the checkpoint first, so its error is the one reported.
    (tmp_path / "capture.json").write_text("{}")

    def load():
        raise ValueError("model.pt: not a readable model checkpoint")

    with pytest.raises(ValueError, match="model.pt"):
        _overlap.decode_while_loading(tmp_path, None, load)
    with pytest.raises(ValueError, match="capture.json"):
        _overlap.decode_while_loading(tmp_path, None, lambda: "model")
    assert _overlap.decode_while_loading(tmp_path / "x.exr", None, lambda: "model") == ("model", None)


def test_overlapped_relief_is_the_integral_of_the_written_normals(tmp_path):
    """The depth integrated on its own thread while the maps were written is the one of the normals written."""
    from network.infer import relief_depth

    assert main(["--input", str(CAPTURE), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    maps = {k: read_exr(tmp_path / "o" / f"capture_{k}.exr") for k in ("normal", "mask", "depth")}
    normal = np.stack([maps["normal"][f"normal.{c}"] for c in "XYZ"], axis=-1)
    mask = maps["mask"]["mask.Y"][..., None]
    cam = CameraRecord.read(tmp_path / "o" / "capture_camera.json")
    want = relief_depth({"normal": normal, "mask": mask}, cam.intrinsics, cam.distance_m)[..., 0]
    assert (mask[..., 0] > 0).sum() > 1000
    np.testing.assert_allclose(maps["depth"]["depth.Y"], want, rtol=1e-6, atol=0)
