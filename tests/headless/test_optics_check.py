"""headless/optics_check.py: the analytic optics/camera round trip end to end, and its default folder."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_demo_round_trip(tmp_path):
    proc = _run("headless/optics_check.py", "--out", str(tmp_path), "--height", "192", "--width", "256", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "R_unpol" in proc.stdout  # the errors print even with --quiet
    for name in ("inputs.png", "nine_maps.png", "metrics.json", "maps.npy", "mask.npy", "capture/capture.json"):
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
    assert not list(tmp_path.rglob("*.tmp*")), "temporary files left behind"


def test_default_out_is_not_the_demo_folder():
    """optics_check and the demo write to different folders by default."""
    from headless import demo, optics_check

    assert optics_check.build_parser().parse_args([]).out == Path("out/optics-check")
    assert demo.build_parser().parse_args([]).out == Path("out/demo")


def test_bad_size_is_a_usage_error():
    proc = _run("headless/optics_check.py", "--height", "30")
    assert proc.returncode == 2 and "multiples of 4" in proc.stderr
