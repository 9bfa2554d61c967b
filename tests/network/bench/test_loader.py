"""The loader benchmark (network.bench.loader, ``headless/bench.py loader``) on a tiny split."""

import json
import math

import numpy as np

from tests.network.test_packed import _write_split


def test_loader_bench_quick_rows(tmp_path, capsys):
    from headless import bench

    split = _write_split(tmp_path / "split", 3, np.random.default_rng(2))
    out = tmp_path / "loader.json"
    assert bench.main(["loader", "--quick", "--input", str(split), "--repeat", "1", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert json.loads(capsys.readouterr().out) == result
    entry = result["sizes"]["64"]
    assert entry["samples"] == 2 and set(entry["loader"]) == {
        f"{k}/workers_{w}" for k in ("exr", "pack") for w in (0, 1)
    }
    for key, row in entry["loader"].items():
        assert f"{row['workers']} worker processes" in row["what"] and "at 64 px" in row["what"]
        block = int(row["what"].split()[0])
        assert block >= 2 * row["workers"] and math.isclose(
            row["samples_per_second"], block * 2 / row["seconds_median"]
        )
        ratio = row["samples_per_second"] / entry["model"]["batch_2"]["samples_per_second"]
        assert math.isclose(entry["headroom_over_model_batch_2"][key], ratio)
    item = entry["item"]
    assert len(item["exr"]["cpu_seconds_all"]) == len(item["pack"]["cpu_seconds_all"]) == 2  # --repeat 1, 2 samples
    assert math.isclose(
        item["pack_over_exr_cpu"], item["exr"]["cpu_seconds_median"] / item["pack"]["cpu_seconds_median"]
    )
    assert "batch 2" in entry["model"]["batch_2"]["what"] and entry["model"]["batch_2"]["repeats"] == 1
    # the copies are 64 px samples; the pack holds 17 float16 channels (maps, targets) and a uint8 mask
    assert entry["pack_bytes_per_sample"] == 64 * 64 * (17 * 2 + 1)
