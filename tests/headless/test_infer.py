"""headless/infer.py: one-line errors (the end-to-end run on a capture is tested with network.infer)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_missing_input_is_one_error_line(tmp_path):
    proc = subprocess.run(
        [sys.executable, "headless/infer.py", "--input", str(tmp_path / "nope"), "--out", str(tmp_path / "o"),
         "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), proc.stderr
    assert not (tmp_path / "o").exists()
