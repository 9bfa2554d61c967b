"""Tests of network/train.py: overfitting and exact resume, the real pass, guards, bf16, input variants, validation.

Also the training CLI (headless/train.py), which is a thin layer over :func:`network.train.train`.
"""

import csv
import hashlib
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from network.checkpoint import load_checkpoint
from network.train import TrainConfig, train
from network.train_files import LOG_COLUMNS
from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.io import exr
from tests.helpers import toy_train_config

ROOT = Path(__file__).resolve().parents[2]


pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py


def _log(out):
    with open(out / "log.csv", newline="") as f:
        return list(csv.DictReader(f))


def _copy_with(src, dst, edit):
    """Copy a dataset, rewrite each sample's EXR channels with ``edit(index, channels)``; keep the sidecars valid."""
    shutil.copytree(src, dst)
    for idx in sorted(pdataset.completed_indices(dst)):
        paths = psample.sample_paths(dst, idx)
        channels = exr.read_exr(paths.exr)
        edit(idx, channels)
        exr.write_exr(paths.exr, channels, allow_nonfinite=True)
        meta = json.loads(paths.sidecar.read_text())
        meta["sha256"] = hashlib.sha256(paths.exr.read_bytes()).hexdigest()
        meta["exr_bytes"] = paths.exr.stat().st_size
        paths.sidecar.write_text(json.dumps(meta))
    return dst


# ------------------------------------------------------------------------------------------------
# settings, overfitting and exact resume


def test_config_rejects_bad_values(tmp_path):
    with pytest.raises(ValueError, match="steps must be a positive integer"):
        TrainConfig(data=tmp_path, out=tmp_path, steps=0)
    with pytest.raises(ValueError, match="unknown input variant 'rgb'"):
        TrainConfig(data=tmp_path, out=tmp_path, inputs="rgb")
    with pytest.raises(ValueError, match="real_weight"):
        TrainConfig(data=tmp_path, out=tmp_path, real_weight=-1.0)


@pytest.mark.mitsuba
def test_toy_model_overfits_and_resume_is_exact(tiny_dataset, tmp_path):
    # decay_steps fixes the cosine horizon, so the 20-step "killed" run has the 40-step run's schedule.
    common = {"data": tiny_dataset, "config": "toy", "lr": 1e-3, "seed": 0, "checkpoint_every": 10, "decay_steps": 40}
    full = train(TrainConfig(out=tmp_path / "a", steps=40, **common), progress=False)
    assert len(full) == 40 and np.all(np.isfinite(full))
    assert np.mean(full[-5:]) < 0.5 * np.mean(full[:5])  # overfits three samples
    # Stop after 20 steps ("killed"), resume to 40: the same loss curve, value for value.
    train(TrainConfig(out=tmp_path / "b", steps=20, **common), progress=False)
    resumed = train(TrainConfig(out=tmp_path / "b", steps=40, resume=True, **common), progress=False)
    np.testing.assert_allclose(resumed, full, rtol=1e-6, atol=1e-7)
    with pytest.raises(FileExistsError, match="pass resume=True"):
        train(TrainConfig(out=tmp_path / "b", steps=41, **common), progress=False)


# ------------------------------------------------------------------------------------------------
# the real pass


@pytest.mark.mitsuba
def test_real_pass_skipped_while_weight_is_zero(tiny_dataset, tmp_path):
    stats = {}
    # Rendered samples serve as "real" captures (their ground truth is ignored by RealDataset).
    cfg = toy_train_config(
        tiny_dataset, tmp_path / "r", steps=4, real=tiny_dataset, real_weight=0.1, real_start=2, real_warmup=2
    )
    losses = train(cfg, progress=False, stats=stats)
    assert len(losses) == 4
    # Weights 0, 0, 0 (ramp start), 0.05: one real batch loaded, one real pass, at the last step only.
    assert stats["real_batches"] == 1 and stats["real_passes"] == 1 and stats["synthetic_batches"] == 4
    rows = _log(tmp_path / "r")
    assert [float(r["real_weight"]) for r in rows] == [0.0, 0.0, 0.0, 0.05]
    assert [r["real"] for r in rows[:3]] == ["", "", ""]
    real = float(rows[3]["real"])
    assert math.isfinite(real) and real > 0
    # The total is the synthetic loss plus the weighted real loss.
    assert float(rows[3]["loss"]) == pytest.approx(float(rows[3]["synthetic"]) + 0.05 * real, rel=1e-6)
    for r in rows[:3]:
        assert float(r["loss"]) == float(r["synthetic"])


