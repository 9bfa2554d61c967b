"""headless/render.py: argument handling, one-line errors, and the Blender route.

``--via-blender`` lays every scene out in Blender (bpy wheel) and exports it back to a spec
before rendering; for the same seeds the sample files must equal the bpy-free route's: same
maps (float tolerance), same ground truth, same sidecar fields except timings (and the EXR's
byte-level fingerprint, which follows from the maps).
"""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from headless.render import script_args

ROOT = Path(__file__).resolve().parents[2]

SMALL = ["--resolution", "32", "--spp", "4", "--quiet"]
GROUND_TRUTH = ("mask", "normal", "albedo", "roughness", "metallic", "depth")


def test_script_args_after_double_dash():
    assert script_args(["blender", "-b", "-P", "headless/render.py", "--", "--out", "x"]) == ["--out", "x"]
    assert script_args(["headless/render.py", "--out", "x", "--count", "2"]) == ["--out", "x", "--count", "2"]
    assert script_args(["headless/render.py", "--", "--out", "x"]) == ["--out", "x"]


def _sidecar(path: Path) -> dict:
    meta = json.loads(path.read_text())
    meta.pop("seconds")  # wall times
    for key in ("sha256", "exr_bytes"):  # fingerprints of the EXR bytes, compared through the arrays
        meta.pop(key, None)
    return meta


def _assert_same_dataset(a: Path, b: Path, indices) -> None:
    from pbrdf.data import sample as psample

    for i in indices:
        sa, _ = psample.read_sample(a, i)
        sb, _ = psample.read_sample(b, i)
        assert sa.keys() == sb.keys()
        np.testing.assert_allclose(sb["maps"], sa["maps"], atol=1e-5, err_msg=f"sample {i}")
        for key in GROUND_TRUTH:
            np.testing.assert_array_equal(sb[key], sa[key], err_msg=f"sample {i} {key}")
        assert sa["mask"].any()
        ja, jb = (_sidecar(d / "samples" / f"{i:06d}.json") for d in (a, b))
        assert ja == jb


