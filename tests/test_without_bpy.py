"""Without the bpy wheel, `pytest -m "not bpy"` still collects every other test and doctest.

The child process hides bpy (and Blender's companion modules) so `import bpy` fails as it does in
an environment installed without the ``bpy`` extra; collection must then report no errors, and
the tests marked ``bpy`` must be the ones deselected.
"""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HIDE_BPY = (
    "import sys; sys.modules.update(dict.fromkeys(['bpy', 'bmesh', 'mathutils', 'bpy_extras']));"
    "import pytest; sys.exit(pytest.main(sys.argv[1:]))"
)


@pytest.mark.slow
def test_collection_without_bpy():
    args = ["--collect-only", "-q", "-p", "no:cacheprovider", "-m", "not bpy"]
    res = subprocess.run([sys.executable, "-c", HIDE_BPY, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-3000:]
    assert "error" not in out.lower().split("collected")[-1] or " 0 errors" in out, out[-3000:]
    tail = out.strip().splitlines()[-1]
    # e.g. "1234/1400 tests collected (166 deselected) in 20s"
    assert "deselected" in tail, tail
    assert "blender_addon/rig_bpy.py" not in out  # a bpy module's doctests are not collected
    assert "pbrdf/polar/stokes.py" in out  # every other package's doctests are
