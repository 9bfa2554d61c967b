"""headless/infer.py: one-line errors, nothing written on failure (the end-to-end run on a capture is tested
with network.infer)."""

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pbrdf.data import capture
from pbrdf.data import sample as psample
from pbrdf.sensor import camera

ROOT = Path(__file__).resolve().parents[2]


def _infer(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "headless/infer.py", *args, "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=300
    )


def _assert_one_error_line(proc: subprocess.CompletedProcess, start: str) -> None:
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [proc.stderr.rstrip("\n")], proc.stderr  # exactly one line
    assert proc.stderr.startswith(f"error: {start}"), proc.stderr


def test_missing_input_is_one_error_line(tmp_path):
    proc = _infer("--input", str(tmp_path / "nope"), "--out", str(tmp_path / "o"))
    _assert_one_error_line(proc, str(tmp_path / "nope"))
    assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """``(checkpoint, sample EXR)``: a toy model and a valid 24 x 32 sample."""
    import torch

    from tests.helpers import make_model

    root = tmp_path_factory.mktemp("infer")
    model = make_model()
    ckpt = root / "model.pt"
    torch.save({"config": model.config.to_dict(), "model": model.state_dict()}, ckpt)
    bad = {k: v.clone().fill_(float("nan")) if v.is_floating_point() else v for k, v in model.state_dict().items()}
    torch.save({"config": model.config.to_dict(), "model": bad}, root / "nan.pt")
    return ckpt, _sample(root / "good", np.random.default_rng(0))


def _sample(root: Path, rng: np.random.Generator, maps_value: float | None = None) -> Path:
    h, w = 24, 32
    mask = np.zeros((h, w), bool)
    mask[4:20, 6:26] = True
    normal = np.zeros((h, w, 3), np.float32)
    normal[mask, 2] = 1.0
    maps = rng.uniform(0.05, 1.0, (h, w, 9)).astype(np.float32)
    maps[..., 6:] -= 0.5
    if maps_value is not None:
        maps[:] = maps_value
    sample = {
        "maps": maps,
        "mask": mask,
        "normal": normal,
        "albedo": np.full((h, w, 3), 0.5, np.float32),
        "roughness": np.full((h, w), 0.5, np.float32),
        "metallic": np.zeros((h, w), np.float32),
        "depth": np.where(mask, 1.0, 0.0).astype(np.float32),
    }
    psample.write_sample(root, 0, sample, {"seed": 0})
    return psample.sample_paths(root, 0).exr


@pytest.mark.parametrize(
    "content",
    [b"", bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8)), pickle.dumps({"model": 1})],
    ids=["empty (EOFError)", "random bytes (UnpicklingError)", "plain pickle (a warning, then UnpicklingError)"],
)
def test_non_torch_checkpoint_is_one_error_line(tmp_path, toy, content):
    bad = tmp_path / "model.pt"
    bad.write_bytes(content)
    proc = _infer("--checkpoint", str(bad), "--input", str(toy[1]), "--out", str(tmp_path / "o"))
    _assert_one_error_line(proc, f"{bad}: not a ")
    assert not (tmp_path / "o").exists()


def test_maps_near_float32_max_write_nothing(tmp_path, toy):
    # Maps of 3e38 used to write _normal.exr/.png and then fail on NaN albedo, leaving a partial result; now the
    # maps are checked first (CP must lie in [-1, 1]) and nothing is written.
    sample = _sample(tmp_path / "big", np.random.default_rng(0), maps_value=3e38)
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(sample), "--out", str(tmp_path / "o"))
    _assert_one_error_line(proc, "maps: the CP maps (R_CP, G_CP, B_CP) must lie in [-1, 1]; got |CP| up to 3e+38")
    assert not (tmp_path / "o").exists()


def test_nan_predictions_write_nothing(tmp_path, toy):
    ckpt, sample = toy
    proc = _infer("--checkpoint", str(ckpt.with_name("nan.pt")), "--input", str(sample), "--out", str(tmp_path / "o"))
    _assert_one_error_line(proc, "the network predicted NaN or Inf ")
    assert not (tmp_path / "o").exists()


def test_dark_capture_is_one_error_line(tmp_path, toy):
    model = camera.CameraModel()
    folder = capture.save_capture(tmp_path / "dark", np.full((4, 32, 32), 16, np.uint16), model)
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(folder), "--out", str(tmp_path / "o"))
    _assert_one_error_line(proc, f"{folder}: nothing usable: every raw value is at or below black_level 16 DN")
    assert not (tmp_path / "o").exists()


