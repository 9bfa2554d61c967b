"""Tests of network/ablation.py and headless/ablation.py: six runs, one budget, one table (toy scale)."""

import json

import pytest
import torch

from network import ablation, compare

pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py


def test_scene_kind_reads_every_object():
    mats = {"t": {"kind": "measured"}, "p": {"kind": "pplastic"}, "c": {"kind": "pconductor"}}
    kind = lambda *names: ablation.scene_kind({"materials": mats, "objects": [{"material": n} for n in names]})  # noqa: E731
    assert (kind("t", "t"), kind("p", "c"), kind("t", "p")) == ("expanded", "analytic", "mixed")


def test_config_refuses_unknown_runs(tmp_path):
    with pytest.raises(ValueError, match=r"unknown ablation runs \['rgb'\]"):
        ablation.AblationConfig(splits=tmp_path, out=tmp_path, runs=("full", "rgb"))


def test_trend_lines_say_when_a_trend_does_not_hold():
    def row(mae, metal):
        return {"methods": {"ours": {"normal_mae": {"mean": mae}, "metallic_rmse": {"mean": metal}}}}

    def verdicts(res):
        return tuple(line.split(":", 1)[0] for line in ablation.trend_lines(res))

    res = {"white": row(30, 0.30), "spectral": row(29, 0.2), "polar": row(20, 0.19), "full": row(19, 0.18)}
    # Without per-scene rows a step's gain is the difference of the means, with no interval.
    assert compare.paired_gain(res, "spectral", "polar", "normal_mae") == (pytest.approx(9.0), None)
    # Polarization gains most in normal MAE, spectral multiplexing in metallic RMSE: neither paper trend holds.
    assert verdicts(res) == ("does not hold", "does not hold")
    # The verdicts follow the data: make the paper's factor the largest gain of each metric.
    res["white"], res["full"] = row(40, 0.30), row(19, 0.05)
    assert verdicts(res) == ("holds", "holds")
    assert verdicts({"full": row(1, 1)}) == ("not checked", "not checked")


def test_trend_lines_pair_the_scenes():
    """Scene difficulty dwarfs a 1 deg gain; pairing the scenes still resolves it, and a zero-mean step is noise."""
    import numpy as np

    rng = np.random.default_rng(0)
    hard = rng.uniform(10, 50, 40)  # per-scene difficulty, shared by every run

    def row(mae, metal):
        scenes = [{"index": i, "ours": {"normal_mae": float(a), "metallic_rmse": float(b)}}
                  for i, (a, b) in enumerate(zip(mae, metal, strict=True))]  # fmt: skip
        means = {"normal_mae": {"mean": float(np.mean(mae))}, "metallic_rmse": {"mean": float(np.mean(metal))}}
        return {"per_scene": scenes, "methods": {"ours": means}}

    noise = lambda s: rng.normal(0, s, 40)  # noqa: E731
    runs = {"white": (hard + 1.0, 0.3 + noise(0.01)), "spectral": (hard + noise(0.1), 0.3 + noise(0.01))}
    runs["polar"] = (runs["spectral"][0] + noise(0.1), runs["spectral"][1] + noise(0.05))
    runs["full"] = (runs["polar"][0] + noise(0.1), runs["polar"][1] + noise(0.05))
    res = {k: row(*v) for k, v in runs.items()}
    normal, metal = ablation.trend_lines(res)
    gain, (lo, hi) = compare.paired_gain(res, "white", "spectral", "normal_mae")
    # Unpaired, the 40-scene means' standard errors (about 1.8 deg each) swamp the 1 deg step.
    assert np.std(hard) / np.sqrt(40) > 1.5
    assert 0.9 < lo < gain < hi < 1.1
    assert normal.startswith("holds: spectral multiplexing") and "within noise" not in normal
    assert "paired 95 % intervals over scenes" in normal
    assert "interval includes 0, so the ranking is within noise" in metal


@pytest.fixture(scope="module")
def splits(tmp_path_factory, pbrdf_library):
    """Tiny stand-ins for train-engine, test-scenes and their white twins (32 px, 4 spp)."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("splits")
    common = {"resolution": 32, "spp": 4, "pbrdfs": pbrdf_library, "objects": (1, 2), "table_fraction": 0.5}
    for name, seed, count, raw in (("train-engine", 3, 12, False), ("test-scenes", 4, 2, True)):
        for suffix, pattern in (("", None), ("-white", "white")):
            generate(GenerateConfig(out=root / f"{name}{suffix}", count=count, seed=seed, keep_raw=raw,
                                    split=f"{name}{suffix}", pattern=pattern, **common), progress=False)  # fmt: skip
    return root


@pytest.mark.mitsuba
def test_ablation_trains_six_runs_and_writes_the_table(splits, tmp_path, capsys):
    from headless.ablation import main
    from pbrdf.data import sample as psample

    out = tmp_path / "abl"
    args = ["--input", str(splits), "--out", str(out), "--scenes", "2", "--steps", "2", "--batch-size", "1",
            "--limit", "2", "--quiet", "--config", "toy", "--overrides", "image_size=32", "canonical_size=16",
            "train_pixels=16", "infer_chunk=512"]  # fmt: skip
    assert main(args) == 0
    table = (out / "ablation.md").read_text()
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| run")]
    assert [r.split(" | ")[0][2:] for r in rows] == [*(r.name for r in ablation.RUNS), "constant", "baseline"]
    assert "| white | uniform white illumination | test-scenes-white (2) |" in table
    assert "| full | + circular polarization (ours) | test-scenes (2) |" in table
    assert "Trends of the paper:" in table and "Command: `python headless/ablation.py --input" in table
    results = json.loads((out / "ablation.json").read_text())["results"]
    for run in ablation.RUNS:  # each run saw its own variant, for the whole budget
        ckpt = torch.load(out / run.name / "model.pt", weights_only=True)
        assert ckpt["inputs"] == run.inputs and ckpt["step"] == 2 and results[run.name]["step"] == 2
        train = torch.load(out / run.name / "checkpoint.pt", weights_only=True)["train"]
        assert train["steps"] == 2 and train["seed"] == 0 and len(train["indices"]) == 2
        data = splits / run.data
        for i in train["indices"]:  # the sources' scenes, checked against the sidecars' material kinds
            meta = json.loads(psample.sample_paths(data, i).sidecar.read_text())
            kinds = {meta["materials"][o["material"]]["kind"] == "measured" for o in meta["objects"]}
            assert {"analytic": kinds == {False}, "expanded": kinds == {True}}.get(run.scenes, True)
    # Run again: training is finished, nothing is retrained (same model files).
    before = {r.name: (out / r.name / "model.pt").stat().st_mtime_ns for r in ablation.RUNS}
    assert main([*args, "--stage", "train"]) == 0
    assert before == {r.name: (out / r.name / "model.pt").stat().st_mtime_ns for r in ablation.RUNS}
    # Too few scenes of a kind: one line, exit 2.
    capsys.readouterr()
    assert main([*args[:4], "--scenes", "50", "--stage", "train", "--runs", "analytic"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run 'analytic' needs 50 analytic scenes, found" in err
