"""headless/relight.py: predicted maps -> Blender asset, relit frames and a .blend, in its own process."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def maps(tmp_path):
    """Predicted maps of a 16 x 24 hemisphere-ish blob, as headless/infer.py writes them."""
    from network.infer import write_predictions

    h, w = 16, 24
    yy, xx = np.mgrid[0:h, 0:w]
    u, v = (xx - w / 2 + 0.5) / (w / 2), (yy - h / 2 + 0.5) / (h / 2)
    mask = (u**2 + v**2 < 0.8).astype(np.float32)[..., None]
    z = np.sqrt(np.clip(1 - u**2 - v**2, 0.05, 1))
    normal = np.stack([u, -v, z], -1) / np.sqrt(u**2 + v**2 + z**2)[..., None]
    pred = {
        "normal": (normal * mask).astype(np.float32),
        "albedo": np.full((h, w, 3), 0.5, np.float32) * mask,
        "roughness": np.full((h, w, 1), 0.4, np.float32) * mask,
        "metallic": np.zeros((h, w, 1), np.float32),
        "mask": mask,
    }
    write_predictions(tmp_path / "pred", "blob", pred)
    return tmp_path / "pred"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "headless/relight.py", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)  # fmt: skip


@pytest.mark.bpy
def test_relight_writes_frames_and_blend(maps, tmp_path):
    pytest.importorskip("bpy")
    out = tmp_path / "relit"
    proc = _run("--input", maps, "--name", "blob", "--out", out, "--frames", "2", "--size", "16", "--samples", "1",
                "--save-blend", "--quiet")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert len(list(out.glob("point_*.png"))) == 2 and len(list(out.glob("env_*.png"))) == 1
    assert (out / "blob.blend").is_file()
    assert not list(out.glob("*.tmp*")) and not list(out.glob(".*"))
    assert ".tmp" not in proc.stdout + proc.stderr  # the log names the final files only
    assert "deprecated" not in proc.stderr


@pytest.mark.bpy
def test_old_maps_flag_still_works(maps, tmp_path):
    pytest.importorskip("bpy")
    proc = _run("--maps", maps, "--name", "blob", "--out", tmp_path / "o", "--frames", "0", "--save-blend")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "o" / "blob.blend").is_file()
    assert [line for line in proc.stderr.splitlines() if "deprecated" in line] == [
        "relight.py: deprecated: --maps is now --input (the old form goes away in the next release)"
    ]


@pytest.mark.bpy
def test_missing_maps_are_one_error_line(tmp_path):
    pytest.importorskip("bpy")
    proc = _run("--input", tmp_path, "--name", "nothing", "--out", tmp_path / "o", "--frames", "0")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("error:") and "no nothing_*.exr" in proc.stderr


def test_bad_sizes_are_usage_errors(tmp_path):
    proc = _run("--input", tmp_path, "--out", tmp_path / "o", "--size", "4")
    assert proc.returncode == 2 and "--size >= 8" in proc.stderr


@pytest.mark.bpy
def test_refuses_blender_older_than_4_2(tmp_path, monkeypatch, capsys):
    """The bpy wheel's route with the Blender version faked (bpy.app.version is read-only): one line, status 2."""
    pytest.importorskip("bpy")
    from blender_addon import compat
    from headless import relight

    monkeypatch.setattr(compat, "running_blender", lambda: (3, 4, 1))
    assert relight.main(["--input", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.splitlines() == ["error: relight.py needs Blender 4.2 or later, this is 3.4.1"]
    assert not (tmp_path / "o").exists()
