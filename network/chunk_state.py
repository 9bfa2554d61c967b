"""The committable state of a long run trained in chunks (a GPU lease or a CPU session each).

A full ``checkpoint.pt`` (float32 weights and AdamW moments) of ``small`` is about 47 MB and of
``medium`` about 220 MB: too big to commit after every chunk. Between chunks a run keeps a *chunk
state* folder instead (``runs/next/`` in the repository):

- ``state.pt``: the latest weights in bfloat16, as a ``model.pt`` dict (:data:`network.checkpoint.MODEL_KEYS`,
  ``step``, ``params_sha256`` of the bfloat16 tensors), loadable by :func:`network.checkpoint.load_checkpoint`;
- ``best.pt``: the weights of the best validation so far, likewise (when validated; a local file, not
  committed: git ignores it, so it does not travel to a lease either, see docs/gpu_lease.md);
- ``state.json``: ``step``, the ``best`` validation (step, normal MAE), the run's ``train`` settings
  (schedule, seed, batch, preset) and one row per chunk (its steps and its end's validation: a chunk
  stopped by ``time_budget`` ends validated, and git keeps each chunk's ``state.pt``, so selection can
  pick a chunk end);
- ``log.csv.gz``, ``val.csv``: the whole run's curves (:mod:`network.train_files`; the step log gzipped:
  about 170 bytes a step as text, and the folder travels to every lease).

:func:`seed_run` turns such a folder into a fresh run folder that ``headless/train.py --resume``
continues at ``step``: the weights (bfloat16 widened to float32), a fresh AdamW state, the RNG
seeded from ``(seed, step)``, and the curves. The learning-rate schedule depends on the step only
(:mod:`network.schedules`), so it goes on where it was; the zeroed Adam moments are what differs, and
the chunk re-warms the learning rate over a few steps (``--rewarm-from STEP --rewarm-steps N``) while
they settle. :func:`export_state` writes the folder back from the run after the chunk. A run folder
that already holds a ``checkpoint.pt`` at least as far on (a chunk killed on this machine, the CPU run
between its chunks) is left alone: it resumes exactly. ``RUN/seeded.json`` names the step a run was
seeded at (the re-warm's start).
"""

from __future__ import annotations

import gzip
import json
import shutil
import time
from pathlib import Path
from typing import Any

import torch

from pbrdf.io.atomic import atomic_open, atomic_write_text

from .checkpoint import CHECKPOINT_FORMAT, load_checkpoint, model_file_state, params_sha256, save_checkpoint
from .train_files import val_rows

__all__ = ["CURVE_FILES", "INFO_FILE", "SEEDED_FILE", "STATE_FILE", "export_state", "read_info", "seed_run", "to_bf16"]

#: The bfloat16 weights of the latest step, and the run's record (JSON).
STATE_FILE, INFO_FILE, BEST_FILE = "state.pt", "state.json", "best.pt"
#: The curves a chunk continues and writes back: run folder name -> chunk-state name (gzipped when it ends in .gz).
CURVE_FILES = {"log.csv": "log.csv.gz", "val.csv": "val.csv"}
#: Written into a seeded run folder: ``{"step": the step it was seeded at}``.
SEEDED_FILE = "seeded.json"
#: Version of ``state.json``.
STATE_FORMAT = 1


