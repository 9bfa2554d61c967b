"""Dataset generation end to end: reproducible, sharded, resumable, with clear errors."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")

from blender_addon.core.generate import GenerateConfig, generate  # noqa: E402
from pbrdf.data import dataset  # noqa: E402
from pbrdf.data import sample as psample  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
SMALL = {"resolution": 32, "spp": 4}


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((root / "samples").iterdir()) if p.suffix == ".exr"}


def test_shards_union_equals_full_run_bitwise(tmp_path):
    full = generate(GenerateConfig(out=tmp_path / "full", count=4, seed=7, **SMALL), progress=False)
    assert full.written == [0, 1, 2, 3] and not full.failed
    for k in range(2):
        generate(GenerateConfig(out=tmp_path / "sharded", count=4, seed=7, shard=(k, 2), **SMALL), progress=False)
    assert _files(tmp_path / "full") == _files(tmp_path / "sharded")
    manifest = dataset.read_manifest(tmp_path / "sharded")
    assert manifest["completed"] == [0, 1, 2, 3]
    sample, meta = psample.read_sample(tmp_path / "full", 2)
    assert sample["maps"].shape == (32, 32, 9)
    assert meta["run_seed"] == 7 and "mitsuba" in meta["versions"]
    assert meta["materials"] and meta["objects"][0]["mesh"].startswith("builtin:")


def test_different_seed_gives_different_samples(tmp_path):
    generate(GenerateConfig(out=tmp_path / "a", count=1, seed=1, **SMALL), progress=False)
    generate(GenerateConfig(out=tmp_path / "b", count=1, seed=2, **SMALL), progress=False)
    assert _files(tmp_path / "a") != _files(tmp_path / "b")


def test_resume_after_kill_loses_and_duplicates_nothing(tmp_path):
    out = tmp_path / "killed"
    cmd = [sys.executable, "headless/render.py", "--out", str(out), "--count", "6", "--resolution", "32",
           "--spp", "4", "--seed", "3", "--quiet"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and len(dataset.completed_indices(out) if out.exists() else ()) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = dataset.completed_indices(out)
    assert 2 <= len(done_before) < 6
    # Resuming writes exactly the rest, and the result equals an uninterrupted run bit for bit.
    resumed = subprocess.run([*cmd, "--resume"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"skipped {len(done_before)}" in resumed.stdout
    assert dataset.completed_indices(out) == set(range(6))
    generate(GenerateConfig(out=tmp_path / "clean", count=6, seed=3, **SMALL), progress=False)
    assert _files(out) == _files(tmp_path / "clean")
    assert not [p for p in (out / "samples").iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--count", "0"], "--count 0 must be >= 1"),
        (["--count", "2", "--assets", "/nonexistent"], "does not exist"),
        (["--count", "2", "--shard", "3/2"], "shard"),
        (["--count", "2", "--resolution", "31"], "resolution must be even"),
    ],
)
def test_bad_arguments_fail_with_one_line(tmp_path, args, message):
    proc = subprocess.run(
        [sys.executable, "headless/render.py", "--out", str(tmp_path / "x"), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], proc.stderr
    assert not (tmp_path / "x" / "samples").exists() or not any((tmp_path / "x" / "samples").iterdir())


def test_rerun_without_resume_refuses(tmp_path):
    generate(GenerateConfig(out=tmp_path, count=1, **SMALL), progress=False)
    with pytest.raises(FileExistsError, match="--resume"):
        generate(GenerateConfig(out=tmp_path, count=1, **SMALL), progress=False)


def test_resume_with_other_scene_settings_refuses(tmp_path):
    """A split whose definition changed (textures added) must not add samples to its old folder."""
    generate(GenerateConfig(out=tmp_path, count=2, shard=(0, 2), **SMALL), progress=False)
    with pytest.raises(ValueError, match=r"texture_fraction=0.0 there, 0.5 now.*new folder") as info:
        generate(GenerateConfig(out=tmp_path, count=2, resume=True, texture_fraction=0.5, **SMALL), progress=False)
    assert (
        "\n" not in str(info.value)
        and psample.check_complete(tmp_path, 0)
        and not (tmp_path / "samples" / "000001.exr").exists()
    )
    assert generate(GenerateConfig(out=tmp_path, count=2, resume=True, **SMALL), progress=False).written == [1]


def test_resume_of_a_folder_from_before_textures_refuses_textures(tmp_path):
    """A manifest without ``texture_fraction`` (runs before the field) had none: textures now refuse to mix in."""
    generate(GenerateConfig(out=tmp_path, count=2, shard=(0, 2), **SMALL), progress=False)
    manifest = tmp_path / "manifest.json"
    doc = json.loads(manifest.read_text())
    del doc["config"]["texture_fraction"], doc["config"]["asset_materials"]
    manifest.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"^\S+: its samples were made with other settings \(texture_fraction=0.0 "):
        generate(GenerateConfig(out=tmp_path, count=2, resume=True, texture_fraction=0.5, **SMALL), progress=False)
    assert generate(GenerateConfig(out=tmp_path, count=2, resume=True, **SMALL), progress=False).written == [1]


def test_assets_folder_and_rig_file(tmp_path):
    import trimesh

    from pbrdf.sensor.rig import Rig

    assets_dir = tmp_path / "assets"
    assets_dir.mkdir()
    trimesh.creation.icosphere(2).export(assets_dir / "ball.glb")
    rig_file = tmp_path / "rig.json"
    Rig.from_dict({"camera": {"focal_length": 0.012}}).save(rig_file)
    cfg = GenerateConfig(out=tmp_path / "ds", count=1, assets=assets_dir, rig=rig_file, **SMALL)
    report = generate(cfg, progress=False)
    assert report.written == [0], report.failed
    _, meta = psample.read_sample(tmp_path / "ds", 0)
    assert meta["objects"][0]["mesh"].endswith("ball.glb")
    assert meta["rig"]["camera"]["focal_length"] == 0.012
    assert np.isfinite(meta["intrinsics"]).all() and os.path.exists(tmp_path / "ds" / "manifest.json")


def test_runs_remove_temporaries_of_killed_runs_and_nothing_else(tmp_path):
    """render.py --resume (and any run) clears a killed run's temporary manifest and arrays (of its shard)."""
    out = tmp_path / "d"
    generate(GenerateConfig(out=out, count=2, seed=4, npz=True, **SMALL), progress=False)
    dead = "tmp-999999999-0a1b2c3d"  # a pid above any pid_max: a killed writer
    leftovers = [f".manifest.json.{dead}", f"arrays/.000000.npz.{dead}", f"samples/.000000.exr.{dead}"]
    kept = ["notes.txt", f".notes.txt.{dead}", f"arrays/.000001.npz.{dead}", "arrays/readme.txt"]  # 1: shard 1's
    for name in leftovers + kept:
        (out / name).write_bytes(b"half")
    before = {p.name: p.read_bytes() for p in (out / "samples").iterdir() if ".tmp-" not in p.name}
    report = generate(GenerateConfig(out=out, count=2, seed=4, npz=True, resume=True, shard=(0, 2), **SMALL),
                      progress=False)  # fmt: skip
    assert report.skipped == 1 and not report.written
    assert not [n for n in leftovers if (out / n).exists()]
    assert all((out / n).read_bytes() == b"half" for n in kept)
    assert {p.name: p.read_bytes() for p in (out / "samples").iterdir()} == before
    assert dataset.read_manifest(out)["completed"] == [0, 1]
    # Shard 1 takes its own, and a fresh run of another shard (no --resume) the manifest's too.
    (out / f".manifest.json.{dead}").write_bytes(b"half")
    generate(GenerateConfig(out=out, count=3, seed=4, npz=True, shard=(2, 3), **SMALL), progress=False)
    assert not (out / f".manifest.json.{dead}").exists() and (out / f"arrays/.000001.npz.{dead}").exists()
    generate(GenerateConfig(out=out, count=2, seed=4, npz=True, resume=True, shard=(1, 2), **SMALL), progress=False)
    assert not (out / f"arrays/.000001.npz.{dead}").exists() and (out / "arrays/readme.txt").exists()


