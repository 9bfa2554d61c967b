"""Tests of network/train_files.py: the truncation of ``log.csv`` and ``val.csv`` on resume.

The files' repair through a whole training run (an emptied log, a stale ``model.pt`` or ``best.pt``) is
tested with :func:`network.train.train` in tests/network/test_train.py.
"""

import csv
import os

import pytest

from network.train_files import truncate_log


@pytest.mark.parametrize(
    ("text", "rows"),
    [
        ("", []),  # emptied
        ("0,1.", []),  # a cut-off row without header
        ("step,a,b\n0,1,x\n1,2,y\n2,3,z\n3,4,w\n", [["0", "1", "x"], ["1", "2", "y"]]),  # rows after the checkpoint
        ("step,a,b\n0,1,x\n1,2", [["0", "1", "x"]]),  # a cut-off last row
        ("0,1,x\n1,2,y\n", [["0", "1", "x"], ["1", "2", "y"]]),  # rows without header
        ("old,header\n1,2,y\njunk\n", [["1", "2", "y"]]),
    ],
)
def test_truncated_log_always_has_its_header(tmp_path, text, rows):
    path = tmp_path / "log.csv"
    path.write_text(text)
    truncate_log(path, 2, ("step", "a", "b"))
    with open(path, newline="") as f:
        assert list(csv.reader(f)) == [["step", "a", "b"], *rows]
    assert os.listdir(tmp_path) == ["log.csv"]  # replaced through a temporary file, none left


def test_truncated_log_is_replaced_atomically(tmp_path):
    """The log is replaced by a rename (a reader, or a kill, never sees it emptied or half-rewritten in place)."""
    path = tmp_path / "log.csv"
    path.write_text("step,a,b\n0,1,x\n5,6,y\n")
    with open(path) as old:
        truncate_log(path, 1, ("step", "a", "b"))
        assert old.read() == "step,a,b\n0,1,x\n5,6,y\n"  # the old file was never touched
    assert path.read_text().splitlines() == ["step,a,b", "0,1,x"]
