"""network/evaluation.py and headless/evaluate.py: the one evaluation, through the capture path or stored maps."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from network import evaluation
from network.checkpoint import load_checkpoint
from network.infer import DEFAULT_CHECKPOINT
from pbrdf.data import sample as psample
from pbrdf.io.strict_json import loads_strict

pytestmark = pytest.mark.mitsuba
ROOT = Path(__file__).resolve().parents[2]
STATS = {"format": "pdir-train-stats/1", "albedo": [0.4, 0.35, 0.3], "roughness": 0.42, "metallic": 0.3}


@pytest.fixture(scope="module")
def test_split(tmp_path_factory):
    """The first three scenes of test-procedural at 48 px (same scenes, smaller images)."""
    root = tmp_path_factory.mktemp("splits") / "test-procedural"
    cmd = [sys.executable, "headless/render.py", "--split", "test-procedural", "--count", "3", "--resolution",
           "48", "--spp", "8", "--out", str(root), "--quiet"]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return root


def test_every_row_is_scored_on_the_object_coverage(test_split):
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    result = evaluation.evaluate_dataset(model, ckpt, test_split, STATS, lpips=False)
    assert result["split"] == "test-procedural" and result["scenes"] == 3
    assert set(result["methods"]) == {"ours", "baseline", "constant", "object_mean"}  # refined: not asked for
    assert result["methods"]["object_mean"]["roughness_rmse"]["count"] == 0  # uniform objects: no oracle row
    assert "paired" not in result and all("refined" not in r for r in result["per_scene"])
    assert "refinement" not in evaluation.results_markdown(result)
    for row in result["per_scene"]:
        s, _ = psample.read_sample(test_split, row["index"], keys=("normal", "object"))
        region = s["object"] >= 0
        assert row["pixels"] == int(region.sum())
        # The constant normal's error, computed independently: angle to +z on the coverage.
        n = s["normal"][region]
        want = np.degrees(np.arctan2(np.linalg.norm(n[:, :2], axis=1), n[:, 2])).mean()
        assert row["constant"]["normal_mae"] == pytest.approx(want, abs=1e-3)
        assert 0.5 < row["mask_iou"] <= 1.0
        assert row["baseline"]["roughness_rmse"] is None  # photometric stereo predicts no roughness
    ours = result["methods"]["ours"]["normal_mae"]
    assert ours["ci"][0] <= ours["mean"] <= ours["ci"][1]


def test_nothing_detected_scores_the_constant_and_no_baseline_brdf(test_split, monkeypatch):
    """A scene whose automatic mask is empty (a dark metal): the constant stands in, photometric stereo
    still predicts no roughness or metallic (it once borrowed the constant's, test-meshes scene 0)."""
    decode = evaluation.load_input
    monkeypatch.setattr(
        evaluation, "load_input", lambda *a, **k: dataclasses.replace(inp := decode(*a, **k), mask=0 * inp.mask)
    )
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    row = evaluation.evaluate_dataset(model, ckpt, test_split, STATS, lpips=False, limit=1)["per_scene"][0]
    assert row["ours"] == row["constant"] and row["mask_iou"] == 0.0
    assert row["baseline"]["normal_mae"] == row["constant"]["normal_mae"]
    assert row["baseline"]["roughness_rmse"] is None and row["baseline"]["metallic_rmse"] is None


def test_refinement_row_is_paired_with_the_network(test_split):
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    result = evaluation.evaluate_dataset(model, ckpt, test_split, STATS, lpips=False, refine=True, limit=2)
    for row in result["per_scene"]:
        assert set(row["refine"]) == {"refined", "seconds", "message", "roughness", "guard"}
        for g in row["refine"]["guard"].values():  # per object, the guard's verdicts (None: refined)
            assert set(g) >= {"roughness"} and (g.get("lp_gain") is None or np.isfinite(g["lp_gain"]))
        # The refinement changes the albedo scale and the roughness per object: the normals are the network's,
        # and so is the roughness wherever every object kept it.
        assert row["refined"]["normal_mae"] == row["ours"]["normal_mae"]
        if all(o["kept"] for o in row["refine"]["roughness"].values()):
            assert row["refined"]["roughness_rmse"] == row["ours"]["roughness_rmse"]
        assert np.isfinite(row["refined"]["roughness_rmse"])
        assert row["refined"]["albedo_si_psnr"] == pytest.approx(row["ours"]["albedo_si_psnr"], abs=0.3)
    want = np.mean([r["refined"]["albedo_psnr"] - r["ours"]["albedo_psnr"] for r in result["per_scene"]])
    assert result["paired"]["albedo_psnr"]["mean"] == pytest.approx(want)
    text = evaluation.results_markdown(result)
    assert "Ours + refinement" in text and "Refinement minus network" in text


def test_cli_writes_strict_json_and_refuses_other_splits(test_split, tmp_path):
    stats = tmp_path / "stats.json"
    stats.write_text('{"format": "pdir-train-stats/1", "albedo": [0.4, 0.35, 0.3], "roughness": 0.42, "metallic": 0.3}')
    out = tmp_path / "eval"
    cmd = [sys.executable, "headless/evaluate.py", "--split", "test", "--input", str(test_split.parent),
           "--train-stats", str(stats), "--out", str(out), "--quiet"]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "Constant (normal to camera, train means)" in proc.stdout and "IoU" in proc.stdout
    assert "| Ours (shipped model) |" in proc.stdout  # the default checkpoint
    assert "not rendered (skipped): test-meshes, test-pbrdf" in proc.stdout
    data = loads_strict((out / "test_splits.json").read_text())
    assert data["results"][0]["scenes"] == 3
    # An unlabelled dataset is no test split: one error line, exit 2.
    plain = tmp_path / "plain" / "test-procedural"
    (plain / "samples").mkdir(parents=True)
    cmd[5] = str(plain.parent)
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert "not a test split" in proc.stderr


def _copy_of_shipped_model(folder, *, nan=False):
    """The shipped model (and its training statistics) in ``folder``; with ``nan`` every weight is NaN.

    The parameter hash is recomputed, so the copy passes as an intact checkpoint.
    """
    import shutil

    import torch

    from network.checkpoint import params_sha256

    folder.mkdir(parents=True, exist_ok=True)
    ckpt = torch.load(DEFAULT_CHECKPOINT, weights_only=True, map_location="cpu")
    if nan:
        ckpt["model"] = {k: torch.full_like(v, float("nan")) if v.is_floating_point() else v
                         for k, v in ckpt["model"].items()}  # fmt: skip
        ckpt["params_sha256"] = params_sha256(ckpt["model"])
    torch.save(ckpt, folder / "model.pt")
    shutil.copy(DEFAULT_CHECKPOINT.parent / "train_stats.json", folder / "train_stats.json")
    return folder / "model.pt"


def test_a_checkpoint_that_predicts_nan_stops_the_evaluation(test_split, tmp_path):
    # It used to be scored as the constant predictor (exit 0, an "Ours" row equal to the constant one).
    path = _copy_of_shipped_model(tmp_path / "broken", nan=True)
    out = tmp_path / "eval"
    cmd = [sys.executable, "headless/evaluate.py", "--split", "test-procedural", "--input", str(test_split.parent),
           "--checkpoint", str(path), "--limit", "2", "--out", str(out), "--quiet"]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode != 0 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: ") and "NaN" in lines[0], lines
    assert not out.exists() and "Ours" not in proc.stdout  # no table was written or printed


def test_input_dir_gets_the_split_report_with_the_checkpoint_named(test_split, tmp_path):
    path = _copy_of_shipped_model(tmp_path / "mine")
    out = tmp_path / "eval"
    cmd = [sys.executable, "headless/evaluate.py", "--input", str(test_split), "--checkpoint", str(path),
           "--limit", "2", "--jobs", "1", "--out", str(out), "--quiet"]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    result = loads_strict((out / "evaluation.json").read_text())["results"][0]
    assert result["model"] == "Ours (mine/model.pt)" and result["scenes"] == 2
    table = (out / "evaluation.md").read_text()
    labels = [ln.split("|")[1].strip() for ln in table.splitlines() if ln.startswith("| ") and "---" not in ln]
    assert {"Ours (mine/model.pt)", "Photometric stereo (calibrated)", "Constant (normal to camera, train means)"} <= (
        set(labels)
    ) and "Ours (shipped model)" not in table
    assert not any(lbl.startswith("Per-object mean") for lbl in labels)  # uniform objects: the oracle is the truth
    for m in ("ours", "baseline", "constant"):  # per-scene means with their 95 % intervals, the mean inside
        s = result["methods"][m]["normal_mae"]
        assert s["ci"][0] <= s["mean"] <= s["ci"][1], (m, s)


@pytest.fixture(scope="module")
def stored_maps(tmp_path_factory):
    """Two rendered samples without raw brackets (a plain dataset: only the stored maps and mask)."""
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("plain")
    assert len(generate(GenerateConfig(out=root, count=2, resolution=32, spp=4, seed=11), progress=False).written) == 2
    return root


def test_samples_without_raw_brackets_are_scored_from_their_stored_maps(stored_maps):
    from network import metrics
    from network.infer import predict

    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    polar = {**ckpt, "inputs": "polar"}  # the input variant is applied (once) inside predict
    result = evaluation.evaluate_dataset(model, polar, stored_maps, STATS, lpips=False)
    assert result["split"] is None and result["scenes"] == 2 and result["model"] == "Ours"
    for row in result["per_scene"]:
        sample, meta = psample.read_sample(stored_maps, row["index"])
        assert not psample.sample_paths(stored_maps, row["index"]).raw.exists()
        mask = sample["mask"].astype(bool)
        region = sample["object"] >= 0 if "object" in sample else mask
        assert row["mask_iou"] == pytest.approx((mask & region).sum() / (mask | region).sum())
        maps = sample["maps"].copy()
        maps[..., 6:] = 0  # no CP: what the 'polar' variant sees, zeroed here independently
        pred = predict(model, maps, mask, input_scale=ckpt["input_scale"], radiance=meta["rig"]["display"]["radiance"])
        if np.array_equal(region, mask):
            want = metrics.normal_mae_deg(pred["normal"], sample["normal"], mask)
            assert row["ours"]["normal_mae"] == pytest.approx(want, rel=1e-6)
        assert row["baseline"]["normal_mae"] is not None and row["baseline"]["metallic_rmse"] is None


def test_worker_processes_give_the_same_rows(test_split):
    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    one = evaluation.evaluate_dataset(model, ckpt, test_split, STATS, lpips=False, limit=2)
    two = evaluation.evaluate_dataset(model, ckpt, test_split, STATS, lpips=False, limit=2, jobs=2,
                                    checkpoint_path=DEFAULT_CHECKPOINT)  # fmt: skip
    for a, b in zip(one["per_scene"], two["per_scene"], strict=True):
        assert a["index"] == b["index"] and a["mask_iou"] == b["mask_iou"]
        for m in ("ours", "baseline", "constant"):  # one torch thread vs two: float rounding only
            assert b[m]["normal_mae"] == pytest.approx(a[m]["normal_mae"], abs=1e-3)
    with pytest.raises(ValueError, match="checkpoint_path"):
        evaluation.evaluate_dataset(model, ckpt, test_split, STATS, lpips=False, jobs=2)


def test_scores_per_object_of_a_multi_object_scene():
    # Two objects: "ours" exact on the left one, 90 deg off on the right one. The per-object rows
    # must separate them, and their mean weigh each object once (not by its pixels).
    h, w = 8, 12
    objects = -np.ones((h, w), dtype=np.int64)
    objects[2:6, 1:3] = 0  # 8 pixels
    objects[1:7, 5:11] = 1  # 36 pixels
    region = objects >= 0
    n_gt = np.zeros((h, w, 3), np.float32)
    n_gt[..., 2] = 1.0
    n_ours = n_gt.copy()
    n_ours[objects == 1] = (1.0, 0.0, 0.0)
    gt = {"normal": n_gt, "albedo": np.full((h, w, 3), 0.5, np.float32), "roughness": np.full((h, w), 0.3, np.float32),
          "metallic": np.zeros((h, w), np.float32)}  # fmt: skip
    preds = {m: dict(gt, normal=n_ours if m == "ours" else n_gt) for m in evaluation.METHODS}
    meta = {"objects": [{"mesh": "builtin:sphere", "material": "a"}, {"mesh": "x.glb", "material": "b"}],
            "materials": {"a": {"kind": "pplastic"}, "b": {"kind": "measured"}}}  # fmt: skip
    scene = evaluation.ScenePredictions(0, meta, np.zeros((h, w, 9)), region, region, gt, preds, None, objects)
    row = evaluation.score_scene(scene, lpips=False)
    per = {o["id"]: o for o in row["objects"]}
    assert per[0]["pixels"] == 8 and per[1]["pixels"] == 36 and per[1]["material"] == "measured"
    assert per[0]["ours"]["normal_mae"] == pytest.approx(0.0, abs=1e-4)
    assert per[1]["ours"]["normal_mae"] == pytest.approx(90.0, abs=1e-3)
    summary = evaluation.summarize_rows([row])
    assert summary["objects"] == 2
    assert summary["per_object"]["ours"]["normal_mae"]["mean"] == pytest.approx(45.0, abs=1e-3)
    assert row["ours"]["normal_mae"] == pytest.approx(90.0 * 36 / 44, abs=1e-3)  # the scene weighs pixels


def test_per_object_roughness_correlation_is_over_dielectric_objects():
    """Four one-object scenes: the model's roughness follows the truth on the dielectrics, the constant
    does not; the metal (whose roughness the model gets wrong) is left out of the correlation."""
    h, w = 4, 4
    objects = np.zeros((h, w), np.int64)
    region = objects >= 0
    rows = []
    for i, (r_true, r_ours, metal) in enumerate([(0.2, 0.25, 0), (0.5, 0.45, 0), (0.8, 0.7, 0), (0.3, 0.9, 1)]):
        gt = {"normal": np.dstack([np.zeros((h, w, 2)), np.ones((h, w))]), "albedo": np.full((h, w, 3), 0.5),
              "roughness": np.full((h, w), r_true), "metallic": np.full((h, w), float(metal))}  # fmt: skip
        preds = {m: dict(gt, roughness=np.full((h, w), r_ours if m == "ours" else 0.4)) for m in evaluation.METHODS}
        meta = {"objects": [{"mesh": "builtin:sphere", "material": "a"}], "materials": {"a": {"kind": "pplastic"}}}
        scene = evaluation.ScenePredictions(i, meta, np.zeros((h, w, 9)), region, region, gt, preds, None, objects)
        rows.append(evaluation.score_scene(scene, lpips=False))
    corr = evaluation.summarize_rows(rows)["roughness_correlation"]
    want = np.corrcoef([0.2, 0.5, 0.8], [0.25, 0.45, 0.7])[0, 1]
    assert corr["ours"]["count"] == 3 and corr["ours"]["r"] == pytest.approx(want)
    assert corr["constant"]["r"] is None  # no correlation to speak of
    md = evaluation.results_markdown({"data": "d", "scenes": 4, **evaluation.summarize_rows(rows)})
    assert f"ours {want:.2f}" in md and "constant none (constant)" in md


def test_per_object_oracle_knows_each_objects_mean_but_no_texture():
    """Two objects, one striped in roughness and albedo: the oracle predicts each object's mean."""
    h, w = 8, 12
    objects = np.full((h, w), -1)
    objects[:, :6], objects[:, 6:11] = 0, 1
    region = objects >= 0
    rough = np.where(np.arange(w) % 2 == 0, 0.2, 0.6) * np.ones((h, 1))
    rough[:, 6:] = 0.9  # object 1 is uniform
    albedo = np.repeat(rough[..., None], 3, axis=2) / 2
    gt = {"albedo": albedo, "roughness": rough, "metallic": np.zeros((h, w)), "normal": np.zeros((h, w, 3))}
    pred = evaluation.object_mean_predict(gt, region, objects)
    assert np.allclose(pred["roughness"][:, :6], 0.4) and np.allclose(pred["roughness"][:, 6:11], 0.9)
    assert np.allclose(pred["albedo"][:, :6], 0.2) and (pred["roughness"][~region] == 0).all()
    scores = evaluation.score(pred, gt, region, lpips=False)
    assert scores["roughness_rmse"] == pytest.approx(0.2 * np.sqrt(48 / 88))  # +-0.2 on object 0's 48 of 88 pixels
    assert scores["normal_mae"] is None  # it knows materials only
    gt["roughness"][:, :6] = 0.3
    gt["albedo"][:, :6] = 0.1
    assert evaluation.object_mean_predict(gt, region, objects) == {}  # every object uniform: n/a


def test_depth_is_scored_from_the_integrated_normals():
    """Exact normals of a sphere integrate to its depth (up to scale); a flat answer does not."""
    from pbrdf.sensor.projection import pinhole_intrinsics, pixel_rays

    k = pinhole_intrinsics(200.0, 48, 48)
    rays = pixel_rays(k, 48, 48)
    c, radius = np.array([0.0, 0.0, -0.7]), 0.1
    b, rr = rays @ c, np.sum(rays * rays, -1)
    disc = b * b - rr * (c @ c - radius**2)
    region = disc > 0
    t = np.where(region, (b - np.sqrt(np.where(region, disc, 0))) / rr, 0.0)
    normal = ((t[..., None] * rays - c) / radius).astype(np.float32)
    gt = {"normal": normal, "depth": t.astype(np.float32)}
    exact = evaluation.score({"normal": normal}, gt, region, lpips=False, intrinsics=k)["depth_si_error"]
    flat = np.zeros_like(normal)
    flat[..., 2] = 1.0
    plane = evaluation.score({"normal": flat}, gt, region, lpips=False, intrinsics=k)["depth_si_error"]
    assert exact < 0.2 < 1.0 < plane, (exact, plane)
    assert evaluation.score({"normal": normal}, gt, region, lpips=False)["depth_si_error"] is None  # no camera