def test_multi_object_samples_label_every_object_with_its_own_material(tmp_path, pbrdf_library):
    """Run seed 0 draws three objects (a table, a plastic, a metal): each must show up in the object
    channel, and the ground truth on its pixels must be its own material's Disney parameters."""
    out = tmp_path / "multi"
    cfg = GenerateConfig(out=out, count=1, seed=0, resolution=48, spp=4, objects=(2, 3), pbrdfs=pbrdf_library,
                         table_fraction=0.5, variant="llvm")  # fmt: skip
    report = generate(cfg, progress=False)
    assert report.written == [0], report.failed
    sample, meta = psample.read_sample(out, 0)
    materials = {m["name"]: m for m in meta["spec"]["materials"]}
    objects = meta["spec"]["objects"]
    assert len(objects) == 3 and {m["kind"] for m in materials.values()} == {"measured", "pplastic", "conductor"}
    assert len({o["material"] for o in objects}) == 3
    ids = sample["object"]
    assert set(np.unique(ids).tolist()) == {-1.0, 0.0, 1.0, 2.0}
    for i, obj in enumerate(objects):
        sel = ids == i
        assert sel.sum() >= 10, f"object {i} covers {sel.sum()} pixels"
        mat = materials[obj["material"]]
        np.testing.assert_array_equal(sample["albedo"][sel], np.broadcast_to(np.float32(mat["albedo"]), (sel.sum(), 3)))
        np.testing.assert_array_equal(sample["roughness"][sel], np.float32(mat["roughness"]))
        np.testing.assert_array_equal(sample["metallic"][sel], np.float32(mat["metallic"]))
    assert np.all(sample["albedo"][ids < 0] == 0) and np.all(sample["mask"] <= (ids >= 0))
    assert meta["objects_range"] == [2, 3] and meta["table_fraction"] == 0.5
    manifest = dataset.read_manifest(out)
    assert manifest["config"]["objects"] == [2, 3] and manifest["config"]["table_fraction"] == 0.5
    assert manifest["config"]["variant"] == "llvm" and manifest["variant"] == meta["variant"]


