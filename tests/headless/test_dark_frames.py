"""headless/dark_frames.py: a rendered dataset's raw captures get dark frames; one-line errors, status 2.

The run renders one 64-px scene through a jittered rig (room light on, raw bracket kept) and
checks what the dark frames are for: the automatic foreground mask covers the whole frame before
and the object after (the library's own checks are in tests/network/test_pseudo_real.py).
"""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pbrdf.data import capture as pcapture
from pbrdf.data import capture_decode as pdecode
from pbrdf.data import sample as psample

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "headless/dark_frames.py", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


@pytest.mark.parametrize(("make", "reason"), [(lambda p: p, "no raw captures"), (lambda p: p / "nope", "not a folder")])
def test_bad_input_is_one_line_and_status_2(tmp_path, make, reason):
    res = _run("--input", make(tmp_path), "--quiet")
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("error: ") and reason in res.stderr


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """One 64-px scene through a rig jittered at 1.5 (room light on), its raw bracket kept, no dark frames."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("dark") / "ds"
    cfg = GenerateConfig(out=root, count=1, resolution=64, spp=4, seed=11, keep_raw=True, rig_jitter=1.5)
    assert len(generate(cfg, progress=False).written) == 1
    return root


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


@pytest.mark.mitsuba
def test_dark_frames_give_back_the_object(rendered, tmp_path):
    root = shutil.copytree(rendered, tmp_path / "ds")
    paths = psample.sample_paths(root, 0)
    truth = psample.read_sample(paths.sidecar, keys=("mask",))[0]["mask"] > 0
    before = pdecode.decode_capture(pcapture.load_capture(paths.raw)).input_mask
    assert before.mean() > 0.9  # the room light lifts the whole frame above the noise floor

    res = _run("--input", root)  # with the progress bar
    assert res.returncode == 0, res.stderr
    assert res.stdout == f"{root}: dark frames written for 1 captures\n" and "dark frames" in res.stderr
    first = pcapture.load_capture(paths.raw).dark
    assert first is not None
    assert _iou(pdecode.decode_capture(pcapture.load_capture(paths.raw)).input_mask, truth) > 0.85

    again = _run("--input", root, "--quiet")  # resumable: a capture with dark frames is skipped
    assert (again.returncode, again.stdout, again.stderr) == (0, f"{root}: dark frames written for 0 captures\n", "")
    over = _run("--input", root, "--overwrite", "--quiet")
    assert over.returncode == 0 and "for 1 captures" in over.stdout
    np.testing.assert_array_equal(pcapture.load_capture(paths.raw).dark, first)  # a pure function of the sample


@pytest.mark.mitsuba
def test_a_sidecar_without_the_rendered_rig_is_one_line(rendered, tmp_path):
    root = shutil.copytree(rendered, tmp_path / "ds")
    sidecar = psample.sample_paths(root, 0).sidecar
    meta = json.loads(sidecar.read_text())
    del meta["spec"]  # still a complete sample (the EXR's hash is unchanged), but no rig to simulate
    sidecar.write_text(json.dumps(meta))
    res = _run("--input", root, "--quiet")
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr == f"error: {sidecar}: no rendered rig (spec.rig) or sample_seed: 'spec'\n"
