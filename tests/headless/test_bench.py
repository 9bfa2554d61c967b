"""headless/bench.py: the JSON on stdout equals the file, argument checks, the network benchmark end to end."""

import json
import subprocess
import sys
from pathlib import Path

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
        # The one timing rule: one warm-up, then --repeat timed calls, each entry saying what it timed.
        assert entry["warmup_runs"] == 1 and entry["repeats"] == 1 and len(entry["seconds_all"]) == 1
        assert "decode" in entry["what"] and f"grid='{grid}'" in entry["what"]
        # Smooth scene, no noise, no quantisation: only interpolation error of a slowly varying
        # field (s0 is up to about 1) remains.
        assert entry["stokes_max_abs_error_noise_free"] < 2e-3
    assert "median" in result["timing_rule"]
    assert not list(tmp_path.glob("*.tmp*"))


def test_bench_rejects_bad_size():
    proc = _run("headless/bench.py", "decode", "--height", "30")
    assert proc.returncode == 2
    assert "multiples of 4" in proc.stderr


def test_bench_network_toy(tmp_path):
    out = tmp_path / "net.json"
    proc = _run("headless/bench.py", "network", "--configs", "toy", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    toy = json.loads(out.read_text())["configs"]["toy"]
    assert toy["parameters"] > 1000 and toy["train_step_seconds"] > 0 and toy["decoder_pixels_per_second"] > 0
    # Every timed entry follows the one rule and names what it timed.
    for entry in (toy["train_forward"], toy["train_step"], toy["encode"], toy["inference"]["stride_2"]["decode"]):
        assert entry["warmup_runs"] == 1 and entry["repeats"] == 1 and entry["what"]
        assert entry["seconds_median"] == entry["seconds_all"][0]


def test_bench_quick_and_old_capture_flag(tmp_path):
    """--quick runs the toy network only; the old --capture flag still works with one deprecation line."""
    out = tmp_path / "quick.json"
    proc = _run("headless/bench.py", "network", "--quick", "--no-train", "--capture", str(tmp_path), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert list(json.loads(out.read_text())["configs"]) == ["toy"]
    lines = [line for line in proc.stderr.splitlines() if "deprecated" in line]
    assert lines == [
        "bench.py network: deprecated: --capture is now --input (the old form goes away in the next release)"
    ]
