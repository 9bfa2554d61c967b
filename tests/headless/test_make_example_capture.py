"""tools/make_example_capture.py --height: the middle rows of the square render, the principal point moved with them."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pbrdf.data.capture import load_capture

ROOT = Path(__file__).resolve().parents[2]


def _make(out: Path, *extra: str) -> None:
    cmd = [sys.executable, "tools/make_example_capture.py", "--out", str(out), "--resolution", "24", "--spp", "4",
           "--seed", "3", "--quiet", *extra]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr


def test_height_keeps_the_middle_rows(tmp_path):
    pytest.importorskip("mitsuba")
    _make(tmp_path / "square")
    _make(tmp_path / "wide", "--height", "16")
    square, wide = load_capture(tmp_path / "square"), load_capture(tmp_path / "wide")
    assert square.raws.shape[1:] == (48, 48) and wide.raws.shape[1:] == (32, 48)
    np.testing.assert_array_equal(wide.raws, square.raws[:, 8:40])  # decoded rows 4..19: raw rows 8..39
    k_square = np.array(json.loads((tmp_path / "square" / "capture.json").read_text())["intrinsics"])
    k_wide = np.array(json.loads((tmp_path / "wide" / "capture.json").read_text())["intrinsics"])
    assert k_wide[1, 2] == pytest.approx(k_square[1, 2] - 8) and k_wide[0, 2] == k_square[0, 2]
    truth_square, truth_wide = np.load(tmp_path / "square_truth.npz"), np.load(tmp_path / "wide_truth.npz")
    np.testing.assert_array_equal(truth_wide["normal"], truth_square["normal"][4:20])
    proc = subprocess.run([sys.executable, "tools/make_example_capture.py", "--resolution", "24", "--height", "13"],
                          cwd=ROOT, capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 2 and "--height must be even" in proc.stderr