@pytest.mark.mitsuba
def test_resume_with_real_loader_is_exact(tiny_dataset, tmp_path):
    kw = {"real": tiny_dataset, "real_weight": 0.1, "real_start": 1, "real_warmup": 2, "decay_steps": 6}
    full = train(toy_train_config(tiny_dataset, tmp_path / "a", steps=6, checkpoint_every=3, **kw), progress=False)
    train(
        toy_train_config(tiny_dataset, tmp_path / "b", steps=3, checkpoint_every=3, **kw), progress=False
    )  # "killed" at 3
    stats = {}
    resumed = train(
        toy_train_config(tiny_dataset, tmp_path / "b", steps=6, resume=True, **kw), progress=False, stats=stats
    )
    assert stats["steps"] == 3 and stats["real_passes"] == 3  # steps 3..5 all have weight > 0
    # Bit for bit on the CPU: same data order of both loaders, same pixels, same weights and optimizer state.
    assert resumed == full
    a, b = _log(tmp_path / "a"), _log(tmp_path / "b")
    assert [r["loss"] for r in a] == [r["loss"] for r in b] and [r["real"] for r in a] == [r["real"] for r in b]


# ------------------------------------------------------------------------------------------------
# guards and precision


@pytest.mark.mitsuba
def test_nan_inputs_are_reported_skipped_and_stop_the_run(tiny_dataset, tmp_path, caplog):
    def poison(idx, ch):
        if idx == 1:
            ch["maps.G_unpol"][10, 10] = np.nan

    bad = _copy_with(tiny_dataset, tmp_path / "nan", poison)
    caplog.set_level(logging.WARNING, logger="network.train")
    stats = {}
    losses = train(toy_train_config(bad, tmp_path / "o", steps=6), progress=False, stats=stats)
    # Every epoch of 3 steps draws each of the 3 samples once: the poisoned one is skipped once per epoch.
    rows = _log(tmp_path / "o")
    skipped = [int(r["step"]) for r in rows if r["skipped"]]
    assert stats["skipped"] == 2 and len(losses) == 4 and np.all(np.isfinite(losses))
    assert len(skipped) == 2 and 0 <= skipped[0] < 3 <= skipped[1] < 6
    ckpt = torch.load(tmp_path / "o" / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 6 and ckpt["skipped"] == 2 and len(ckpt["losses"]) == 4
    messages = [r.getMessage() for r in caplog.records if "skipped" in r.getMessage()]
    assert len(messages) == 2
    for step, msg in zip(skipped, messages, strict=True):
        assert msg.startswith(f"step {step}: non-finite input (synthetic maps")
    # Too many: a clear error naming the limit.
    with pytest.raises(FloatingPointError, match="more than max_skipped=1"):
        train(toy_train_config(bad, tmp_path / "o2", steps=6, max_skipped=1), progress=False)


@pytest.mark.mitsuba
def test_bf16_autocast_runs_on_cpu(tiny_dataset, tmp_path):
    fp32 = train(toy_train_config(tiny_dataset, tmp_path / "f", steps=2), progress=False)
    bf16 = train(
        toy_train_config(tiny_dataset, tmp_path / "h", steps=2, bf16=True), progress=True
    )  # with the progress bar
    assert np.all(np.isfinite(bf16))
    # Same weights and pixels at step 0: bf16 rounding (8-bit mantissa) moves the loss a little, not a lot.
    assert bf16[0] != fp32[0]
    assert bf16[0] == pytest.approx(fp32[0], rel=0.05)


# ------------------------------------------------------------------------------------------------
# input variants


@pytest.mark.mitsuba
def test_input_variant_is_applied_and_stored(tiny_dataset, tmp_path):
    from network.data import SampleDataset
    from network.inputs import apply_inputs

    cp_names = psample.CHANNELS["maps"][6:]

    def scramble_cp(idx, ch):
        rng = np.random.default_rng(idx)
        for name in cp_names:
            ch[name] = rng.uniform(-1, 1, ch[name].shape).astype(np.float32)

    other = _copy_with(tiny_dataset, tmp_path / "cp", scramble_cp)
    runs = {}
    for variant in ("polar", "full"):
        for name, data in (("a", tiny_dataset), ("b", other)):
            runs[variant, name] = train(
                toy_train_config(data, tmp_path / f"{variant}_{name}", steps=3, inputs=variant), progress=False
            )
    # 'polar' never sees CP: random CP maps change nothing, bit for bit; 'full' sees them.
    assert runs["polar", "a"] == runs["polar", "b"]
    assert runs["full", "a"] != runs["full", "b"]
    ma, ca = load_checkpoint(tmp_path / "polar_a" / "model.pt")
    mb, cb = load_checkpoint(tmp_path / "polar_b" / "checkpoint.pt")
    assert ca["inputs"] == cb["inputs"] == "polar"
    for k, v in ma.state_dict().items():
        assert torch.equal(v, mb.state_dict()[k]), k
    # The stored variant applied at inference: the model's output ignores CP.
    item = SampleDataset(tiny_dataset, size=64)[0]
    maps, mask = item["maps"][None], item["mask"][None]
    maps2 = maps.clone()
    maps2[:, 6:] = torch.rand_like(maps2[:, 6:]) * 2 - 1
    with torch.no_grad():
        p1, p2 = ma(apply_inputs(maps, ca["inputs"]), mask), ma(apply_inputs(maps2, ca["inputs"]), mask)
    torch.testing.assert_close(p1["normal"], p2["normal"], rtol=0, atol=0)
    # A checkpoint from before input variants (no "inputs" key) means 'full'.
    old = torch.load(tmp_path / "full_a" / "model.pt", weights_only=True)
    del old["inputs"]
    torch.save(old, tmp_path / "old.pt")
    assert load_checkpoint(tmp_path / "old.pt")[1]["inputs"] == "full"
    # Resuming with another variant is refused.
    with pytest.raises(ValueError, match="inputs='polar', not 'full'"):
        train(toy_train_config(tiny_dataset, tmp_path / "polar_a", steps=4, resume=True, inputs="full"), progress=False)


# ------------------------------------------------------------------------------------------------
# validation, TensorBoard, the CLI


@pytest.mark.mitsuba
def test_validation_mae_and_tensorboard(tiny_dataset, tmp_path):
    pytest.importorskip("tensorboard")
    from network.data import SampleDataset

    out = tmp_path / "v"
    train(toy_train_config(tiny_dataset, out, steps=2, val=tiny_dataset, val_every=2, val_samples=2, tensorboard=True),
          progress=False)  # fmt: skip
    rows = list(csv.DictReader(open(out / "val.csv")))
    assert [int(r["step"]) for r in rows] == [2] and int(rows[0]["samples"]) == 2
    # Independent recomputation from model.pt: angle between unit normals over the mask, in degrees.
    model, _ = load_checkpoint(out / "model.pt")
    ds, errs = SampleDataset(tiny_dataset, size=64, input_scale="calibrated"), []  # the training default
    for i in range(2):
        it = ds[i]
        with torch.no_grad():
            n = model(it["maps"][None], it["mask"][None])["normal"][0].double()
        m = it["mask"][0] > 0
        p, g = n[:, m], it["normal"].double()[:, m]
        cos = (p * g).sum(0) / (p.norm(dim=0) * g.norm(dim=0))
        errs.append(torch.rad2deg(torch.acos(cos.clamp(-1, 1))).mean().item())
    assert float(rows[0]["normal_mae_deg"]) == pytest.approx(np.mean(errs), rel=1e-4)
    assert list((out / "tb").glob("events.out.tfevents.*"))


@pytest.mark.mitsuba
def test_runs_without_tensorboard_with_one_warning(tiny_dataset, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # as if tensorboard were not installed
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        losses = train(toy_train_config(tiny_dataset, tmp_path / "o", steps=2, tensorboard=True), progress=False)
    assert len(losses) == 2
    msgs = [str(w.message) for w in caught if "TensorBoard" in str(w.message)]
    assert len(msgs) == 1 and "pip install tensorboard" in msgs[0]
    assert not (tmp_path / "o" / "tb").exists()


def _cli(*args, timeout=120):
    cmd = [sys.executable, "headless/train.py", *map(str, args)]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})  # fmt: skip


