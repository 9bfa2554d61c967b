"""headless/train.py: the --input flag and one-line usage errors.

Training itself and the CLI run on a rendered dataset are tested with network.train.
"""

import subprocess
import sys
from pathlib import Path

from headless import train

ROOT = Path(__file__).resolve().parents[2]


def test_missing_input_is_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "headless/train.py", "--out", str(tmp_path / "x")], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip() == "error: the following arguments are required: --input (see train.py --help)"


def test_missing_dataset_is_one_error_line(tmp_path, capsys):
    code = train.main(["--input", str(tmp_path / "missing"), "--out", str(tmp_path / "x"), "--quiet",
                       "--no-tensorboard"])  # fmt: skip
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "dataset folder not found" in lines[0], lines
