"""headless/relight.py: predicted maps -> Blender asset, relit frames and a .blend, in its own process."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _blob(h=16, w=24):
    """``(maps, depth)``: predicted maps of an ``h x w`` hemisphere-ish blob (as infer.py predicts) and a relief."""
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
    return pred, (np.where(mask[..., 0] > 0, 1.0 - 0.1 * z, 0.0)[..., None]).astype(np.float32)


@pytest.fixture
def maps(tmp_path):
    """Predicted maps of a 16 x 24 hemisphere-ish blob, as headless/infer.py writes them (no depth: a card)."""
    from pbrdf.data.predictions import write_predictions

    write_predictions(tmp_path / "pred", "blob", _blob()[0])
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


#: Opens a saved .blend in a fresh process and prints what an artist gets, as JSON.
CHECK_BLEND = """
import json, sys
import bpy, mathutils
bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
scene = bpy.context.scene
images = [i for i in bpy.data.images if i.type == "IMAGE"]
loaded = []
for image in images:
    image.reload()
    loaded.append(len(image.pixels[:]) == image.size[0] * image.size[1] * image.channels > 0 and image.has_data)
print(json.dumps({
    "engine": scene.render.engine, "denoise": scene.cycles.use_denoising, "samples": scene.cycles.samples,
    "world": scene.world is not None and len(scene.world.node_tree.nodes) > 0,
    "lights": [o.name for o in scene.objects if o.type == "LIGHT" and not o.hide_render],
    "asset_on_camera": any(o.parent == scene.camera for o in scene.objects if o.type == "MESH"),
    "light_to_asset": [(o.matrix_world.translation - sum((m.matrix_world @ mathutils.Vector(c) for c in m.bound_box),
                        mathutils.Vector()) / 8).length for o in scene.objects if o.type == "LIGHT"
                       for m in scene.objects if m.type == "MESH"],
    "images": sorted(i.name for i in images), "packed": [i.packed_file is not None for i in images], "loaded": loaded,
}))
"""


@pytest.mark.bpy
def test_saved_blend_is_lit_and_self_contained(tmp_path):
    """Even without relit frames: Cycles with denoising, the world, a light, the camera with the asset, packed images.

    The .blend of a relief asset is opened in a fresh process after the maps and the HDR have
    been moved away; the light circles the asset (not the relief's origin, the camera).
    """
    pytest.importorskip("bpy")
    from pbrdf.data.predictions import write_predictions
    from pbrdf.io.exr import write_exr

    pred, depth = _blob()
    maps = tmp_path / "pred"
    write_predictions(maps, "blob", {**pred, "depth": depth})

    hdr = tmp_path / "sky.exr"
    write_exr(hdr, {c: np.full((4, 8), 0.5, np.float32) for c in "RGB"})
    out = tmp_path / "relit"
    proc = _run("--input", maps, "--name", "blob", "--out", out, "--frames", "0", "--hdr", hdr, "--save-blend",
                "--quiet")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    shutil.move(maps, tmp_path / "moved")
    hdr.rename(tmp_path / "moved.exr")
    check = subprocess.run([sys.executable, "-c", CHECK_BLEND, str(out / "blob.blend")], capture_output=True,
                           text=True, timeout=600)  # fmt: skip
    assert check.returncode == 0, check.stderr[-2000:]
    got = json.loads(check.stdout.strip().splitlines()[-1])
    assert (got["engine"], got["denoise"], got["world"], got["asset_on_camera"]) == ("CYCLES", True, True, True)
    assert got["samples"] >= 128 and got["lights"] == ["PDIR Orbit Light"]
    assert got["images"] == ["blob_albedo", "blob_mask", "blob_metallic", "blob_normal", "blob_roughness", "sky.exr"]
    assert all(got["packed"]) and all(got["loaded"])
    # frame 1 of the orbit: radius = height = 0.6 m around the asset's centre
    assert got["light_to_asset"] == [pytest.approx(0.6 * 2**0.5, rel=1e-4)]


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


@pytest.mark.bpy
def test_relight_defaults_are_the_measured_ones_everywhere():
    """relight.py, the relight job and the demo use the samples and denoising docs/measurements/relight.md chose."""
    import re

    pytest.importorskip("bpy")
    from blender_addon import relight_job
    from headless import demo, relight
    from network.demo import DemoConfig

    doc = (ROOT / "docs" / "measurements" / "relight.md").read_text()
    chosen = re.search(r"\*\*Defaults since this entry: (\d+) samples, denoising (on|off)\*\*", doc)
    assert chosen, "docs/measurements/relight.md states no default"
    samples, denoise = int(chosen[1]), chosen[2] == "on"
    args = relight.build_parser().parse_args(["--out", "x"])
    assert (args.samples, args.denoise) == (relight_job.SAMPLES, relight_job.DENOISE) == (samples, denoise)
    assert args.size == relight_job.SIZE
    cli = demo.build_parser().parse_args([])
    cfg = DemoConfig()
    assert (cli.relight_samples, cli.relight_denoise) == (cfg.relight_samples, cfg.relight_denoise)
    assert (cfg.relight_samples, cfg.relight_denoise) == (samples, denoise)
    # the demo's relit frames at its maps' resolution (more pixels would only interpolate the maps)
    assert cli.relight_size == cfg.relight_size == cli.resolution == cfg.resolution
    assert f"{samples} Cycles samples" in (ROOT / "README.md").read_text()
    from blender_addon import relight_operator  # the denoiser's prefilter the frames were measured with

    assert f"with the {relight_operator.DENOISE_PREFILTER} prefilter" in doc


def _pixels(folder: Path) -> dict[str, np.ndarray]:
    from PIL import Image

    return {p.name: np.asarray(Image.open(p)) for p in sorted(folder.glob("*.png"))}


@pytest.mark.bpy
def test_jobs_in_one_process_write_what_separate_runs_write(tmp_path):
    """--jobs (the demo's route): a relief asset with its .blend, then a card without, relit in one process.

    Each asset's frames are those of its own relight.py process, pixel for pixel (the second job
    starts from an empty session, not from the first one's scene), and only the first has a .blend.
    """
    pytest.importorskip("bpy")
    from pbrdf.data.predictions import write_predictions

    pred, depth = _blob()
    write_predictions(tmp_path / "relief", "blob", {**pred, "depth": depth})
    write_predictions(tmp_path / "card", "card", {**pred, "albedo": pred["albedo"] * [1.0, 0.6, 0.3]})
    assets = [("relief", "blob", True), ("card", "card", False)]
    settings = ["--frames", "2", "--size", "16", "--samples", "2", "--denoise", "--quiet"]
    for folder, name, blend in assets:
        proc = _run("--input", tmp_path / folder, "--name", name, "--out", tmp_path / "one" / folder, *settings,
                    *(["--save-blend"] if blend else []))  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-2000:]
    jobs = [{"input": str(tmp_path / f), "name": n, "out": str(tmp_path / "batch" / f), "save_blend": b}
            for f, n, b in assets]  # fmt: skip
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    proc = _run("--jobs", tmp_path / "jobs.json", *settings)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert [line for line in proc.stdout.splitlines() if line.startswith("wrote ")] == [
        f"wrote 4 files to {tmp_path / 'batch' / 'relief'}", f"wrote 3 files to {tmp_path / 'batch' / 'card'}"
    ]  # fmt: skip
    for folder, _, _ in assets:
        one, batch = _pixels(tmp_path / "one" / folder), _pixels(tmp_path / "batch" / folder)
        assert list(one) == list(batch) == ["env_0001.png", "point_0001.png", "point_0002.png"]
        for key in one:
            np.testing.assert_array_equal(batch[key], one[key], err_msg=f"{folder}/{key}")
    assert (tmp_path / "batch" / "relief" / "blob.blend").is_file()
    assert not (tmp_path / "batch" / "card" / "card.blend").exists()
    different = (
        _pixels(tmp_path / "batch" / "relief")["point_0001.png"]
        != _pixels(tmp_path / "batch" / "card")["point_0001.png"]
    )
    assert different.any()  # the two assets do relight differently (the comparison above can fail)


@pytest.mark.parametrize(
    ("content", "says"),
    [("[]", "non-empty JSON list"), ("{", "not JSON"), ('[{"input": "x"}]', "job 0: expected an object"),
     ('[{"input": "x", "out": "y", "save_blend": "yes"}]', "job 0: save_blend must be true or false")],
)  # fmt: skip
def test_bad_jobs_file_is_one_line(tmp_path, content, says):
    pytest.importorskip("bpy")
    (tmp_path / "jobs.json").write_text(content)
    proc = _run("--jobs", tmp_path / "jobs.json", "--frames", "0")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("error: ") and says in proc.stderr, proc.stderr


def test_jobs_excludes_input_and_out(tmp_path):
    proc = _run("--jobs", tmp_path / "jobs.json", "--input", tmp_path)
    assert proc.returncode == 2 and "give neither --input nor --out" in proc.stderr
    proc = _run("--frames", "1")
    assert proc.returncode == 2 and "--input, --out" in proc.stderr


@pytest.fixture(scope="module")
def toy_sample(tmp_path_factory):
    """``(checkpoint, sample EXR, dark sample EXR)``: a toy model, a 24 x 32 sample and one all dark."""
    import torch

    from pbrdf.data import sample as psample
    from tests.helpers import make_model

    root = tmp_path_factory.mktemp("infer_blend")
    model = make_model()
    torch.save({"config": model.config.to_dict(), "model": model.state_dict()}, root / "model.pt")
    h, w = 24, 32
    mask = np.zeros((h, w), bool)
    mask[4:20, 6:26] = True
    maps = np.random.default_rng(0).uniform(0.05, 1.0, (h, w, 9)).astype(np.float32)
    maps[..., 6:] -= 0.5
    paths = []
    for folder, value in (("good", maps), ("dark", np.zeros_like(maps))):
        sample = {"maps": value, "mask": mask, "normal": np.dstack([0 * mask, 0 * mask, mask]).astype(np.float32),
                  "albedo": np.full((h, w, 3), 0.5, np.float32), "roughness": np.full((h, w), 0.5, np.float32),
                  "metallic": np.zeros((h, w), np.float32), "depth": mask.astype(np.float32)}  # fmt: skip
        psample.write_sample(root / folder, 0, sample, {"seed": 0})
        paths.append(psample.sample_paths(root / folder, 0).exr)
    return root / "model.pt", *paths


@pytest.mark.bpy
def test_infer_blend_starts_blender_early_and_saves_the_asset(tmp_path, toy_sample):
    """infer.py --blend (Blender started beside the prediction): the .blend of the written maps; on an error, none.

    --card: the toy model's normals integrate to no relief worth a mesh.
    """
    pytest.importorskip("bpy")
    ckpt, good, dark = toy_sample
    infer = [sys.executable, "headless/infer.py", "--checkpoint", str(ckpt), "--blend", "--card", "--quiet"]
    proc = subprocess.run([*infer, "--input", str(good), "--out", str(tmp_path / "o")], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    blend = tmp_path / "o" / f"{good.stem}.blend"
    check = subprocess.run([sys.executable, "-c", CHECK_BLEND, str(blend)], capture_output=True, text=True,
                           timeout=600)  # fmt: skip
    assert check.returncode == 0, check.stderr[-2000:]
    got = json.loads(check.stdout.strip().splitlines()[-1])
    assert got["asset_on_camera"] and all(got["packed"]) and len(got["images"]) == 5
    proc = subprocess.run([*infer, "--input", str(dark), "--out", str(tmp_path / "d")], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: "), proc.stderr
    assert not (tmp_path / "d").exists()