def test_good_sample_writes_every_map(tmp_path, toy):
    ckpt, sample = toy
    proc = _infer("--checkpoint", str(ckpt), "--input", str(sample), "--out", str(tmp_path / "o"))
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert len(list((tmp_path / "o").glob("000000_*.exr"))) == 6  # with the relief depth
    proc = _infer("--checkpoint", str(ckpt), "--input", str(sample), "--out", str(tmp_path / "card"), "--card")
    assert proc.returncode == 0 and not list((tmp_path / "card").glob("*_depth.*"))


def test_room_lit_capture_without_dark_frames_is_one_warning_line(tmp_path, toy):
    """The automatic mask swallows a frame whose background is lit (no dark frames): reconstructed, warned once."""
    from tests.helpers import disc_stokes

    model = camera.CameraModel(ambient=(0.001,) * 3)
    raws = camera.simulate_capture(disc_stokes(48, 64, 14.0), model, rng=np.random.default_rng(0))
    folder = capture.save_capture(tmp_path / "lit", raws, model, extra={"distance_m": 0.7})
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(folder), "--out", str(tmp_path / "o"), "--card")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == [proc.stderr.rstrip("\n")], proc.stderr  # exactly one line
    assert proc.stderr.startswith(f"warning: {folder}: the automatic object mask covers 100% of the frame"), proc.stderr
    assert len(list((tmp_path / "o").glob("lit_*.exr"))) == 5


def test_shipped_model_relief_depth_matches_the_example_truth(tmp_path):
    """The relief of examples/capture: its predicted normals integrated, anchored at capture.json's distance_m."""
    from pbrdf.io.exr import read_exr

    proc = _infer("--input", str(ROOT / "examples" / "capture"), "--out", str(tmp_path / "o"))
    assert proc.returncode == 0, proc.stderr
    depth = read_exr(tmp_path / "o" / "capture_depth.exr")["depth.Y"]
    truth = np.load(ROOT / "examples" / "capture_truth.npz")["depth"]
    inside = (depth > 0) & (truth > 0)
    assert np.isfinite(depth).all() and inside.sum() > 0.9 * (depth > 0).sum()
    rel = np.abs(depth[inside] / truth[inside] - 1)
    assert np.median(rel) < 0.03, np.median(rel)  # measured 1.4 % (2026-11-24)
    import json

    cam = json.loads((tmp_path / "o" / "capture_camera.json").read_text())
    meta = json.loads((ROOT / "examples" / "capture" / "capture.json").read_text())
    assert (cam["height"], cam["width"]) == depth.shape and cam["distance_m"] == meta["distance_m"]
    # the depth is the pinhole of these intrinsics: its median matches the anchor
    assert abs(np.median(depth[depth > 0]) - meta["distance_m"]) < 1e-3


def test_sequence_writes_numbered_frames_and_its_speed(tmp_path, toy):
    import json
    import shutil

    seq = tmp_path / "face"
    for frame in ("t000", "t001", "t002"):
        shutil.copytree(ROOT / "examples" / "capture", seq / frame)
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(seq), "--out", str(tmp_path / "o"), "--card")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert "3 frames" in proc.stdout and "frames/s" in proc.stdout
    for i in (1, 2, 3):
        assert len(list((tmp_path / "o").glob(f"face_{i:04d}_*.exr"))) == 5
        assert (tmp_path / "o" / f"face_{i:04d}_camera.json").is_file()
    doc = json.loads((tmp_path / "o" / "face_sequence.json").read_text())
    assert [f["capture"] for f in doc["frames"]] == [str((seq / f).resolve()) for f in ("t000", "t001", "t002")]
    assert doc["frames_per_second"] > 0
    # a stray folder, and --blend (one asset), are refused on one line before anything is written
    (seq / "notes").mkdir()
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(seq), "--out", str(tmp_path / "bad"))
    _assert_one_error_line(proc, f"{seq}: a sequence folder holds only capture folders; notes has no capture.json")
    (seq / "notes").rmdir()
    proc = _infer("--checkpoint", str(toy[0]), "--input", str(seq), "--out", str(tmp_path / "bad"), "--blend")
    _assert_one_error_line(proc, "--blend saves one capture's asset")
    assert not (tmp_path / "bad").exists()


def _maps(folder: Path, name: str, key: str) -> np.ndarray:
    from pbrdf.io.exr import read_exr

    chans = read_exr(folder / f"{name}_{key}.exr")
    return np.stack([chans[c] for c in sorted(chans)], -1)


