"""headless/mesh_corpus.py: a corpus folder indexed into its index.json; one-line errors, status 2."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "headless/mesh_corpus.py", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def test_a_folder_is_indexed_and_the_refusals_named(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    root = tmp_path / "corpus"
    root.mkdir()
    trimesh.creation.icosphere(subdivisions=2).export(root / "blob.off")  # 320 faces: usable
    trimesh.creation.box().export(root / "box.off")  # 12 faces: too few
    res = _run("--input", root)
    assert res.returncode == 0, res.stderr
    assert res.stdout == f"{root}: 1 usable meshes\n"
    assert "box.off left out" in res.stderr
    assert json.loads((root / "index.json").read_text())["files"] == ["blob.off"]
    quiet = _run("--input", root, "--quiet")  # the cached index answers
    assert (quiet.returncode, quiet.stdout, quiet.stderr) == (0, f"{root}: 1 usable meshes\n", "")


@pytest.mark.parametrize("make", [lambda p: p / "missing", lambda p: p])
def test_a_missing_or_empty_corpus_is_one_line_and_status_2(tmp_path, make):
    res = _run("--input", make(tmp_path), "--quiet")
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("error: ")
