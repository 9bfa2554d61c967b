"""headless/robustness.py, the sweep on rendered scenes: nominal cell = evaluation, true rig, display basis, resume."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from headless import robustness as cli
from network import robustness as rb
from network.checkpoint import load_checkpoint
from network.evaluation import evaluate_dataset
from network.infer import DEFAULT_CHECKPOINT, load_input
from pbrdf.data import capture as pcapture
from pbrdf.data import sample as psample

ROOT = Path(__file__).resolve().parents[2]
STATS = {"format": "pdir-train-stats/1", "albedo": [0.4, 0.35, 0.3], "roughness": 0.42, "metallic": 0.3}


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    """The first two scenes of test-procedural at 64 px, 8 spp, with their display bases."""
    root = tmp_path_factory.mktemp("splits") / "test-procedural"
    cmd = [sys.executable, "headless/render.py", "--split", "test-procedural", "--count", "2", "--resolution",
           "64", "--spp", "8", "--out", str(root), "--quiet"]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    cache = cli.BasisCache(root, root / "robustness" / "basis")
    for i in (0, 1):
        cache.ensure(i)
    assert cache.not_reproduced == []  # the re-render gives the split's raw brackets bit for bit
    return root, cache


@pytest.mark.mitsuba
def test_nominal_cell_equals_a_plain_evaluation(split, torch_one_thread):
    root, cache = split
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    cell = rb.run_cell(model, ckpt, root, [0, 1], STATS, cache, "nominal", 0, "nominal")
    plain = evaluate_dataset(model, ckpt, root, STATS, lpips=False)
    assert cell["scenes"] == [0, 1]
    for row, want in zip(cell["rows"], plain["per_scene"], strict=True):
        assert row["mask_iou"] == want["mask_iou"] and row["pixels"] == want["pixels"]
        for k in rb.SWEEP_METRICS:
            assert row["ours"][k] == want["ours"][k], k


@pytest.mark.mitsuba
def test_true_rig_undoes_crosstalk_that_the_nominal_decoder_leaves(split, tmp_path, torch_one_thread):
    root, cache = split
    cap = pcapture.load_capture(psample.sample_paths(root, 0).raw)
    seed = psample.check_complete(root, 0, verify_hash=False)["sample_seed"]
    region = psample.read_sample(root, 0, keys=("object",))[0]["object"] >= 0
    maps = {}
    for name, term, level, decoder in (("ref", "nominal", 0.0, "nominal"), ("nominal", "crosstalk", 0.15, "nominal"),
                                       ("true", "crosstalk", 0.15, "true")):  # fmt: skip
        folder = rb.capture_scene(tmp_path / name, cache(0), cap, seed, term, level, decoder)
        maps[name] = load_input(folder).maps[region]
    err = {k: np.abs(maps[k] - maps["ref"])[:, :6].mean() for k in ("nominal", "true")}  # unpol and LP
    assert err["true"] < 0.25 * err["nominal"], err
    # The model's scores: with the true rig the albedo is as without cross-talk, not with the nominal decoder.
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    cells = {d: rb.run_cell(model, ckpt, root, [0, 1], STATS, cache, "crosstalk", 4, d) for d in rb.DECODERS}
    ref = rb.run_cell(model, ckpt, root, [0, 1], STATS, cache, "nominal", 0, "nominal")

    def off(cell):
        return sum(
            abs(r["ours"]["albedo_psnr"] - n["ours"]["albedo_psnr"])
            for r, n in zip(cell["rows"], ref["rows"], strict=True)
        )

    assert off(cells["true"]) < off(cells["nominal"])


@pytest.mark.mitsuba
def test_display_angle_from_the_basis_matches_a_direct_render(split):
    import dataclasses

    from blender_addon.core import render
    from blender_addon.core.spec import SceneSpec

    root, cache = split
    meta = psample.check_complete(root, 0, verify_hash=False)
    spec = SceneSpec.from_dict(meta["spec"])
    display = dataclasses.replace(spec.rig.display, polarization_angle=math.radians(95.0))
    spec = dataclasses.replace(spec, rig=dataclasses.replace(spec.rig, display=display))
    direct = render.render_stokes(spec, render.RenderSettings(resolution=64, spp=8, variant=meta["variant"])).stokes
    basis = cache(0)
    formed = rb.display_stokes(basis, 1.0, 5.0)
    peak = np.abs(direct).max()
    assert np.abs(formed - direct).max() < 0.01 * peak  # Monte Carlo only
    assert np.abs(formed - direct)[..., 1:3].mean() < 0.2 * np.abs(basis["v"] - direct)[..., 1:3].mean()


@pytest.mark.mitsuba
def test_resume_skips_finished_cells(split, tmp_path, capsys, torch_one_thread):
    root, _ = split
    out = tmp_path / "out"
    args = ["--input", str(root), "--limit", "1", "--out", str(out), "--terms", "display_angle"]
    assert cli.main(args) == 0
    first = capsys.readouterr().out
    assert "[5/5] display_angle-4-nominal (level 5)" in first and (out / "robustness.png").is_file()
    assert "| display polarization-angle error (deg) | 5 | nominal |" in (out / "robustness.md").read_text()
    planted = out / "cells" / "display_angle-1-nominal.json"
    cell = json.loads(planted.read_text())
    cell["seconds"] = -1.0  # a marker: a recomputed cell would lose it
    planted.write_text(json.dumps(cell))
    (out / "cells" / "display_angle-4-nominal.json").unlink()
    assert cli.main([*args, "--resume"]) == 0
    again = capsys.readouterr().out
    assert "[2/5] display_angle-1-nominal: done before, skipped" in again
    assert "[5/5] display_angle-4-nominal (level 5)" in again
    assert json.loads(planted.read_text())["seconds"] == -1.0


def test_help_and_one_line_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0 and "--resume" in capsys.readouterr().out
    assert cli.main(["--input", str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"error: {tmp_path / 'missing'}: split folder not found"]
    assert cli.main(["--input", str(tmp_path), "--limit", "0"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == ["error: --limit must be >= 1, got 0"]


@pytest.mark.mitsuba
def test_calibrated_decoder_brings_the_model_back_to_the_true_rig(split, tmp_path, capsys, torch_one_thread):
    # Every term at its worst level at once (64 px renders): decoded with the rig.json the calibration
    # estimates from synthetic targets, the model scores as with the true rig; with the nominal rig it does not.
    root, _ = split
    out = tmp_path / "out"
    assert cli.main(["--input", str(root), "--limit", "1", "--out", str(out), "--cases", "worst"]) == 0
    text = capsys.readouterr().out
    assert "[4/4] worst-nominal" in text and "| worst | normal MAE (deg) |" in (out / "calibrated.md").read_text()
    assert (out / "calibrated" / "rigs" / "worst-calibrated.json").is_file()
    cells = rb.load_cells(out / "calibrated" / "cells")
    cal, true, nom = (cells[f"worst-{d}"]["rows"][0]["ours"] for d in ("calibrated", "true", "nominal"))
    assert abs(cal["albedo_psnr"] - true["albedo_psnr"]) < 0.1 and abs(cal["normal_mae"] - true["normal_mae"]) < 0.3
    assert abs(nom["albedo_psnr"] - true["albedo_psnr"]) > 1.0 or abs(nom["normal_mae"] - true["normal_mae"]) > 2.0
    assert cells["worst-calibrated"]["calibration_errors"]["crosstalk"] < 5e-3
