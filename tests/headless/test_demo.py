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

from network.metrics import normal_mae_deg

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


def _truth_and_prediction(out: Path, name: str):
    """Scored region, ground-truth normals and the written normal prediction of demo scene ``name``."""
    from pbrdf.data import sample as psample
    from pbrdf.io import exr

    sub, stem = name.split("_", 1)  # "<analytic|measured>_<index>": the dataset folder and the sample
    sample, _ = psample.read_sample(out / "data" / sub / "samples" / f"{stem}.json")
    region = sample["object"] >= 0 if "object" in sample else sample["mask"].astype(bool)
    channels = exr.read_exr(out / "predictions" / name / f"{name}_normal.exr")
    pred = np.stack([channels[f"normal.{c}"] for c in "XYZ"], axis=-1).astype(np.float64)
    return region, sample["normal"].astype(np.float64), pred


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
    for who in ("ours", "baseline"):
        assert np.isfinite(metrics["mean"][who]["normal_mae"]), who
    # The shipped model against the constant normal facing the camera, per scene, from the files the demo wrote.
    # Rows are looked up by their keys (scene name, method): more rows or methods may be added.
    rows = {r["scene"]: r for r in metrics["scenes"]}
    names = sorted(p.parent.name for p in (out / "predictions").glob("*/*_normal.exr"))
    assert len(names) == 2 and set(names) <= set(rows), (names, list(rows))
    constant = {}
    for name in names:
        region, gt, pred = _truth_and_prediction(out, name)
        have = region & (np.linalg.norm(pred, axis=-1) > 0.5)  # where the written prediction exists
        assert have.sum() > 0.5 * region.sum(), name
        facing = np.broadcast_to(np.array([0.0, 0.0, 1.0]), gt.shape)  # camera space: z toward the camera
        ours = normal_mae_deg(pred, gt, have)
        constant[name] = normal_mae_deg(facing, gt, region)
        # Measured at this size: ours 5-8 deg, the constant 40 deg.
        assert ours < 0.5 * normal_mae_deg(facing, gt, have), (name, ours)
        row = rows[name]["ours"]["normal_mae"]
        assert np.isfinite(row) and row < 0.5 * constant[name], (name, row, constant[name])
        if have.sum() == region.sum():  # the prediction covers what is scored: the reported number is this one
            assert row == pytest.approx(ours, rel=1e-6), name
    assert metrics["mean"]["ours"]["normal_mae"] < 0.5 * min(constant.values())
    # Every stage ran and was timed.
    assert {"pbrdf expansion", "render (Mitsuba + camera model)", "capture path: decode, mask, model, baselines",
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
    # Relief assets with the capture's camera, and the truth relit alike and scored against.
    for name in names:
        for folder in ("predictions", "truth", "constant"):
            assert (out / folder / name / f"{name}_depth.exr").is_file(), (folder, name)
            assert (out / folder / name / f"{name}_camera.json").is_file(), (folder, name)
        truth_frames = sorted(p.name for p in (out / "relit_truth" / name).glob("*.png"))
        assert truth_frames == sorted(p.name for p in (out / "relit" / name).glob("*.png")), name
        assert truth_frames == sorted(p.name for p in (out / "relit_constant" / name).glob("*.png")), name
    relight = {r["scene"]: r for r in metrics["relight"]}
    assert set(relight) == set(names)
    for r in relight.values():
        assert len(r["frames"]) == 3 and r["psnr"] > 12.0 and 0.0 <= r["lpips"] < 0.5, r
        assert np.isfinite(r["constant"]["psnr"]) and 0.0 <= r["constant"]["lpips"] <= 1.0, r
    assert "constant relit PSNR" in (out / "metrics.md").read_text()
    assert "prediction against truth" in (out / "report.html").read_text()


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


@pytest.mark.bpy
@pytest.mark.mitsuba
def test_every_json_the_demo_writes_is_strict(demo_out):
    """Metrics, timings, manifests, sidecars, capture files and pBRDF tables: no NaN or Infinity anywhere."""
    from pbrdf.io.strict_json import loads_strict

    out, _ = demo_out if isinstance(demo_out, tuple) else (demo_out, None)
    files = sorted(Path(out).rglob("*.json"))
    kinds = {p.name if p.name in ("metrics.json", "timings.json", "manifest.json", "capture.json") else p.suffix
             for p in files}  # fmt: skip
    assert {"metrics.json", "timings.json", "manifest.json", "capture.json"} <= kinds
    for path in files:
        loads_strict(path.read_text())  # raises on NaN / Infinity
    summary = loads_strict((Path(out) / "metrics.json").read_text())
    assert set(summary["methods"]) == {"ours", "baseline", "constant", "object_mean"}
    ours = summary["methods"]["ours"]["normal_mae"]
    assert ours["ci"][0] <= ours["mean"] <= ours["ci"][1]
    assert 0.5 <= summary["mask_iou"]["mean"] <= 1.0
