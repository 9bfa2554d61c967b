"""headless/compare.py and network/compare.py: paired verdicts, the gate, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from headless.compare import WORSE, main
from network.compare import compare_results


def _result(split, normal, psnr):
    pairs = enumerate(zip(normal, psnr, strict=True))
    rows = [{"index": i, "ours": {"normal_mae": n, "albedo_psnr": p}} for i, (n, p) in pairs]
    methods = {"ours": {"normal_mae": {"mean": float(np.mean(normal))}, "albedo_psnr": {"mean": float(np.mean(psnr))}}}
    return {"split": split, "per_scene": rows, "methods": methods}


def _write(path, results):
    path.write_text(json.dumps({"results": results}))
    return path


@pytest.fixture
def pair(tmp_path):
    rng = np.random.default_rng(0)
    n = rng.uniform(8, 20, 30)
    p = rng.uniform(15, 25, 30)
    noise = rng.normal(0, 0.1, 30)
    before = [_result("test-a", n, p), _result("test-b", n, p)]
    # a: normals 1 deg better on every scene, albedo unchanged up to noise; b: albedo 1 dB worse.
    after = [_result("test-a", n - 1 + noise, p + noise), _result("test-b", n + noise, p - 1 + noise)]
    return _write(tmp_path / "before.json", before), _write(tmp_path / "after.json", after)


def test_verdicts_follow_the_direction_of_each_metric(pair):
    before, after = (json.loads(p.read_text())["results"] for p in pair)
    rows = {(r["split"], r["metric"]): r for r in compare_results(before, after)}
    assert rows["test-a", "normal_mae"]["verdict"] == "better" and rows["test-a", "normal_mae"]["gain"] > 0.9
    assert rows["test-a", "albedo_psnr"]["verdict"] == "no difference"
    assert rows["test-b", "albedo_psnr"]["verdict"] == "worse"  # PSNR: lower is worse
    assert rows["test-b", "albedo_psnr"]["gain"] == pytest.approx(-1.0, abs=0.1)
    assert rows["test-b", "albedo_psnr"]["ci"][1] < 0 and rows["test-a", "normal_mae"]["scenes"] == 30


def test_cli_prints_writes_and_gates(pair, tmp_path, capsys):
    before, after = pair
    out = tmp_path / "cmp.md"
    assert main(["--before", str(before), "--after", str(after), "--out", str(out)]) == 0
    md = out.read_text()
    assert "| test-b | Albedo PSNR (dB) |" in md and "Worse at 95 %: test-b albedo_psnr." in md
    assert main(["--before", str(before), "--after", str(after), "--gate"]) == WORSE
    assert main(["--before", str(before), "--after", str(before), "--gate"]) == 0  # equal: never worse


def test_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    empty = tmp_path / "empty"
    empty.mkdir()
    other = str(_write(tmp_path / "other.json", [_result("test-c", [1.0], [2.0])]))
    unrelated = str(_write(tmp_path / "x.json", [{"split": "y"}]))
    cases = (([str(bad), str(bad)], "not JSON"), ([str(empty), str(bad)], "no test_splits.json"),
             ([other, unrelated], "share no split"))  # fmt: skip
    for args, what in cases:
        capsys.readouterr()
        assert main(["--before", args[0], "--after", args[1]]) == 2
        err = capsys.readouterr().err
        assert what in err and err.count("\n") == 1