@pytest.mark.mitsuba
def test_cli_help_and_one_line_errors(tiny_dataset, tmp_path, capsys):
    from headless.train import main

    h = _cli("--help")  # the script runs standalone
    assert h.returncode == 0
    for flag in ("--real", "--real-weight", "--real-warmup", "--inputs", "--bf16", "--device", "--overrides", "--val"):
        assert flag in h.stdout
    r = _cli("--out", tmp_path / "x")
    assert r.returncode == 2
    assert r.stderr.strip() == "error: the following arguments are required: --input (see train.py --help)"
    for args, match in (
        (["--input", tiny_dataset, "--out", tmp_path / "x", "--inputs", "rgb"], "argument --inputs: invalid choice"),
        (["--input", tiny_dataset, "--out", tmp_path / "x", "--steps", "0"], "steps must be a positive integer"),
        (["--input", tmp_path / "missing", "--out", tmp_path / "x"], "dataset folder not found"),
        (["--input", tiny_dataset, "--out", tmp_path / "x", "--overrides", "image_size"], "expected key=value"),
        (["--input", tiny_dataset, "--out", tmp_path / "x", "--overrides", "bogus=1"], "Unknown ModelConfig keys"),
    ):
        try:
            code = main([*map(str, args), "--quiet", "--no-tensorboard"])
        except SystemExit as exc:  # argparse errors
            code = exc.code
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert code == 2, (args, err)
        assert len(lines) == 1 and lines[0].startswith("error:") and match in lines[0], err


