"""Training on synthetic samples: AdamW, gradient clipping, NaN/Inf guards, exact resume.

One step = one batch of rendered samples (:class:`network.data.SampleDataset`), the model decodes
``train_pixels`` random masked pixels per image, and :func:`network.losses.synthetic_loss`
compares them with the ground truth gathered at the same pixels. A checkpoint holds the model
and optimizer state dicts, the model config as a plain dict, the step, the loss history and the
torch RNG state (pixel sampling) and data order, so a resumed run continues the same loss curve
(on the CPU). Logs go to ``log.csv`` (one row per step) and, when available, TensorBoard.
"""

from __future__ import annotations

import csv
import logging
import math
import random
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from pbrdf.atomic import temporary_path

from .config import ModelConfig, get_config
from .data import TARGET_KEYS, SampleDataset
from .losses import LossWeights, synthetic_loss
from .model import PolarInverseModel

__all__ = ["TrainConfig", "train", "gather_pixels", "load_checkpoint"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainConfig:
    """Flags of ``headless/train.py``."""

    data: Path
    out: Path
    config: str = "toy"
    steps: int = 100
    batch_size: int = 1
    lr: float = 8e-5
    weight_decay: float = 0.05
    clip: float = 1.0
    seed: int = 0
    resume: bool = False
    checkpoint_every: int = 50
    weights: LossWeights = field(default_factory=LossWeights)
    overrides: dict = field(default_factory=dict)


def gather_pixels(maps: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """``(B, C, H, W)`` maps at flat pixel indices ``(B, P)`` -> ``(B, C, P)``."""
    b, c = maps.shape[:2]
    return maps.reshape(b, c, -1).gather(2, pixels[:, None, :].expand(-1, c, -1))


def _batch(ds: SampleDataset, order: list[int], step: int, size: int) -> dict[str, torch.Tensor]:
    items = [ds[order[(step * size + j) % len(order)]] for j in range(size)]
    return {k: torch.stack([it[k] for it in items]) for k in items[0]}


def _save(path: Path, state: dict) -> None:
    tmp = temporary_path(path)
    torch.save(state, tmp)
    tmp.replace(path)


def load_checkpoint(path: str | Path) -> tuple[PolarInverseModel, dict]:
    """Model (eval mode) and the raw checkpoint dict from a file written by :func:`train`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, weights_only=True, map_location="cpu")
        model = PolarInverseModel(ModelConfig.from_dict(ckpt["config"]))
        model.load_state_dict(ckpt["model"])
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a model checkpoint: {exc}") from None
    model.eval()
    return model, ckpt


def train(cfg: TrainConfig, *, progress: bool = True) -> list[float]:
    """Train (or resume) and return the loss per step of the whole run."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / "checkpoint.pt"
    model_cfg = get_config(cfg.config, **cfg.overrides)
    ds = SampleDataset(cfg.data, size=model_cfg.image_size)
    torch.manual_seed(cfg.seed)
    model = PolarInverseModel(model_cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, losses = 0, []
    order = list(range(len(ds)))
    random.Random(cfg.seed).shuffle(order)
    if cfg.resume and ckpt_path.is_file():
        ckpt = torch.load(ckpt_path, weights_only=True, map_location="cpu")
        if ckpt["config"] != model_cfg.to_dict():
            raise ValueError(f"{ckpt_path}: checkpoint config differs from --config {cfg.config}")
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        start, losses, order = ckpt["step"], list(ckpt["losses"]), list(ckpt["order"])
        torch.set_rng_state(ckpt["torch_rng"])
    elif ckpt_path.exists() and not cfg.resume:
        raise FileExistsError(f"{ckpt_path}: exists; pass --resume to continue or choose another --out")
    log_path = out / "log.csv"
    new_log = not (cfg.resume and log_path.is_file())
    if new_log:
        log_path.write_text("step,loss,seconds," + ",".join(TARGET_KEYS) + ",chromaticity\n")
    else:  # drop rows after the checkpoint (a kill between checkpoint and log)
        rows = log_path.read_text().splitlines()
        log_path.write_text("\n".join(rows[: start + 1]) + "\n")
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=cfg.steps, initial=start, desc=f"train {cfg.config}", unit="step")
    model.train()
    skipped = 0
    with open(log_path, "a", newline="") as f:
        writer = csv.writer(f)
        for step in range(start, cfg.steps):
            t0 = time.perf_counter()
            batch = _batch(ds, order, step, cfg.batch_size)
            pred = model(batch["maps"], batch["mask"])
            pixels, valid = pred["pixels"], pred["valid"][:, None].to(batch["maps"].dtype)
            target = {k: gather_pixels(batch[k], pixels) for k in TARGET_KEYS}
            loss, parts = synthetic_loss(pred, target, valid, cfg.weights)
            if not torch.isfinite(loss):
                skipped += 1
                log.warning("step %d: non-finite loss %s, step skipped (%d so far)", step, float(loss), skipped)
                opt.zero_grad(set_to_none=True)
                if skipped > 10:
                    raise FloatingPointError(f"{skipped} non-finite losses; stopping (last at step {step})")
                continue
            opt.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.clip)
            if not math.isfinite(float(grad_norm)):
                skipped += 1
                log.warning("step %d: non-finite gradient norm, step skipped", step)
                continue
            opt.step()
            losses.append(float(loss.detach()))
            writer.writerow([step, losses[-1], time.perf_counter() - t0, *[parts.get(k, "") for k in TARGET_KEYS],
                             parts.get("chromaticity", "")])  # fmt: skip
            f.flush()
            if bar is not None:
                bar.set_postfix(loss=f"{losses[-1]:.4f}")
                bar.update()
            if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == cfg.steps:
                _save(ckpt_path, {
                    "config": model_cfg.to_dict(), "model": model.state_dict(), "optimizer": opt.state_dict(),
                    "step": step + 1, "losses": losses, "order": order,
                    "torch_rng": torch.get_rng_state(),
                })  # fmt: skip
                _save(out / "model.pt", {"config": model_cfg.to_dict(), "model": model.state_dict()})
    if bar is not None:
        bar.close()
    return losses
