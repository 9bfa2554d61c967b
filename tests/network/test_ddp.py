"""Distributed training: 2 CPU processes on gloo equal 1 process with the global batch.

The equivalence test starts its 2 ranks by forking this process (same environment variables as
``torchrun``, same ``env://`` initialisation; no interpreter and torch start-up per rank, which
costs 5-15 s on a small shared machine); a slow-marked test runs the CLI under ``torchrun``.

Why the runs are comparable: the sample at global data position ``k`` and its pixels depend only
on the seed, the step and ``k`` (``network.train`` docs): step ``s`` of rank ``r`` with batch 1
takes position ``2 s + r``, the 1-process run with batch 2 takes positions ``2 s`` and ``2 s + 1``,
and every sample draws its pixels from a generator seeded with ``pixel_seed(seed, loader, s, k)``.
The losses average over pixels (synthetic) and images (real) with equal counts per image, so the
mean of the two ranks' gradients (DDP) equals the batch-2 gradient up to float rounding.
"""

import csv
import hashlib
import multiprocessing
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.distributed as dist

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")
if not dist.is_available() or not dist.is_gloo_available():
    pytest.skip("torch.distributed with gloo is not available", allow_module_level=True)

from network.train import TrainConfig, train  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def _has_real() -> bool:
    try:
        from network.losses import real_loss  # noqa: F401
        from network.realdata import RealDataset  # noqa: F401
    except ImportError:
        return False
    return True


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _worker(rank: int, world: int, port: int, cfg: TrainConfig) -> None:
    """One forked rank: the environment torchrun would set, then the library entry point."""
    code = 1
    try:
        os.environ.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(world), MASTER_ADDR="127.0.0.1",
                          MASTER_PORT=str(port))  # fmt: skip
        torch.set_num_threads(1)
        train(cfg, progress=False)
        code = 0
    finally:
        os._exit(code)  # skip the parent's atexit handlers (Mitsuba/Dr.Jit) in the child


def _fork_run(cfg: TrainConfig, world: int = 2) -> None:
    ctx = multiprocessing.get_context("fork")
    port = _free_port()
    procs = [ctx.Process(target=_worker, args=(r, world, port, cfg)) for r in range(world)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=300)
    assert [p.exitcode for p in procs] == [0] * world


def _torchrun(*args):
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", "headless/train.py"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([*cmd, *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _rows(out):
    with open(out / "log.csv", newline="") as f:
        return list(csv.DictReader(f))


def _sha256(state):
    """Independent of network.train: SHA-256 over names and raw bytes of every tensor, in file order."""
    h = hashlib.sha256()
    for k, v in state.items():
        h.update(k.encode())
        h.update(v.contiguous().view(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def test_two_processes_equal_one_process_with_the_global_batch_and_resume(tiny_dataset, tmp_path):
    # The real pass (a second forward/backward before the optimizer step) is included when it exists.
    real = _has_real()
    kw = {"real": tiny_dataset, "real_weight": 0.1, "real_start": 1} if real else {}
    base = {"data": tiny_dataset, "config": "toy", "lr": 1e-3, "decay_steps": 4, "seed": 3, "device": "cpu",
            "tensorboard": False, **kw}  # fmt: skip
    # 1 process x batch 2 first (it also imports what the forked ranks then inherit).
    torch.set_num_threads(1)
    ref_out = tmp_path / "ref"
    ref = train(TrainConfig(out=ref_out, steps=4, batch_size=2, **base), progress=False)
    # 2 processes x batch 1: "killed" after 2 steps, then resumed to 4.
    out = tmp_path / "ddp"
    _fork_run(TrainConfig(out=out, steps=2, checkpoint_every=2, batch_size=1, **base))
    _fork_run(TrainConfig(out=out, steps=4, checkpoint_every=2, batch_size=1, resume=True, **base))

    rows, ref_rows = _rows(out), _rows(ref_out)
    assert [int(r["step"]) for r in rows] == [0, 1, 2, 3]
    for key in ("loss", "synthetic", "grad_norm", *(["real"] if real else [])):
        got = [float(r[key]) for r in rows[1 if key == "real" else 0 :]]
        want = [float(r[key]) for r in ref_rows[1 if key == "real" else 0 :]]
        np.testing.assert_allclose(got, want, rtol=2e-5, err_msg=key)
    np.testing.assert_allclose([float(r["loss"]) for r in rows], ref, rtol=2e-5)
    if real:  # the real pass moved the weights (at initialisation it re-renders nothing: loss 1, no gradient)
        assert min(float(r["real"]) for r in rows[1:]) < 0.99

    # Both ranks hold the same parameters (bitwise), those saved in model.pt.
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    saved = torch.load(out / "model.pt", weights_only=True)["model"]
    assert ckpt["step"] == 4 and ckpt["world_size"] == 2
    assert ckpt["rank_params_sha256"] == [_sha256(saved)] * 2
    assert len(ckpt["rng"]) == 2 and not torch.equal(ckpt["rng"][0]["torch"], ckpt["rng"][1]["torch"])
    # ... and equal those of the 1-process run up to float rounding amplified by Adam over 4 steps
    # (measured 2e-5; one step of lr 1e-3 moves a weight by up to 1e-3).
    ref_state = torch.load(ref_out / "model.pt", weights_only=True)["model"]
    for k, v in ref_state.items():
        torch.testing.assert_close(saved[k], v, rtol=0, atol=1e-4, msg=k)


@pytest.mark.slow
def test_torchrun_cli(tiny_dataset, tmp_path):
    out = tmp_path / "o"
    proc = _torchrun("--input", tiny_dataset, "--out", out, "--steps", "2", "--checkpoint-every", "1", "--lr", "1e-3",
                     "--device", "cpu", "--quiet", "--no-tensorboard")  # fmt: skip
    # Only rank 0 reports and writes; both ranks end with the same parameters.
    assert proc.stdout.count("steps 2, loss first") == 1
    assert [int(r["step"]) for r in _rows(out)] == [0, 1]
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["world_size"] == 2 and ckpt["step"] == 2
    assert ckpt["rank_params_sha256"] == [_sha256(torch.load(out / "model.pt", weights_only=True)["model"])] * 2