@pytest.mark.mitsuba
def test_cli_overrides_are_stored(tiny_dataset, tmp_path):
    from headless.train import main

    out = tmp_path / "o"
    args = ["--input", tiny_dataset, "--out", out, "--steps", "1", "--quiet", "--device", "cpu", "--no-tensorboard"]
    assert main([*map(str, args), "--overrides", "image_size=32", "train_pixels=16", "--inputs", "spectral"]) == 0
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["config"]["image_size"] == 32 and ckpt["config"]["train_pixels"] == 16
    assert ckpt["inputs"] == "spectral"
    model, meta = load_checkpoint(out / "model.pt")
    assert model.config.image_size == 32 and meta["inputs"] == "spectral"


@pytest.mark.parametrize(("role", "where"), [("test-procedural", "data"), ("test-meshes", "val"), ("val", "data")])
def test_training_and_selection_refuse_other_splits(tiny_dataset, tmp_path, role, where):
    labelled = tmp_path / role
    shutil.copytree(tiny_dataset, labelled)
    manifest = json.loads((labelled / "manifest.json").read_text())
    (labelled / "manifest.json").write_text(json.dumps({**manifest, "split": role}))
    kw = {"data": labelled} if where == "data" else {"data": tiny_dataset, "val": labelled}
    cfg = TrainConfig(out=tmp_path / "o", config="toy", steps=1, device="cpu", tensorboard=False, **kw)
    with pytest.raises(ValueError, match=f"split '{role}'; .* may read only"):
        train(cfg, progress=False)
    assert not (tmp_path / "o" / "model.pt").exists()


# ------------------------------------------------------------------------------------------------
# files of a killed run: model.pt, temporaries, logs

DEAD_PID = 999_999_999  # above any pid_max: the pid of a killed run that no process can have


def _plant_leftovers(out):
    names = [f".{n}.tmp-{DEAD_PID}-0a1b2c3d" for n in ("checkpoint.pt", "model.pt", "log.csv", "val.csv")]
    for name in names:
        (out / name).write_bytes(b"half-written")
    (out / "notes.txt").write_text("mine")  # user files stay
    (out / f".notes.txt.tmp-{DEAD_PID}-0a1b2c3d").write_text("not a file of the run")
    return names