def _run(*args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr
    return proc


@pytest.mark.bpy
@pytest.mark.mitsuba
def test_via_blender_equals_bpy_free_route(tmp_path):
    pytest.importorskip("bpy")
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    _run("headless/render.py", "--via-blender", "--out", str(tmp_path / "blender"), "--count", "2", "--seed", "5",
         *SMALL)  # fmt: skip
    report = generate(GenerateConfig(out=tmp_path / "plain", count=2, seed=5, resolution=32, spp=4), progress=False)
    assert report.written == [0, 1]
    _assert_same_dataset(tmp_path / "plain", tmp_path / "blender", [0, 1])
    manifest = json.loads((tmp_path / "blender" / "manifest.json").read_text())
    assert manifest["spec_hook"] == "blender_addon.build_spec.roundtrip_spec"


@pytest.mark.bpy
@pytest.mark.mitsuba
def test_scene_file_via_blender_with_file_mesh_and_npz(tmp_path):
    """--scene renders a given spec (an asset file mesh here); --npz writes the numpy copy the add-on reads."""
    pytest.importorskip("bpy")
    pytest.importorskip("mitsuba")
    import trimesh

    from blender_addon.core import scenegen
    from blender_addon.core.generate import GenerateConfig, generate
    from pbrdf.sensor.rig import Rig

    mesh = tmp_path / "ball.glb"
    trimesh.creation.icosphere(2).export(mesh)
    spec = scenegen.random_scene(Rig(), 21, asset_files=[mesh])
    spec.save(tmp_path / "scene.json")
    args = ["--scene", str(tmp_path / "scene.json"), "--seed", "3", "--npz", "--keep-stokes", *SMALL]
    _run("headless/render.py", "--via-blender", "--out", str(tmp_path / "blender"), *args)
    cfg = GenerateConfig(out=tmp_path / "plain", count=1, seed=3, resolution=32, spp=4, scene=tmp_path / "scene.json",
                         keep_stokes=True)  # fmt: skip
    assert generate(cfg, progress=False).written == [0]
    _assert_same_dataset(tmp_path / "plain", tmp_path / "blender", [0])
    from pbrdf.data import sample as psample

    sample, _ = psample.read_sample(tmp_path / "blender", 0)
    with np.load(tmp_path / "blender" / "arrays" / "000000.npz") as npz:
        np.testing.assert_array_equal(npz["maps"], sample["maps"])
        np.testing.assert_array_equal(npz["stokes"], sample["stokes"])
        assert list(npz["map_names"])[:2] == ["R_unpol", "G_unpol"]
        assert json.loads(str(npz["metadata"]))["spec"]["objects"][0]["mesh"] == str(mesh)


def test_scene_flag_errors_are_one_line(tmp_path):
    from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec

    far = np.diag([0.2, 0.2, 0.2, 1.0])
    far[:3, 3] = (3.0, 0.0, -0.5)  # far right of the view
    objects, materials = (ObjectSpec("o", "builtin:sphere", far, "m"),), (MaterialSpec.diffuse("m", (0.5,) * 3),)
    SceneSpec(objects=objects, materials=materials).save(tmp_path / "out_of_view.json")
    for args, message in (
        (["--out", str(tmp_path / "x")], "--count is required"),
        (["--out", str(tmp_path / "x"), "--scene", str(tmp_path / "none.json")], "does not exist"),
        (["--out", str(tmp_path / "x"), "--scene", str(tmp_path / "out_of_view.json")], "leaves the camera view"),
    ):
        proc = subprocess.run([sys.executable, "headless/render.py", *args], cwd=ROOT, capture_output=True, text=True,
                              timeout=120)  # fmt: skip
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:") and message in lines[0]


def _blender_version(binary: str) -> tuple[int, ...]:
    """The version of a Blender binary from the first line of ``blender --version`` ("Blender 3.4.1")."""
    proc = subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=120)
    first = proc.stdout.strip().splitlines()[0] if proc.stdout.strip() else ""
    match = re.match(r"Blender (\d+)\.(\d+)(?:\.(\d+))?", first)
    assert match, f"`{binary} --version` printed {first!r}"
    return tuple(int(v or 0) for v in match.groups())


@pytest.mark.skipif(shutil.which("blender") is None, reason="no `blender` binary on PATH")
def test_blender_binary_route(tmp_path):
    """`blender -b -P headless/render.py`: one-line refusal before 4.2 (Debian's 3.4), else the bpy-free files."""
    from blender_addon.compat import MIN_BLENDER, version_text

    binary = shutil.which("blender")
    version = _blender_version(binary)
    cmd = [binary, "-b", "--factory-startup", "-P", "headless/render.py", "--", "--out", str(tmp_path / "bl"),
           "--count", "1", "--seed", "2", *SMALL]  # fmt: skip
    if version < MIN_BLENDER:
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
        assert proc.stderr.strip().splitlines() == [
            f"error: render.py needs Blender 4.2 or later, this is {version_text(version)}"
        ]
        assert not (tmp_path / "bl").exists()
        return
    pytest.importorskip("mitsuba")  # the bpy-free reference render (Blender's own Python needs it too)
    from blender_addon.core.generate import GenerateConfig, generate

    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    generate(GenerateConfig(out=tmp_path / "plain", count=1, seed=2, resolution=32, spp=4), progress=False)
    _assert_same_dataset(tmp_path / "plain", tmp_path / "bl", [0])


