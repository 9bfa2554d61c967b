"""headless/demo.py: the end-to-end demo on a tiny configuration and its report in headless Chromium."""

import html.parser
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _chromium() -> str | None:
    return next((shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome") if shutil.which(b)), None)


class _Refs(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs: list[str] = []

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k in ("src", "href") and v and not v.startswith(("http:", "https:", "#", "data:")):
                self.refs.append(v)


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory):
    pytest.importorskip("mitsuba")
    pytest.importorskip("bpy")
    out = tmp_path_factory.mktemp("demo")
    cmd = [sys.executable, str(ROOT / "headless" / "demo.py"), "--out", str(out), "--scenes", "2",
           "--measured-scenes", "1", "--resolution", "40", "--spp", "4", "--tables", "2", "--relight-frames", "2",
           "--relight-size", "40", "--relight-samples", "2", "--quiet"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=1500)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, proc.stdout


@pytest.mark.slow
@pytest.mark.bpy
@pytest.mark.mitsuba
def test_demo_outputs_and_summary(demo_out):
    out, stdout = demo_out
    assert "report:" in stdout and "normal MAE" in stdout
    for name in ("report.html", "metrics.json", "metrics.md", "timings.json"):
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["scenes"]) == 2
    for who in ("ours", "baseline"):
        assert np.isfinite(metrics["mean"][who]["normal_mae"])
        assert 0.0 <= metrics["mean"][who]["normal_mae"] <= 180.0
    # Every stage ran and was timed.
    assert {"pbrdf expansion", "render (Mitsuba + camera model)", "network inference",
            "Blender import + Cycles relight"} <= set(metrics["timings_s"])  # fmt: skip
    # Predictions, raw captures, relit frames and the Blender file exist.
    assert len(list((out / "predictions").glob("*/*_normal.exr"))) == 2
    assert len(list((out / "data").glob("*/samples/*_raw/capture.json"))) == 2
    assert len(list((out / "relit").glob("*/*.blend"))) == 2 and len(list((out / "relit").glob("*/env_*.png"))) == 2
    frames = sorted((out / "relit").glob("analytic_*/point_*.png"))
    assert len(frames) == 2
    # The point light moves: the two relit frames differ.
    from PIL import Image

    a, b = (np.asarray(Image.open(f), dtype=np.float32) for f in frames)
    assert np.abs(a - b).mean() > 1.0
    assert not list(out.rglob("*.tmp*")), "temporary files left behind"


@pytest.mark.slow
@pytest.mark.bpy
@pytest.mark.mitsuba
def test_report_references_exist_and_opens_in_chromium(demo_out):
    out, _ = demo_out
    page = out / "report.html"
    parser = _Refs()
    parser.feed(page.read_text())
    assert len(parser.refs) >= 6, parser.refs
    for ref in parser.refs:
        assert (out / ref).is_file(), ref
    chromium = _chromium()
    if chromium is None:  # make setup installs it (tools/ensure_chromium.sh)
        pytest.skip("no chromium on PATH")
    proc = subprocess.run(
        [chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--log-level=0",
         "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=120, env={**os.environ, "HOME": str(out)},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "<h1>" in proc.stdout and "Metrics" in proc.stdout
    console = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]
    assert not console, console


def test_chromium_console_check_catches_errors(tmp_path):
    """The console check above is not vacuous: a page with a script error is caught."""
    chromium = _chromium()
    if chromium is None:
        pytest.skip("no chromium on PATH")
    page = tmp_path / "bad.html"
    page.write_text("<html><body><script>undefined_function();</script></body></html>")
    proc = subprocess.run(
        [chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--log-level=0",
         "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=120, env={**os.environ, "HOME": str(tmp_path)},
    )  # fmt: skip
    assert any(":CONSOLE" in line and "undefined_function" in line for line in proc.stderr.splitlines())