@pytest.mark.mitsuba
def test_resume_at_the_final_step_repairs_a_stale_model_file(tiny_dataset, tmp_path, capsys):
    """Killed between checkpoint.pt (step 4) and model.pt (still step 2) at the final save; --resume repairs it."""
    from headless.train import main

    out = tmp_path / "o"
    args = ["--input", tiny_dataset, "--out", out, "--checkpoint-every", "2", "--quiet", "--device", "cpu",
            "--no-tensorboard", "--overrides", "image_size=32", "train_pixels=16"]  # fmt: skip
    assert main([*map(str, args), "--steps", "2"]) == 0
    step2 = (out / "model.pt").read_bytes()
    assert main([*map(str, args), "--steps", "4", "--resume"]) == 0
    # The kill: model.pt back at step 2 (and without the step/hash keys of older files), temporaries left over.
    stale = torch.load(out / "model.pt", weights_only=True)
    (out / "model.pt").write_bytes(step2)
    leftovers = _plant_leftovers(out)
    capsys.readouterr()
    assert main([*map(str, args), "--steps", "4", "--resume"]) == 0
    assert f"model: {out / 'model.pt'}" in capsys.readouterr().out
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    model = torch.load(out / "model.pt", weights_only=True)
    assert ckpt["step"] == 4
    for k, v in ckpt["model"].items():  # the step-4 weights, not those of step 2
        assert torch.equal(model["model"][k], v), k
    assert model["step"] == 4 and model["params_sha256"] == ckpt["rank_params_sha256"][0] == stale["params_sha256"]
    assert load_checkpoint(out / "model.pt")[1]["inputs"] == "full"
    # Leftovers of the run's own files are gone; nothing else was touched.
    assert not any((out / n).exists() for n in leftovers)
    assert (out / "notes.txt").read_text() == "mine" and (out / f".notes.txt.tmp-{DEAD_PID}-0a1b2c3d").exists()
    # A missing model.pt is written too; a current one is left alone (same bytes, same mtime).
    (out / "model.pt").unlink()
    assert main([*map(str, args), "--steps", "4", "--resume"]) == 0
    assert torch.load(out / "model.pt", weights_only=True)["params_sha256"] == ckpt["rank_params_sha256"][0]
    before = (out / "model.pt").stat().st_mtime_ns
    assert main([*map(str, args), "--steps", "4", "--resume"]) == 0
    assert (out / "model.pt").stat().st_mtime_ns == before


@pytest.mark.mitsuba
def test_a_fresh_run_removes_leftovers_of_a_killed_first_save(tiny_dataset, tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    leftovers = _plant_leftovers(out)
    train(
        toy_train_config(tiny_dataset, out, steps=1, overrides={"image_size": 32, "train_pixels": 16}), progress=False
    )
    assert not any((out / n).exists() for n in leftovers)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["checkpoint.pt", "log.csv", "model.pt", "notes.txt", f".notes.txt.tmp-{DEAD_PID}-0a1b2c3d"]
    )


