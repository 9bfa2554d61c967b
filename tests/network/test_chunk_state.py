"""network.chunk_state: bf16 chunk states between chunks, the re-warm, the wall-clock budget."""

import csv
import gzip
import json

import numpy as np
import pytest
import torch

from network.checkpoint import load_checkpoint
from network.chunk_state import export_state, read_info, seed_run
from network.train import TrainConfig, train

pytestmark = [pytest.mark.usefixtures("torch_one_thread"), pytest.mark.mitsuba]  # tests/conftest.py


def _cfg(data, out, **kw):
    base = {"config": "toy", "lr": 1e-3, "seed": 0, "checkpoint_every": 10, "steps": 40, "warmup_steps": 4,
            "tensorboard": False, "device": "cpu"}  # fmt: skip
    return TrainConfig(data=data, out=out, **{**base, **kw})


def _val_steps(path):
    with open(path, newline="") as f:
        return [int(r["step"]) for r in csv.DictReader(f)]


def test_chunk_continues_the_loss_curve(tiny_dataset, tmp_path):
    # The continuous run, and the same run cut at step 20 into a bf16 chunk state with a fresh optimizer.
    full = train(_cfg(tiny_dataset, tmp_path / "full"), progress=False)
    train(_cfg(tiny_dataset, tmp_path / "a", stop_after=20, val=tiny_dataset, val_samples=2), progress=False)
    info = export_state(tmp_path / "a", tmp_path / "state", {"device": "cpu"})
    assert info["step"] == 20 and info["chunks"][-1]["start"] == 0 and info["chunks"][-1]["end"] == 20
    assert info["train"]["lr"] == 1e-3 and "out" not in info["train"]
    state = torch.load(tmp_path / "state" / "state.pt", weights_only=True)
    assert {v.dtype for v in state["model"].values() if v.is_floating_point()} == {torch.bfloat16}
    load_checkpoint(tmp_path / "state" / "state.pt")  # loads as a model.pt
    assert _val_steps(tmp_path / "state" / "val.csv") == [10, 20]
    log_rows = gzip.decompress((tmp_path / "state" / "log.csv.gz").read_bytes()).decode().splitlines()
    assert log_rows[0].startswith("step,") and len(log_rows) == 21

    assert seed_run(tmp_path / "state", tmp_path / "b", seed=0, weight_decay=0.05) == 20
    chunk = train(_cfg(tiny_dataset, tmp_path / "b", resume=True, val=tiny_dataset, val_samples=2, rewarm_from=20,
                       rewarm_steps=4), progress=False)  # fmt: skip
    assert len(chunk) == 20 and np.all(np.isfinite(chunk))
    # No jump: the first five losses after the cut stay within 25 % of the continuous run's (tolerance of
    # the re-warm, measured on this toy run; a chunk restarted from random weights is several times higher).
    ratio = np.mean(chunk[:5]) / np.mean(full[20:25])
    assert 0.75 < ratio < 1.25, ratio
    assert np.mean(chunk[-5:]) < np.mean(full[:5])  # it keeps learning
    # The curves go on in one file: log rows 0..39, validation rows from both chunks.
    with open(tmp_path / "b" / "log.csv", newline="") as f:
        assert [int(r["step"]) for r in csv.DictReader(f)] == list(range(40))
    assert _val_steps(tmp_path / "b" / "val.csv") == [10, 20, 30, 40]
    info2 = export_state(tmp_path / "b", tmp_path / "state", {"device": "cpu"})
    assert info2["step"] == 40 and [(c["start"], c["end"]) for c in info2["chunks"]] == [(0, 20), (20, 40)]
    with open(tmp_path / "b" / "val.csv", newline="") as f:
        maes = {int(r["step"]): float(r["normal_mae_deg"]) for r in csv.DictReader(f)}
    assert [c["val_normal_mae_deg"] for c in info2["chunks"]] == [maes[20], maes[40]]
    best = min(maes, key=maes.get)
    assert info2["best"] == {"step": best, "val_normal_mae_deg": maes[best]}


def test_seed_run_keeps_a_killed_chunk_and_refuses_a_torn_state(tiny_dataset, tmp_path):
    assert seed_run(tmp_path / "none", tmp_path / "r0", seed=0, weight_decay=0.05) == 0  # no state: a fresh run
    assert not (tmp_path / "r0").exists()
    train(_cfg(tiny_dataset, tmp_path / "a", steps=4, checkpoint_every=2, stop_after=2), progress=False)
    export_state(tmp_path / "a", tmp_path / "s")
    train(_cfg(tiny_dataset, tmp_path / "a", steps=4, checkpoint_every=2, resume=True, stop_after=4), progress=False)
    assert seed_run(tmp_path / "s", tmp_path / "a", seed=0, weight_decay=0.05) == 4  # its own checkpoint wins
    assert not (tmp_path / "a" / "seeded.json").exists()
    export_state(tmp_path / "a", tmp_path / "s4")  # a newer state (another machine's chunk) replaces a run at 2
    train(_cfg(tiny_dataset, tmp_path / "c", steps=4, checkpoint_every=2, stop_after=2), progress=False)
    assert seed_run(tmp_path / "s4", tmp_path / "c", seed=0, weight_decay=0.05) == 4
    assert json.loads((tmp_path / "c" / "seeded.json").read_text()) == {"step": 4}
    info = json.loads((tmp_path / "s" / "state.json").read_text())
    (tmp_path / "s" / "state.json").write_text(json.dumps({**info, "step": 3}))
    with pytest.raises(ValueError, match="partly copied"):
        seed_run(tmp_path / "s", tmp_path / "b", seed=0, weight_decay=0.05)
    (tmp_path / "s" / "state.json").write_text("{")
    with pytest.raises(ValueError, match="state.json: unreadable"):
        read_info(tmp_path / "s")
    with pytest.raises(ValueError, match="no checkpoint"):
        export_state(tmp_path / "empty", tmp_path / "s2")


def test_time_budget_stops_validated_and_saved(tiny_dataset, tmp_path):
    losses = train(_cfg(tiny_dataset, tmp_path / "t", time_budget=1e-3, val=tiny_dataset, val_samples=1),
                   progress=False)  # fmt: skip
    assert len(losses) == 1  # the first step already spends the budget
    ckpt = torch.load(tmp_path / "t" / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 1 and _val_steps(tmp_path / "t" / "val.csv") == [1]
    with pytest.raises(ValueError, match="time_budget"):
        _cfg(tiny_dataset, tmp_path / "u", time_budget=0.0)
