"""Output files of :func:`network.train.train`: ``log.csv``, ``val.csv``, TensorBoard, and their repair on resume.

The training loop needs them only at a few points (start, every step, every validation, resume), but
their formats and the repair of what a killed run left behind are what a long run resumes from:
kept here, apart from the loop, so that they change only on purpose. ``log.csv`` and ``val.csv`` are
truncated to the checkpoint atomically and always keep their header; ``model.pt`` and ``best.pt``
are rewritten from the checkpoint when a kill between two writes left them stale.
"""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from pbrdf.io.atomic import atomic_write_text

from .checkpoint import model_file_is_current, model_file_state, params_sha256, save_checkpoint
from .data import TARGET_KEYS

__all__ = [
    "LOG_COLUMNS",
    "OUT_FILES",
    "VAL_COLUMNS",
    "Logs",
    "plain_settings",
    "sync_best_file",
    "sync_model_file",
    "truncate_log",
    "val_rows",
]

log = logging.getLogger(__name__)

#: Columns of ``log.csv`` (one row per step; a skipped step has ``skipped`` = its reason).
LOG_COLUMNS = (
    "step",
    "loss",
    "synthetic",
    "real",
    "real_weight",
    "lr",
    "grad_norm",
    "seconds",
    *TARGET_KEYS,
    "chromaticity",
    "skipped",
)

#: Columns of ``val.csv`` (one row per validation; ``step`` counts completed steps).
VAL_COLUMNS = ("step", "normal_mae_deg", "samples")

#: The files of ``out`` a run writes (atomically: a killed run may leave their temporaries).
OUT_FILES = ("checkpoint.pt", "model.pt", "best.pt", "log.csv", "val.csv")


class Logs:
    """``log.csv``, ``val.csv`` and TensorBoard; only rank 0 writes."""

    def __init__(self, out: Path, start: int, resume: bool, enabled: bool, tensorboard: bool) -> None:
        self.enabled = enabled
        self.tb = None
        self.file = None
        if not enabled:
            return
        self.path = out / "log.csv"
        self.val_path = out / "val.csv"
        if resume and self.path.is_file():
            truncate_log(self.path, start, LOG_COLUMNS)
        else:
            atomic_write_text(self.path, ",".join(LOG_COLUMNS) + "\n")
        if resume and self.val_path.is_file():
            truncate_log(self.val_path, start + 1, VAL_COLUMNS)  # val rows are numbered by completed steps
        elif self.val_path.is_file():
            self.val_path.unlink()
        self.file = open(self.path, "a", newline="")  # closed in close()
        self.writer = csv.writer(self.file)
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter  # noqa: PLC0415

                self.tb = SummaryWriter(log_dir=str(out / "tb"), purge_step=start if resume else None)
            except ImportError as exc:
                warnings.warn(f"TensorBoard logging off ({exc}); `pip install tensorboard` to enable it", stacklevel=3)

    def step(self, row: dict[str, Any], scalars: dict[str, float]) -> None:
        """Append one row to ``log.csv`` (None fields empty) and the scalars to TensorBoard."""
        if not self.enabled:
            return
        self.writer.writerow(["" if row.get(k) is None else row[k] for k in LOG_COLUMNS])
        self.file.flush()
        if self.tb is not None:
            for k, v in scalars.items():
                self.tb.add_scalar(k, v, row["step"])

    def val(self, step: int, mae: float, count: int) -> None:
        """Append one validation to ``val.csv`` (its header first when the file is new) and TensorBoard."""
        if not self.enabled:
            return
        new = not self.val_path.is_file()
        with open(self.val_path, "a", newline="") as f:
            if new:
                f.write(",".join(VAL_COLUMNS) + "\n")
            csv.writer(f).writerow([step, mae, count])
        if self.tb is not None:
            self.tb.add_scalar("val/normal_mae_deg", mae, step)

    def close(self) -> None:
        """Close ``log.csv`` and the TensorBoard writer."""
        if self.file is not None:
            self.file.close()
        if self.tb is not None:
            self.tb.close()


def truncate_log(path: Path, start: int, columns: tuple[str, ...]) -> None:
    """Keep the rows of steps < ``start`` under a fresh header; replace ``path`` atomically.

    Rows of later steps (written after the checkpoint by a killed run), a cut-off last row, the old
    header and anything else that is not a row of ``len(columns)`` fields with an integer step are
    dropped, so an emptied or half-written log resumes with its header and whole rows only.
    """
    rows = []
    for fields in csv.reader(path.read_text(errors="replace").splitlines()):
        if len(fields) == len(columns) and fields[0].isdigit() and int(fields[0]) < start:
            rows.append(fields)
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(columns)
    writer.writerows(rows)
    atomic_write_text(path, buf.getvalue())


def sync_model_file(path: Path, ckpt: dict | None) -> None:
    """(Re)write ``model.pt`` from ``ckpt`` unless it already holds that checkpoint's step and parameters."""
    if ckpt is None:
        return
    sha = params_sha256(ckpt["model"])
    if model_file_is_current(path, int(ckpt["step"]), sha):
        return
    log.warning("%s: missing or older than the checkpoint (step %d); rewritten from it", path, int(ckpt["step"]))
    save_checkpoint(path, model_file_state(ckpt, sha))


def val_rows(path: Path) -> list[tuple[int, float]]:
    """``(step, normal MAE)`` of the whole rows of ``val.csv`` (none when it is missing)."""
    if not path.is_file():
        return []
    rows = []
    for fields in csv.reader(path.read_text(errors="replace").splitlines()):
        if len(fields) == len(VAL_COLUMNS) and fields[0].isdigit():
            with contextlib.suppress(ValueError):
                rows.append((int(fields[0]), float(fields[1])))
    return rows


def sync_best_file(out: Path, ckpt: dict) -> None:
    """Rewrite ``best.pt`` from the resumed checkpoint if its validation was the best and ``best.pt`` lacks it.

    A run killed between writing ``checkpoint.pt`` and ``best.pt`` leaves the best validation row
    in ``val.csv`` without its weights; the checkpoint holds them.
    """
    step = int(ckpt["step"])
    rows = [r for r in val_rows(out / "val.csv") if r[0] <= step]
    if not rows:
        return
    best_step, mae = min(rows, key=lambda r: (r[1], r[0]))
    if best_step != step:
        return
    path = out / "best.pt"
    with contextlib.suppress(Exception):
        stored = torch.load(path, weights_only=True, map_location="cpu", mmap=True)
        if isinstance(stored, dict) and stored.get("step") == step:
            return
    log.warning("%s: missing the best validation (step %d); rewritten from the checkpoint", path, step)
    save_checkpoint(path, {**model_file_state(ckpt), "val_normal_mae_deg": mae})


def plain_settings(cfg: Any) -> dict[str, Any]:
    """A run's settings (a ``TrainConfig``) as plain values (for the record; ``weights_only`` loadable)."""
    out = asdict(cfg)
    for k, v in out.items():
        if isinstance(v, Path):
            out[k] = str(v)
        elif isinstance(v, tuple) and v and isinstance(v[0], Path):
            out[k] = [str(p) for p in v]
    return out