@pytest.mark.mitsuba
def test_resume_of_an_emptied_log_writes_its_header(tiny_dataset, tmp_path):
    out = tmp_path / "o"
    kw = {"checkpoint_every": 1, "overrides": {"image_size": 32, "train_pixels": 16}}
    train(toy_train_config(tiny_dataset, out, steps=1, **kw), progress=False)
    (out / "log.csv").write_text("")  # killed while an in-place rewrite had emptied it
    train(toy_train_config(tiny_dataset, out, steps=2, resume=True, **kw), progress=False)
    with open(out / "log.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(LOG_COLUMNS) and [r[0] for r in rows[1:]] == ["1"]


# ------------------------------------------------------------------------------------------------
# input scale, chunks, selection on validation


@pytest.mark.mitsuba
def test_input_scale_is_stored_and_checked_on_resume(tiny_dataset, tmp_path):
    out = tmp_path / "s"
    train(toy_train_config(tiny_dataset, out, steps=2, checkpoint_every=2), progress=False)
    _, ckpt = load_checkpoint(out / "model.pt")
    assert ckpt["input_scale"] == "calibrated"
    with pytest.raises(ValueError, match="input_scale='calibrated', not 'exposure-invariant'"):
        train(
            toy_train_config(tiny_dataset, out, steps=4, resume=True, input_scale="exposure-invariant"), progress=False
        )
    with pytest.raises(ValueError, match="unknown input scale"):
        toy_train_config(tiny_dataset, out, input_scale="absolute")


@pytest.mark.mitsuba
def test_stop_after_is_one_chunk_of_the_same_run(tiny_dataset, tmp_path):
    """A run trained in chunks (--stop-after, then --resume) follows the uninterrupted run exactly."""
    full = train(toy_train_config(tiny_dataset, tmp_path / "full", steps=8), progress=False)
    first = train(toy_train_config(tiny_dataset, tmp_path / "chunks", steps=8, stop_after=3), progress=False)
    assert len(first) == 3
    assert torch.load(tmp_path / "chunks" / "checkpoint.pt", weights_only=True)["step"] == 3  # saved at the stop
    rest = train(
        toy_train_config(tiny_dataset, tmp_path / "chunks", steps=8, stop_after=6, resume=True), progress=False
    )
    rest = train(toy_train_config(tiny_dataset, tmp_path / "chunks", steps=8, resume=True), progress=False)
    np.testing.assert_allclose(rest, full, rtol=1e-6, atol=1e-7)
    assert [int(r["step"]) for r in _log(tmp_path / "chunks")] == list(range(8))


@pytest.mark.mitsuba
def test_best_checkpoint_is_selected_on_validation_and_repaired_on_resume(tiny_dataset, tmp_path, caplog):
    out = tmp_path / "b"
    cfg = {"steps": 6, "checkpoint_every": 2, "val": tiny_dataset, "val_samples": 2}
    train(toy_train_config(tiny_dataset, out, **cfg), progress=False)
    rows = [(int(r["step"]), float(r["normal_mae_deg"])) for r in csv.DictReader(open(out / "val.csv"))]
    assert [s for s, _ in rows] == [2, 4, 6]
    step, mae = min(rows, key=lambda r: r[1])
    best = torch.load(out / "best.pt", weights_only=True)
    assert best["step"] == step and best["val_normal_mae_deg"] == pytest.approx(mae, rel=1e-12)
    # best.pt loads like model.pt and its weights reproduce the logged validation error.
    from network.data import SampleDataset
    from network.metrics import normal_mae_deg

    model, _ = load_checkpoint(out / "best.pt")
    ds, errs = SampleDataset(tiny_dataset, size=64, input_scale="calibrated"), []
    for i in range(2):
        it = ds[i]
        with torch.no_grad():
            n = model(it["maps"][None], it["mask"][None])["normal"][0].permute(1, 2, 0).numpy()
        errs.append(normal_mae_deg(n, it["normal"].permute(1, 2, 0).numpy(), it["mask"][0].numpy() > 0))
    assert np.mean(errs) == pytest.approx(mae, rel=1e-4)
    # Killed after checkpoint.pt of step 6 but before best.pt, with step 6 the best validation: resume repairs it.
    text = (out / "val.csv").read_text().splitlines()
    (out / "val.csv").write_text("\n".join([*text[:-1], "6,0.5,2"]) + "\n")
    (out / "best.pt").unlink()
    with caplog.at_level(logging.WARNING, logger="network.train"):
        train(toy_train_config(tiny_dataset, out, resume=True, **cfg), progress=False)
    best = torch.load(out / "best.pt", weights_only=True)
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert best["step"] == 6 and best["val_normal_mae_deg"] == 0.5 and "best.pt: missing the best" in caplog.text
    assert all(torch.equal(best["model"][k], v) for k, v in ckpt["model"].items())


@pytest.mark.mitsuba
def test_also_joins_more_training_data_and_refuses_a_test_split(tiny_dataset, tmp_path):
    """--also: the extra dataset's samples join --input's (the checkpoint records both); a test split is refused."""
    from headless.train import main

    args = ["--input", tiny_dataset, "--steps", "1", "--quiet", "--device", "cpu", "--no-tensorboard"]
    assert main([*map(str, args), "--out", str(tmp_path / "o"), "--also", str(tiny_dataset)]) == 0
    ckpt = torch.load(tmp_path / "o" / "checkpoint.pt", weights_only=True)
    assert ckpt["data"]["synthetic"] == 6 and ckpt["train"]["also"] == [str(tiny_dataset)]
    labelled = shutil.copytree(tiny_dataset, tmp_path / "t")
    manifest = json.loads((labelled / "manifest.json").read_text())
    (labelled / "manifest.json").write_text(json.dumps({**manifest, "split": "test-scenes"}))
    cfg = TrainConfig(data=tiny_dataset, also=(labelled,), out=tmp_path / "o2", steps=1, device="cpu",
                      tensorboard=False)  # fmt: skip
    with pytest.raises(ValueError, match="split 'test-scenes'; .* may read only"):
        train(cfg, progress=False)