def _loud(*args: str) -> subprocess.CompletedProcess:
    """headless/infer.py without --quiet (the refinement's lines are printed then)."""
    return subprocess.run([sys.executable, "headless/infer.py", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)  # fmt: skip


def _assert_one_scale_on_the_albedo(base: Path, refined: Path, name: str) -> None:
    """The albedo rescaled by one factor (one object), the other maps the network's."""
    for k in ("normal", "roughness", "metallic", "mask"):
        np.testing.assert_array_equal(_maps(base, name, k), _maps(refined, name, k))
    a, b = _maps(base, name, "albedo"), _maps(refined, name, "albedo")
    sel = (a > 0.02) & (b < 0.999)  # lit, not clipped at 1
    ratio = b[sel] / a[sel]
    assert ratio.max() - ratio.min() < 1e-3 and abs(ratio.mean() - 1.0) > 1e-3, (ratio.min(), ratio.max())


def test_refine_changes_only_the_albedo_and_says_so(tmp_path):
    """The default on examples/capture (calibrated, with distance_m) refines: the albedo is rescaled by one
    factor per object, the other maps are --no-refine's; without --quiet it reports the fit and its time."""
    base, refined = tmp_path / "base", tmp_path / "refined"
    assert _infer("--input", "examples/capture", "--out", str(base), "--card", "--no-refine").returncode == 0
    proc = _loud("--input", "examples/capture", "--out", str(refined), "--card")
    assert proc.returncode == 0, proc.stderr
    assert "warning:" not in proc.stderr, proc.stderr
    line = proc.stdout.splitlines()[0]
    assert line.startswith("capture: refined the albedo scale of 1 object") and line.endswith(" s"), proc.stdout
    _assert_one_scale_on_the_albedo(base, refined, "capture")


def _without_distance(root: Path) -> Path:
    """A copy of examples/capture whose capture.json has no distance_m."""
    import json
    import shutil

    cap = shutil.copytree(ROOT / "examples" / "capture", root / "cap")
    meta = json.loads((cap / "capture.json").read_text())
    del meta["distance_m"]
    (cap / "capture.json").write_text(json.dumps(meta))
    return cap


def test_default_refines_only_where_a_distance_is_known(tmp_path):
    """No distance_m: the default is --no-refine (same maps) and says so on one plain line; --refine forces the
    fit at 0.75 m with a warning; --distance 0.8 turns the default refinement on."""
    cap = _without_distance(tmp_path)
    base = tmp_path / "base"
    assert _infer("--input", str(cap), "--out", str(base), "--card", "--no-refine").returncode == 0
    proc = _loud("--input", str(cap), "--out", str(tmp_path / "auto"), "--card")
    assert proc.returncode == 0 and "warning:" not in proc.stderr, proc.stderr
    assert proc.stdout.splitlines()[0] == "cap: no refinement (no distance_m; --distance M refines the albedo scale)"
    assert len(proc.stdout.splitlines()) == 2 and proc.stdout.splitlines()[1].startswith("wrote 5 maps")
    for k in ("normal", "albedo", "roughness", "metallic", "mask"):
        np.testing.assert_array_equal(_maps(base, "cap", k), _maps(tmp_path / "auto", "cap", k))
    proc = _infer("--input", str(cap), "--out", str(tmp_path / "forced"), "--card", "--refine")
    assert proc.returncode == 0, proc.stderr
    assert "warning: refinement at the default distance 0.75 m (no distance_m given)" in proc.stderr, proc.stderr
    proc = _loud("--input", str(cap), "--out", str(tmp_path / "measured"), "--card", "--distance", "0.8")
    assert proc.returncode == 0 and "warning:" not in proc.stderr, proc.stderr
    assert proc.stdout.startswith("cap: refined the albedo scale of 1 object"), proc.stdout
    _assert_one_scale_on_the_albedo(base, tmp_path / "measured", "cap")


def test_sequence_says_once_what_the_refinement_did(tmp_path, toy):
    """A sequence prints its refinement in one line per outcome, not one per frame; --no-refine prints none."""
    import shutil

    seq = tmp_path / "face"
    for frame in ("t000", "t001", "t002"):
        shutil.copytree(ROOT / "examples" / "capture", seq / frame)
    shutil.rmtree(seq / "t002")
    shutil.move(_without_distance(tmp_path), seq / "t002")
    proc = _loud("--checkpoint", str(toy[0]), "--input", str(seq), "--out", str(tmp_path / "o"), "--card")
    assert proc.returncode == 0 and "warning:" not in proc.stderr, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 3 and lines[2].startswith("wrote 3 frames"), lines
    assert lines[0] == "face: no refinement (no distance_m; --distance M refines the albedo scale) in 1 of 3 frames"
    assert lines[1].startswith("face: refinement on 2 of 3 frames, the albedo refined on "), lines
    proc = _loud("--checkpoint", str(toy[0]), "--input", str(seq), "--out", str(tmp_path / "n"), "--card",
                 "--no-refine")  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.splitlines()[0].startswith("wrote 3 frames"), proc.stdout
