"""headless/bench.py: the JSON on stdout equals the file, argument checks, the network benchmark end to end."""

import json
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_bench_decode_json(tmp_path):
    out = tmp_path / "bench.json"
    proc = _run("headless/bench.py", "decode", "--height", "64", "--width", "96", "--repeat", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result == json.loads(proc.stdout)
    for grid, shape in (("half", [32, 48, 9]), ("full", [64, 96, 9])):
        entry = result[f"ours_{grid}"]
        assert entry["output_shape"] == shape
        # The one timing rule: one warm-up, then --repeat timed calls, each entry saying what it timed.
        assert entry["warmup_runs"] == 1 and entry["repeats"] == 3 and len(entry["seconds_all"]) == 3
        assert entry["seconds_median"] == statistics.median(entry["seconds_all"])
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
    from network.bench.model import EXAMPLE_CAPTURE, SHIPPED_CHECKPOINT, smooth_input
    from network.config import get_config
    from network.model import PolarInverseModel, count_parameters

    out = tmp_path / "net.json"
    proc = _run("headless/bench.py", "network", "--configs", "toy", "--strides", "1", "2", "--repeat", "2", "--out",
                str(out))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    toy = result["configs"]["toy"]
    size = get_config("toy").image_size
    assert toy["parameters"] == count_parameters(PolarInverseModel(get_config("toy")))
    assert toy["image_size"] == size and toy["masked_pixels"] == int(smooth_input(size, 0.5)[1].sum())
    # Every timed entry follows the one rule, names what it timed, and the summary keys are its medians.
    s1, s2 = toy["inference"]["stride_1"], toy["inference"]["stride_2"]
    for entry in (toy["train_forward"], toy["train_step"], toy["encode"], s1["decode"], s2["decode"]):
        assert entry["warmup_runs"] == 1 and entry["repeats"] == 2 and entry["what"]
        assert entry["seconds_median"] == statistics.median(entry["seconds_all"])
    assert toy["train_forward"]["what"].startswith("training-mode forward with gradients enabled")
    assert toy["train_forward"]["grad_enabled"] is True
    assert toy["train_step_seconds"] == toy["train_step"]["seconds_median"]
    assert toy["decoder_pixels_per_second"] == pytest.approx(toy["masked_pixels"] / s1["decode"]["seconds_median"])
    assert s1["total_seconds"] == pytest.approx(toy["encode"]["seconds_median"] + s1["decode"]["seconds_median"])
    if SHIPPED_CHECKPOINT.is_file():  # the stride error comes from the shipped model on the example capture
        pred = result["predict"]
        assert pred["checkpoint"] == str(SHIPPED_CHECKPOINT) and pred["capture"] == str(EXAMPLE_CAPTURE)
        err = pred["stride_2"]["error_vs_stride_1"]
        assert set(err) >= {"normal_deg_mean", "normal_deg_p99", "albedo_mae", "roughness_mae", "metallic_mae"}
        assert 0.0 < err["normal_deg_mean"] <= err["normal_deg_p99"] <= err["normal_deg_max"] < 90.0
        assert "at stride 2" in pred["stride_2"]["what"] and "error_vs_stride_1" not in pred["stride_1"]


def test_bench_quick(tmp_path):
    """--quick runs the toy network only."""
    out = tmp_path / "quick.json"
    proc = _run("headless/bench.py", "network", "--quick", "--no-train", "--input", str(tmp_path), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert list(json.loads(out.read_text())["configs"]) == ["toy"]


def test_bench_render_scenes_and_argument_checks(tmp_path):
    """render's two scenes (the table one with a tabulated seed material), and its spp checks (no rendering)."""
    from blender_addon.core.spec import SceneSpec
    from headless.bench import TABLE_SEED, render_scenes
    from pbrdf.brdf.table import load_table

    scenes = render_scenes(["analytic", "table"], None, tmp_path)
    assert list(scenes) == ["analytic", "table"]
    analytic, table = scenes["analytic"][0], scenes["table"][0]
    assert SceneSpec.from_dict(table.to_dict()) == table  # a valid spec
    (mat,) = table.materials
    assert mat.kind == "measured" and load_table(mat.table).M.shape[3] == 5 and TABLE_SEED in scenes["table"][1]
    assert table.objects == analytic.objects and analytic.materials[0].kind == "pplastic"
    assert list(render_scenes(["table"], tmp_path / f"{TABLE_SEED}.pbsdf", tmp_path)) == ["table"]
    textured = render_scenes(["textured", "table_textured"], None, tmp_path)
    assert list(textured) == ["textured", "table_textured"]
    for spec, _ in textured.values():
        assert SceneSpec.from_dict(spec.to_dict()) == spec and spec.materials[0].textures.slots()
    assert textured["table_textured"][0].materials[0].textures.tables
    for bad in (["--spp", "16", "4"], ["--spp", "4", "--ref-spp", "2"]):
        proc = _run("headless/bench.py", "render", *bad)
        assert proc.returncode == 2 and "--spp must be ascending" in proc.stderr


def test_bench_render_cuda_without_a_gpu_is_one_error_line():
    """--variant cuda on a machine whose Dr.Jit has no CUDA backend: exit 2 and one line, no traceback."""
    import drjit as dr

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("this machine has a CUDA backend")
    proc = _run("headless/bench.py", "render", "--quick", "--quiet", "--variant", "cuda")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().count("\n") == 0 and "CUDA backend" in proc.stderr