@pytest.mark.bpy
def test_via_blender_refuses_blender_older_than_4_2(tmp_path, monkeypatch, capsys):
    """The bpy wheel's route with the Blender version faked (bpy.app.version is read-only): one line, status 2."""
    pytest.importorskip("bpy")
    from blender_addon import compat
    from headless import render

    monkeypatch.setattr(compat, "running_blender", lambda: (3, 4, 1))
    code = render.main(["--via-blender", "--out", str(tmp_path / "bl"), "--count", "1", *SMALL])
    assert code == 2
    assert capsys.readouterr().err.splitlines() == [
        "error: render.py --via-blender needs Blender 4.2 or later, this is 3.4.1"
    ]
    assert not (tmp_path / "bl").exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--split", "test-meshes", "--seed", "3"], "renders with seed 21000; --seed cannot change it"),
        (["--split", "test-meshes", "--count", "49"], "--count must be in 1..48"),
        (["--split", "test-pbrdf"], "needs --pbrdfs DIR"),
        (["--split", "val", "--shapes", "meshes"], "uses --shapes procedural"),
        (["--split", "nope"], "invalid choice: 'nope'"),
    ],
)
def test_split_flag_errors_are_one_line(tmp_path, extra, message):
    res = subprocess.run([sys.executable, "headless/render.py", "--out", str(tmp_path / "o"), *extra],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 2
    assert message in res.stderr
    assert not (tmp_path / "o").exists()


def test_next_split_without_the_mesh_corpus_is_one_line_naming_the_packages(tmp_path):
    env = {**os.environ, "PBRDF_MESH_CORPUS": str(tmp_path / "no-corpus")}
    res = subprocess.run([sys.executable, "headless/render.py", "--split", "val-next", "--pbrdfs", str(tmp_path),
                          "--out", str(tmp_path / "o")], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env=env)  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and "libcgal-demo and openscad-testing-data" in lines[0], res.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.mitsuba
def test_split_prefix_is_labelled_and_keeps_raw(tmp_path):
    from pbrdf.data import dataset
    from pbrdf.data import sample as psample
    from pbrdf.data.splits import dataset_split

    out = tmp_path / "tm"
    cmd = [sys.executable, "headless/render.py", "--split", "test-meshes", "--count", "1", "--out", str(out), *SMALL]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert dataset_split(out) == "test-meshes" and dataset.read_manifest(out)["seed"] == 21000
    sample, meta = psample.read_sample(out, 0)
    assert meta["split"] == "test-meshes" and "raw" in sample
    assert meta["objects"][0]["mesh"].split("?")[0].removeprefix("builtin:") in {
        "torus_knot", "vase", "gear", "l_block", "dumbbell", "thin_plate"}  # fmt: skip
    # The ground truth covers the object; the training mask is the decoded part of it.
    cover = sample["object"] >= 0
    assert np.all(sample["mask"] <= cover) and np.all(np.linalg.norm(sample["normal"][cover], axis=-1) > 0.99)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--count", "1", "--objects", "3-2"], "--objects 3-2 must be N or MIN-MAX with 1 <= MIN <= MAX"),
        (["--count", "1", "--objects", "0"], "--objects 0 must be N or MIN-MAX"),
        (["--count", "1", "--table-fraction", "0.3"], "--table-fraction 0.3 > 0 needs --pbrdfs DIR"),
        (["--count", "1", "--shapes", "none"], "--shapes none leaves nothing to draw: give --assets DIR"),
        (["--count", "1", "--variant", "gpu"], "--variant gpu must be one of ['auto', 'llvm', 'cuda', 'scalar']"),
        (["--split", "val", "--objects", "2"], "--split val fixes the objects and materials: drop --objects"),
        (["--split", "val", "--table-fraction", "0"], "drop --objects and --table-fraction"),
        (["--split", "test-textured", "--texture-fraction", "0"], "fixed test split: drop --texture-fraction"),
        (["--count", "1", "--texture-fraction", "1.5"], "--texture-fraction 1.5 must be in [0, 1]"),
        (["--split", "test-meshes", "--rig-jitter", "1"], "fixed test split: drop --rig-jitter"),
        (["--count", "1", "--rig-jitter", "5"], "--rig-jitter 5.0 must be in [0, 3]"),
        (["--split", "val-next", "--pbrdfs", ".", "--corpus-fraction", "0.5"], "drop --corpus-fraction"),
    ],
)
def test_scene_content_flag_errors_are_one_line(tmp_path, extra, message):
    res = subprocess.run([sys.executable, "headless/render.py", "--out", str(tmp_path / "o"), *extra],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], res.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.mitsuba