def test_generated_shapes_render(tmp_path):
    """``--shapes generated``: sharp-edged, concave, thin and multi-part shapes render to valid samples.

    Needs ``builtin:<generated shape>?seed=N`` in :func:`blender_addon.core.assets.load_mesh`.
    """
    from blender_addon.core.generated_shapes import GENERATED_SHAPES

    report = generate(GenerateConfig(out=tmp_path, count=3, seed=1, shapes="generated", **SMALL), progress=False)
    assert report.written == [0, 1, 2], report.failed
    for i in range(3):
        sample, meta = psample.read_sample(tmp_path, i)
        assert meta["objects"][0]["mesh"].split("?")[0].removeprefix("builtin:") in GENERATED_SHAPES
        assert sample["mask"].sum() > 20 and np.isfinite(sample["maps"]).all()


def test_default_config_keeps_the_single_object_run():
    cfg = GenerateConfig(out=Path("unused"), count=1)
    assert (cfg.shapes, cfg.objects, cfg.table_fraction, cfg.variant) == ("procedural", (1, 1), None, "auto")
    assert GenerateConfig(out=Path("unused"), count=1, assets=ROOT).shapes == "none"  # asset files alone
    assert GenerateConfig(out=Path("unused"), count=1, objects="2-4").objects == (2, 4)
    assert GenerateConfig(out=Path("unused"), count=1, objects=3).objects == (3, 3)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"objects": "0"}, "objects='0' must be N or MIN-MAX with 1 <= MIN <= MAX"),
        ({"objects": "3-2"}, "must be N or MIN-MAX"),
        ({"objects": "two"}, "must be N or MIN-MAX"),
        ({"objects": (1, 2, 3)}, "must be N or MIN-MAX"),
        ({"table_fraction": 0.5}, "table_fraction=0.5 > 0 needs pbrdfs=DIR"),
        ({"table_fraction": -0.1}, r"table_fraction=-0.1 must be in \[0, 1\]"),
        ({"shapes": "none"}, "shapes='none' leaves nothing to draw: give assets=DIR"),
        ({"shapes": "cubes"}, "shapes='cubes' must be one of"),
        ({"variant": "gpu"}, r"variant='gpu' must be one of \['auto', 'llvm', 'cuda', 'scalar'\]"),
        ({"scene": ROOT / "pyproject.toml", "objects": (2, 2)}, "cannot be combined with objects"),
        ({"texture_fraction": 1.5}, r"texture_fraction=1.5 must be in \[0, 1\]"),
        ({"scene": ROOT / "pyproject.toml", "asset_materials": True}, "cannot take texture_fraction or asset_mat"),
    ],
)
def test_bad_config_fails_with_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message) as info:
        GenerateConfig(out=Path("unused"), count=1, **kwargs)
    assert "\n" not in str(info.value)


def test_variant_reaches_the_renderer(tmp_path):
    report = generate(GenerateConfig(out=tmp_path, count=1, resolution=16, spp=4, variant="scalar"), progress=False)
    assert report.written == [0], report.failed
    _, meta = psample.read_sample(tmp_path, 0)
    assert meta["variant"] == dataset.read_manifest(tmp_path)["variant"] == "scalar_spectral_polarized"


def test_white_pattern_renders_the_same_scene_under_a_white_display(tmp_path):
    """--pattern changes the light, not the scene: the ablation's white twin of a split."""
    rgb, white = tmp_path / "rgb", tmp_path / "white"
    for out, pattern in ((rgb, None), (white, "white")):
        generate(GenerateConfig(out=out, count=1, resolution=32, spp=4, seed=7, pattern=pattern), progress=False)
    a, meta_a = psample.read_sample(rgb, 0, keys=("maps", "mask", "normal"))
    b, meta_b = psample.read_sample(white, 0, keys=("maps", "mask", "normal"))
    assert meta_b["rig"]["display"]["pattern"] == "white" and meta_a["rig"]["display"]["pattern"] == "rgb_halves"
    assert meta_a["spec"]["objects"] == meta_b["spec"]["objects"]
    np.testing.assert_array_equal(a["normal"], b["normal"])
    # Physics: a white display lights every colour from the whole panel, the RGB pattern each colour
    # from half of it (blue: the upper half), so every colour of the object gets brighter.
    m = a["mask"].astype(bool) & b["mask"].astype(bool)
    s0_rgb = a["maps"][m][:, :6].reshape(-1, 2, 3).sum(1)
    s0_white = b["maps"][m][:, :6].reshape(-1, 2, 3).sum(1)
    assert np.all(s0_white.sum(0) > 1.2 * s0_rgb.sum(0))
    with pytest.raises(ValueError, match=r"pattern='checkers' must be one of \['rgb_halves', 'white'\] or an image"):
        generate(GenerateConfig(out=tmp_path / "bad", count=1, resolution=32, spp=4, pattern="checkers"))
    assert not (tmp_path / "bad").exists()
