"""The headless entry points run end to end on tiny inputs and report sensible numbers."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_bench_decode_json(tmp_path):
    out = tmp_path / "bench.json"
    proc = _run("headless/bench.py", "decode", "--height", "64", "--width", "96", "--repeat", "1", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result == json.loads(proc.stdout)
    for grid, shape in (("half", [32, 48, 9]), ("full", [64, 96, 9])):
        entry = result[f"ours_{grid}"]
        assert entry["output_shape"] == shape
        assert entry["seconds_median"] > 0
        # Smooth scene, no noise, no quantisation: only interpolation error of a slowly varying
        # field (s0 is up to about 1) remains.
        assert entry["stokes_max_abs_error_noise_free"] < 2e-3


def test_bench_rejects_bad_size():
    proc = _run("headless/bench.py", "decode", "--height", "30")
    assert proc.returncode == 2
    assert "multiples of 4" in proc.stderr


def test_demo_round_trip(tmp_path):
    proc = _run("headless/optics_check.py", "--out", str(tmp_path), "--height", "192", "--width", "256")
    assert proc.returncode == 0, proc.stderr
    for name in ("inputs.png", "nine_maps.png", "metrics.json", "maps.npy", "mask.npy"):
        assert (tmp_path / name).is_file(), name
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    maps = np.load(tmp_path / "maps.npy")
    assert maps.shape == (96, 128, 9) and np.all(np.isfinite(maps))
    # The decoded mask must agree with where the analytic truth has light.
    assert metrics["mask_iou_vs_lit_truth"] > 0.9
    # Unpolarized and LP maps come back within a fraction of their magnitude. What remains is
    # noise, 12-bit steps and demosaicing across the sharp pattern edges mirrored by the spheres
    # (measured at this size: 6-12 % for unpol, 18-22 % for LP). A sign or colour mix-up would
    # give errors of the order of the maps themselves.
    for name in ("R_unpol", "G_unpol", "B_unpol"):
        m = metrics["maps"][name]
        assert m["mae"] < 0.15 * m["truth_mean"], (name, m)
    for name in ("R_LP", "G_LP", "B_LP"):
        m = metrics["maps"][name]
        assert m["mae"] < 0.3 * m["truth_mean"], (name, m)
    assert not list(tmp_path.glob("*.tmp*")), "temporary files left behind"


@pytest.mark.parametrize("script", ["headless/bench.py", "headless/optics_check.py", "headless/demo.py"])
def test_help(script):
    proc = _run(script, "--help")
    assert proc.returncode == 0
    assert "usage" in proc.stdout.lower()


def test_bench_render_default_beats_naive(tmp_path):
    out = tmp_path / "render.json"
    proc = _run(
        "headless/bench.py", "render", "--resolution", "32", "--ref-spp", "128", "--spp", "4", "16", "--out", str(out)
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    default = next(v for k, v in result.items() if k.startswith("default"))
    naive = next(v for k, v in result.items() if k.startswith("naive"))
    # Error falls with samples, and the default configuration is far more accurate per spp
    # (next-event estimation through the polarizer sheet, stratified samples).
    assert default["points"][1]["rel_rmse_unpol_lp"] < default["points"][0]["rel_rmse_unpol_lp"]
    for d, n in zip(default["points"], naive["points"], strict=True):
        assert d["rel_rmse_unpol_lp"] < 0.5 * n["rel_rmse_unpol_lp"]
    assert result["speedup_default_over_naive_at_2pct"] > 5


def test_bench_network_toy(tmp_path):
    out = tmp_path / "net.json"
    proc = _run("headless/bench.py", "network", "--configs", "toy", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    toy = json.loads(out.read_text())["configs"]["toy"]
    assert toy["parameters"] > 1000 and toy["train_step_seconds"] > 0 and toy["decoder_pixels_per_second"] > 0