def test_cuda_variant_without_a_gpu_fails_with_one_line(tmp_path):
    drjit = pytest.importorskip("drjit")
    if drjit.has_backend(drjit.JitBackend.CUDA):
        pytest.skip("Dr.Jit has a CUDA backend here")
    cmd = [sys.executable, "headless/render.py", "--out", str(tmp_path / "o"), "--count", "1", "--variant", "cuda"]
    res = subprocess.run([*cmd, *SMALL], cwd=ROOT, capture_output=True, text=True, timeout=120)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("error: --variant cuda: ") and "CUDA backend" in lines[0]


def test_splits_render_with_llvm_unless_told_and_help_lists_the_new_flags():
    from headless.render import _apply_split, build_parser

    parser = build_parser()
    args = parser.parse_args(["--split", "val"])
    _apply_split(args)
    assert args.variant == "llvm" and args.objects == "1-1" and args.shapes == "procedural"
    args = parser.parse_args(["--split", "val", "--variant", "scalar"])
    _apply_split(args)
    assert args.variant == "scalar"
    text = parser.format_help()
    for flag in ("--objects", "--table-fraction", "--variant", "generated", "train", "none"):
        assert flag in text


@pytest.mark.mitsuba
def test_objects_flag_renders_several_objects(tmp_path):
    from pbrdf.data import sample as psample

    out = tmp_path / "multi"
    _run("headless/render.py", "--out", str(out), "--count", "2", "--seed", "4", "--objects", "2-3", "--variant",
         "llvm", *SMALL)  # fmt: skip
    for i in range(2):
        sample, meta = psample.read_sample(out, i)
        n = len(meta["spec"]["objects"])
        assert 2 <= n <= 3 and meta["objects_range"] == [2, 3] and "table_fraction" not in meta
        assert meta["variant"] == "llvm_ad_mono_polarized"
        assert len({o["material"] for o in meta["spec"]["objects"]}) == n
        assert set(np.unique(sample["object"]).tolist()) <= {-1.0, *map(float, range(n))}
        assert len(np.unique(sample["object"])) >= 3  # background and at least two objects in view
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["objects"] == [2, 3] and manifest["variant"] == "llvm_ad_mono_polarized"


@pytest.mark.mitsuba
def test_test_scenes_split_draws_corpus_files_and_unseen_meshes(tmp_path):
    from pbrdf.brdf import seeds, table
    from pbrdf.data import sample as psample
    from pbrdf.data.splits import ASSET_CORPORA

    corpus = ASSET_CORPORA["assimp-testmodels"]
    if not os.path.isdir(corpus):
        pytest.skip("Debian's assimp-testmodels is not installed (make setup installs it)")
    lib = tmp_path / "lib"
    lib.mkdir()
    mat = seeds.SEED_MATERIALS[3]
    table.save_table(lib / "t.pbsdf", seeds.seed_table(mat, grid=(4, 4, 6)))
    entry = {"name": "t", "table": "t.pbsdf", "albedo": [0.5, 0.4, 0.3], "roughness": mat.roughness, "metallic": 0.0}
    (lib / "materials.json").write_text(json.dumps([entry]))
    out = tmp_path / "ts"
    cmd = [sys.executable, "headless/render.py", "--split", "test-scenes", "--count", "4", "--pbrdfs", str(lib),
           "--out", str(out), *SMALL]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    meshes, counts = [], []
    for i in range(4):
        sample, meta = psample.read_sample(out, i)
        counts.append(len(meta["objects"]))
        meshes += [o["mesh"] for o in meta["objects"]]
        ids = set(np.unique(sample["object"]).astype(int).tolist()) - {-1}
        assert ids <= set(range(len(meta["objects"]))) and ids  # per-object ids for per-object scoring
    assert all(1 <= c <= 4 for c in counts) and max(counts) >= 2
    assert all(m.startswith(corpus) or m.startswith("builtin:") for m in meshes)