def to_bf16(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A state dict with every floating-point tensor in bfloat16 (others unchanged).

    Example:
        >>> to_bf16({"w": torch.ones(2), "n": torch.tensor([3])})["w"].dtype
        torch.bfloat16
    """
    return {k: v.detach().to(torch.bfloat16) if v.is_floating_point() else v for k, v in state.items()}


def read_info(state_dir: str | Path) -> dict[str, Any] | None:
    """``state.json`` of a chunk-state folder (None when the folder holds no state yet).

    Raises:
        ValueError: the file is unreadable or lacks ``step`` (the message names it).
    """
    path = Path(state_dir) / INFO_FILE
    if not path.is_file():
        return None
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: unreadable chunk state ({exc})") from None
    if not isinstance(info, dict) or not isinstance(info.get("step"), int):
        raise ValueError(f"{path}: not a chunk state (no integer step)")
    return info


def _copy(src: Path, dst: Path) -> None:
    """Copy a file, gzipping into a ``.gz`` destination and gunzipping from a ``.gz`` source (atomically)."""
    data = src.read_bytes()
    data = gzip.decompress(data) if src.suffix == ".gz" else data
    with atomic_open(dst) as f:
        f.write(gzip.compress(data, mtime=0) if dst.suffix == ".gz" else data)


def _bf16_model_file(src: Path, dst: Path) -> dict:
    """Write ``src`` (a ``checkpoint.pt``/``model.pt``/``best.pt``) to ``dst`` as a bfloat16 ``model.pt`` dict."""
    ckpt = torch.load(src, weights_only=True, map_location="cpu")
    state = model_file_state({**ckpt, "model": to_bf16(ckpt["model"])})
    if "val_normal_mae_deg" in ckpt:
        state["val_normal_mae_deg"] = ckpt["val_normal_mae_deg"]
    save_checkpoint(dst, state)
    return state


def export_state(
    run_dir: str | Path, state_dir: str | Path, chunk: dict[str, Any] | None = None, history: str | Path | None = None
) -> dict[str, Any]:
    """Write a run folder's latest checkpoint (and best, curves) into a chunk-state folder.

    Args:
        run_dir: a ``headless/train.py`` output folder with ``checkpoint.pt``.
        state_dir: the chunk-state folder (created; its files replaced).
        chunk: facts about this chunk for its row in ``state.json`` (device, seconds, ...); ``start``
            and ``end`` steps are filled in.
        history: the chunk-state folder whose ``state.json`` the new one extends (default ``state_dir``;
            a lease writes to ``$OUT`` and extends the committed ``runs/next``).

    Returns:
        The new ``state.json`` dict.

    Raises:
        ValueError: ``run_dir`` has no ``checkpoint.pt``.
    """
    run_dir, state_dir = Path(run_dir), Path(state_dir)
    ckpt_path = run_dir / "checkpoint.pt"
    if not ckpt_path.is_file():
        raise ValueError(f"{ckpt_path}: no checkpoint to export (did the chunk train?)")
    old = read_info(state_dir if history is None else history) or {"format": STATE_FORMAT, "chunks": []}
    state_dir.mkdir(parents=True, exist_ok=True)
    ckpt = torch.load(ckpt_path, weights_only=True, map_location="cpu", mmap=True)
    state = _bf16_model_file(ckpt_path, state_dir / STATE_FILE)
    best = run_dir / "best.pt"
    if best.is_file():
        _bf16_model_file(best, state_dir / BEST_FILE)
    for name, kept in CURVE_FILES.items():
        if (run_dir / name).is_file():
            _copy(run_dir / name, state_dir / kept)
    end = int(ckpt["step"])
    rows = val_rows(state_dir / "val.csv")
    row = {"start": int(old.get("step", 0)), "end": end, "val_normal_mae_deg": dict(rows).get(end),
           "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **(chunk or {})}  # fmt: skip
    best = min(rows, key=lambda r: (r[1], r[0]), default=None)
    info = {**old, "format": STATE_FORMAT, "step": end, "params_sha256": state["params_sha256"],
            "best": None if best is None else {"step": best[0], "val_normal_mae_deg": best[1]},
            "train": ckpt.get("train", {}), "chunks": [*old.get("chunks", []), row]}  # fmt: skip
    info["train"] = {k: v for k, v in info["train"].items() if k not in ("out", "data", "val", "real", "init_from")}
    atomic_write_text(state_dir / INFO_FILE, json.dumps(info, indent=1) + "\n")
    return info


def seed_run(state_dir: str | Path, run_dir: str | Path, *, seed: int, weight_decay: float) -> int:
    """Prepare ``run_dir`` so that ``headless/train.py --resume`` continues the chunk state's run.

    A ``run_dir`` that has a ``checkpoint.pt`` is kept (that run resumes exactly), and an empty
    chunk state leaves ``run_dir`` alone (the run starts at step 0, e.g. ``--init-from``).

    Args:
        state_dir: the chunk-state folder (:func:`export_state`).
        run_dir: the run folder of this chunk.
        seed: the run's ``--seed`` (the RNG of the chunk is seeded from it and the step).
        weight_decay: the run's AdamW ``--weight-decay`` (the fresh optimizer's parameter groups carry it).

    Returns:
        The step training continues from.

    Raises:
        ValueError: ``state.pt`` and ``state.json`` disagree (the message names the file).
    """
    state_dir, run_dir = Path(state_dir), Path(run_dir)
    info = read_info(state_dir)
    own = run_dir / "checkpoint.pt"
    if own.is_file():
        step = int(torch.load(own, weights_only=True, map_location="cpu", mmap=True)["step"])
        if info is None or step >= info["step"]:
            return step
        for name in ("checkpoint.pt", "model.pt"):  # the state is newer (another machine's chunk): start from it
            (run_dir / name).unlink(missing_ok=True)
    if info is None:
        return 0
    model, ckpt = load_checkpoint(state_dir / STATE_FILE)
    if int(ckpt["step"]) != info["step"] or ckpt.get("params_sha256") != info.get("params_sha256"):
        raise ValueError(f"{state_dir / STATE_FILE}: step {ckpt['step']} or weights differ from {INFO_FILE} "
                         f"(step {info['step']}): a partly copied chunk state")  # fmt: skip
    model = model.float()
    opt = torch.optim.AdamW(model.parameters(), lr=1.0, weight_decay=weight_decay)  # lr is set every step
    step = info["step"]
    rng = {"torch": torch.Generator().manual_seed(seed * 1_000_003 + step).get_state(), "cuda": None}
    weights = model.state_dict()
    record = {
        "format": CHECKPOINT_FORMAT, "config": ckpt["config"], "inputs": ckpt["inputs"],
        "input_scale": ckpt["input_scale"], "model": weights, "optimizer": opt.state_dict(), "step": step,
        "losses": [], "skipped": 0, "rng": [rng], "rank_params_sha256": [params_sha256(weights)], "world_size": 1,
        "data": {}, "train": {"seeded_from": str(state_dir)},
    }  # fmt: skip
    run_dir.mkdir(parents=True, exist_ok=True)
    for name, kept in CURVE_FILES.items():
        if (state_dir / kept).is_file():
            _copy(state_dir / kept, run_dir / name)
    if (state_dir / BEST_FILE).is_file():  # train.py writes best.pt only when validation beats val.csv's best
        shutil.copyfile(state_dir / BEST_FILE, run_dir / BEST_FILE)
    save_checkpoint(run_dir / "checkpoint.pt", record)
    atomic_write_text(run_dir / SEEDED_FILE, json.dumps({"step": step}) + "\n")  # the re-warm's start
    return step
