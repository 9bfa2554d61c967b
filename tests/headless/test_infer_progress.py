"""headless/infer.py: stage lines with the elapsed time on stderr unless --quiet, and the auto stride."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from pbrdf.data import sample as psample

ROOT = Path(__file__).resolve().parents[2]


def _toy(root: Path) -> tuple[Path, Path]:
    """A toy checkpoint and a 24 x 32 sample."""
    import torch

    from tests.helpers import make_model

    model = make_model()
    ckpt = root / "model.pt"
    torch.save({"config": model.config.to_dict(), "model": model.state_dict()}, ckpt)
    rng = np.random.default_rng(0)
    mask = np.zeros((24, 32), bool)
    mask[4:20, 6:26] = True
    maps = rng.uniform(0.05, 1.0, (24, 32, 9)).astype(np.float32)
    maps[..., 6:] -= 0.5
    sample = {"maps": maps, "mask": mask, "normal": np.dstack([np.zeros((24, 32, 2)), mask]).astype(np.float32),
              "albedo": np.full((24, 32, 3), 0.5, np.float32), "roughness": np.full((24, 32), 0.5, np.float32),
              "metallic": np.zeros((24, 32), np.float32), "depth": mask.astype(np.float32)}  # fmt: skip
    psample.write_sample(root / "s", 0, sample, {"seed": 0})
    return ckpt, psample.sample_paths(root / "s", 0).exr


def test_stage_lines_show_the_elapsed_time(tmp_path):
    ckpt, exr = _toy(tmp_path)
    cmd = [sys.executable, "headless/infer.py", "--checkpoint", str(ckpt), "--input", str(exr), "--gltf", "--card"]
    proc = subprocess.run([*cmd, "--out", str(tmp_path / "o")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert all(re.fullmatch(r"\[ *\d+\.\d s\] .+", line) for line in lines), lines
    stages = [line.split("] ", 1)[1] for line in lines]
    assert stages[0] == "starting Python and torch" and "writing the maps and the glTF binary" in stages
    assert "predicting the maps (320 pixels, stride 1)" in stages  # a small mask: auto is stride 1
    seconds = [float(line[1:].split(" s]")[0]) for line in lines]
    assert seconds == sorted(seconds)
    quiet = subprocess.run([*cmd, "--out", str(tmp_path / "q"), "--quiet", "--stride", "2"], cwd=ROOT,
                           capture_output=True, text=True, timeout=300)  # fmt: skip
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr


def test_a_sequence_with_mismatched_frames_is_one_line_and_writes_nothing(tmp_path):
    from pbrdf.data import capture
    from pbrdf.sensor import camera

    for name, exposures in (("t000", (0.01, 0.02, 0.1, 0.2)), ("t001", (0.01, 0.02, 0.1, 0.4))):
        raws = np.full((4, 32, 48), 500, np.uint16)
        (tmp_path / "seq").mkdir(exist_ok=True)
        capture.save_capture(tmp_path / "seq" / name, raws, camera.CameraModel(exposures=exposures))
    cmd = [sys.executable, "headless/infer.py", "--input", str(tmp_path / "seq"), "--out", str(tmp_path / "o")]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    assert proc.stderr.splitlines()[-1].startswith(f"error: {tmp_path / 'seq' / 't001'}: exposures_s"), proc.stderr
    assert not (tmp_path / "o").exists()
