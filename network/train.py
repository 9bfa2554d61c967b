"""Training loop: synthetic (and real) batches, AdamW, schedules, guards, exact resume, DDP.

One step = one batch of rendered samples (:class:`network.data.SampleDataset`) and, with a real
folder (:class:`network.realdata.RealDataset`) and a real-loss weight above 0, one batch of real
captures. The model decodes ``train_pixels`` random masked pixels per image;
:func:`network.losses.synthetic_loss` compares them with the ground truth gathered at the same
pixels and :func:`network.losses.real_loss` with the re-rendered captures. The two passes run one
after the other (forward, backward, forward, backward, one optimizer step), so only one graph is
alive at a time; the real pass is skipped entirely (not even loaded) while its weight is 0.
An input variant (:func:`network.inputs.apply_inputs`) changes what the network sees, not what the
losses compare with (the real loss always uses the measured unpol and LP maps).

Determinism. The model is initialised from ``torch.manual_seed(seed)``. The learning rate, the
real-loss weight, the data order and the sampled pixels are pure functions of the step
(:mod:`network.schedules`), so resuming needs only the step; the checkpoint also keeps every rank's
torch RNG state (anything else random, e.g. in a loss), so a resumed run continues the same loss
curve exactly (on the CPU). Checkpoint files: :mod:`network.checkpoint`.

Mixed precision. With ``bf16`` the forward pass runs under ``torch.autocast(bfloat16)``; the model
returns float32, the losses are computed in float32 outside autocast and the backward pass runs
outside it (a backward inside bf16 autocast is a known NaN source).

Guards. A batch with NaN/Inf inputs is skipped before the forward pass; a non-finite loss or
gradient norm skips the optimizer step. Each skip is logged as a warning naming the step, and
more than ``max_skipped`` skips stop the run with :class:`FloatingPointError`.

Selection. With a validation set, ``best.pt`` (a ``model.pt`` with ``val_normal_mae_deg``) is the
checkpoint of lowest validation normal MAE among the checkpoints that had a validation (validate at
checkpoint steps, the default, for it to follow every one); test splits never enter it.

Files. ``checkpoint.pt`` and ``model.pt`` are written atomically (checkpoint first); ``model.pt``
records the step and parameter hash of the checkpoint it was cut from, and a resume that has no
steps left rewrites it from the checkpoint when it is missing or stale (a run killed between the two
writes), and ``best.pt`` likewise when the checkpoint's validation was the best. ``log.csv`` and
``val.csv`` are truncated to the checkpoint atomically and always keep their header (these files and
their repairs: :mod:`network.train_files`). Every run first removes the temporary files a killed run
left in ``out`` (:func:`pbrdf.io.atomic.remove_leftovers`, for the files named here only).

Distributed. Under ``torchrun`` (``WORLD_SIZE > 1``, :mod:`network.distributed`) the model is
wrapped in :class:`~torch.nn.parallel.DistributedDataParallel` (gradients averaged over ranks),
logged losses are averaged over ranks, only rank 0 writes the checkpoint, ``model.pt``,
``log.csv``, ``val.csv`` and TensorBoard (``OUT/tb``), and the others wait at a barrier. Every
checkpoint records a SHA-256 of each rank's parameters; different values stop the run. Resuming
restores every rank (weights, optimizer, its own RNG state).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, Dataset

from pbrdf.data.splits import require_role
from pbrdf.io.atomic import remove_leftovers

from .checkpoint import CHECKPOINT_FORMAT, load_checkpoint, model_file_state, params_sha256, save_checkpoint
from .config import get_config
from .data import INPUT_SCALES, TARGET_KEYS, SampleDataset, checkpoint_input_scale, gather_pixels
from .distributed import DistContext, init_distributed, resolve_device, rng_state, set_rng_state
from .inputs import INPUT_VARIANTS, apply_inputs, checkpoint_inputs
from .losses import LossWeights, synthetic_loss
from .metrics import normal_mae_deg
from .model.polar_model import PolarInverseModel
from .schedules import StepBatches, learning_rate, pixel_seed, real_loss_weight, sample_batch_pixels
from .train_files import LOG_COLUMNS, OUT_FILES, Logs, sync_best_file, sync_model_file, val_rows

__all__ = ["LOG_COLUMNS", "TrainConfig", "load_checkpoint", "train"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainConfig:
    """Flags of ``headless/train.py`` (schedules: :mod:`network.schedules`).

    Attributes:
        data: rendered dataset folder (``headless/render.py``).
        indices: train on these sample indices of ``data`` only (None: every completed sample).
        out: output folder (checkpoint, model, logs).
        config: model preset (``toy``, ``small``, ``paper``); ``overrides`` replace fields of it.
        steps: total optimizer steps of the run (a resumed run continues up to it).
        stop_after: end this invocation after that many completed steps (with a checkpoint), without
            changing the schedules, which still span ``steps``: one chunk of a long run (None: ``steps``).
        batch_size: samples per step and process (the global batch is ``batch_size * WORLD_SIZE``).
        lr, weight_decay: AdamW; ``warmup_steps``, ``decay_steps`` (None: ``steps``), ``min_lr_ratio``:
            the learning-rate schedule.
        clip: gradient-norm clipping threshold.
        real: folder of real captures (None: synthetic only); ``real_weight``, ``real_start``,
            ``real_warmup``: the real-loss weight schedule.
        inputs: input variant (:data:`network.inputs.INPUT_VARIANTS`), applied to every batch.
        input_scale: ``"calibrated"`` (absolute brightness, the display radiance from each
            sample's rig) or ``"exposure-invariant"`` (:mod:`network.data`).
        bf16: bf16 autocast for the forward pass (meant for CUDA; allowed on the CPU).
        device: ``"cpu"``, ``"cuda"`` or ``"auto"`` (CUDA when available).
        val: held-out rendered dataset; normal MAE every ``val_every`` steps (0: at checkpoints)
            on its first ``val_samples`` samples.
        max_skipped: more skipped steps than this stop the run.
        workers: data-loading worker processes per loader.
        tensorboard: write TensorBoard events to ``OUT/tb`` (when tensorboard is installed).
    """

    data: Path
    out: Path
    indices: tuple[int, ...] | None = None
    config: str = "toy"
    steps: int = 100
    stop_after: int | None = None
    batch_size: int = 1
    lr: float = 8e-5
    weight_decay: float = 0.05
    warmup_steps: int = 0
    decay_steps: int | None = None
    min_lr_ratio: float = 0.1
    clip: float = 1.0
    seed: int = 0
    resume: bool = False
    checkpoint_every: int = 50
    weights: LossWeights = field(default_factory=LossWeights)
    overrides: dict = field(default_factory=dict)
    real: Path | None = None
    real_weight: float = 0.1
    real_start: int = 0
    real_warmup: int = 0
    inputs: str = "full"
    input_scale: str = "calibrated"
    bf16: bool = False
    device: str = "auto"
    val: Path | None = None
    val_every: int = 0
    val_samples: int = 8
    max_skipped: int = 10
    workers: int = 0
    tensorboard: bool = True

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "checkpoint_every", "val_samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a positive integer. Got {value!r}")
        for name in ("warmup_steps", "real_start", "real_warmup", "val_every", "max_skipped", "workers", "seed"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer. Got {value!r}")
        if self.indices is not None:
            object.__setattr__(self, "indices", tuple(int(i) for i in self.indices))
            if not self.indices or min(self.indices) < 0 or len(set(self.indices)) != len(self.indices):
                raise ValueError("indices must be a non-empty list of distinct sample indices >= 0")
        if self.stop_after is not None and (not isinstance(self.stop_after, int) or self.stop_after < 1):
            raise ValueError(f"stop_after must be a positive integer or None. Got {self.stop_after!r}")
        if self.decay_steps is not None and self.decay_steps < 1:
            raise ValueError(f"decay_steps must be a positive integer or None. Got {self.decay_steps!r}")
        for name in ("lr", "clip"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be a finite number > 0. Got {getattr(self, name)!r}")
        for name in ("weight_decay", "real_weight"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a finite number >= 0. Got {getattr(self, name)!r}")
        if not 0.0 <= self.min_lr_ratio <= 1.0:
            raise ValueError(f"min_lr_ratio must be in [0, 1]. Got {self.min_lr_ratio!r}")
        if self.inputs not in INPUT_VARIANTS:
            raise ValueError(f"unknown input variant {self.inputs!r}; choose one of {INPUT_VARIANTS}")
        if self.input_scale not in INPUT_SCALES:
            raise ValueError(f"unknown input scale {self.input_scale!r}; choose one of {INPUT_SCALES}")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ValueError(f"device must be 'cpu', 'cuda' or 'auto'. Got {self.device!r}")


# ------------------------------------------------------------------------------------------------
# Data


def _collate(items: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        k: torch.stack([it[k] for it in items]) if isinstance(items[0][k], torch.Tensor) else [it[k] for it in items]
        for k in items[0]
    }


def _loader(ds: Dataset, sampler: StepBatches, workers: int) -> Iterator[dict[str, Any]]:
    return iter(DataLoader(ds, batch_sampler=sampler, num_workers=workers, collate_fn=_collate))


def _nonfinite_keys(batch: dict[str, Any]) -> list[str]:
    return [
        k for k, v in batch.items() if isinstance(v, torch.Tensor) and v.is_floating_point() and not v.isfinite().all()
    ]


class _PixelModel(nn.Module):
    """Training forward at given pixels (what DDP wraps): encode, then decode the sampled pixels."""

    def __init__(self, model: PolarInverseModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, maps: torch.Tensor, mask: torch.Tensor, pixels: torch.Tensor, valid: torch.Tensor) -> dict:
        features = self.model.encode(maps, mask)
        return self.model.decode_pixels(features, maps, pixels, valid)


# ------------------------------------------------------------------------------------------------
# Validation


@torch.no_grad()
def _validate(model: PolarInverseModel, ds: SampleDataset, count: int, inputs: str, device: torch.device) -> float:
    """Mean normal MAE (degrees) of dense predictions over the first ``count`` samples."""
    was_training = model.training
    model.eval()
    errors = []
    for i in range(min(count, len(ds))):
        item = ds[i]
        maps = apply_inputs(item["maps"][None].to(device), inputs)
        pred = model(maps, item["mask"][None].to(device))
        mask = item["mask"][0].numpy() > 0
        normal = pred["normal"][0].float().permute(1, 2, 0).cpu().numpy()
        errors.append(normal_mae_deg(normal, item["normal"].permute(1, 2, 0).numpy(), mask))
    model.train(was_training)
    return float(sum(errors) / len(errors))


# ------------------------------------------------------------------------------------------------
# Training


def _real_modules() -> tuple[Any, Any]:
    try:
        from .losses import real_loss  # noqa: PLC0415
        from .realdata import RealDataset  # noqa: PLC0415
    except ImportError as exc:
        raise ValueError(f"real-data training needs network/realdata.py and network.losses.real_loss: {exc}") from None
    return RealDataset, real_loss


def train(cfg: TrainConfig, *, progress: bool = True, stats: dict | None = None) -> list[float]:
    """Train (or resume) and return the loss per completed step of the whole run (skipped steps excluded).

    Args:
        cfg: the run's settings.
        progress: show a progress bar (rank 0).
        stats: filled in place with counters of this call: ``steps`` (optimizer steps), ``skipped`` (steps
            skipped by the guards), ``synthetic_batches``, ``real_batches`` (real batches loaded),
            ``real_passes`` (real forward/backward passes), ``rank``, ``world_size``.

    Returns:
        The (rank-averaged) total loss of every completed step since step 0.

    Raises:
        FileExistsError: ``out`` has a checkpoint and ``resume`` is off.
        ValueError: bad settings, or a checkpoint that does not match them.
        FloatingPointError: more than ``max_skipped`` steps were skipped.
    """
    stats = {} if stats is None else stats
    stats.update(steps=0, skipped=0, synthetic_batches=0, real_batches=0, real_passes=0)
    device = resolve_device(cfg.device)
    dd, device = init_distributed(device)
    stats.update(rank=dd.rank, world_size=dd.world)
    try:
        return _train(cfg, progress, stats, dd, device)
    finally:
        if dd.owned and dist.is_initialized():
            dist.destroy_process_group()


def _train(cfg: TrainConfig, progress: bool, stats: dict, dd: DistContext, device: torch.device) -> list[float]:
    out = Path(cfg.out)
    ckpt_path = out / "checkpoint.pt"
    main = dd.rank == 0
    model_cfg = get_config(cfg.config, **cfg.overrides)
    # Test splits are read by the final evaluation only; selection reads val only.
    require_role(cfg.data, ("train",), "training")
    if cfg.val is not None:
        require_role(cfg.val, ("val",), "validation")
    if cfg.real is not None:
        require_role(cfg.real, ("train",), "training (real-data loss)")
    ds = SampleDataset(
        cfg.data, size=model_cfg.image_size, input_scale=cfg.input_scale,
        indices=list(cfg.indices) if cfg.indices is not None else None,
    )  # fmt: skip
    if cfg.indices is not None and len(ds) != len(cfg.indices):
        missing = sorted(set(cfg.indices) - set(ds.indices))
        raise ValueError(f"{cfg.data}: {len(missing)} of the requested indices are not completed samples "
                         f"(first: {missing[0]})")  # fmt: skip
    real_ds, real_loss = None, None
    if cfg.real is not None:
        real_dataset_cls, real_loss = _real_modules()
        real_ds = real_dataset_cls(cfg.real, size=model_cfg.image_size, input_scale=cfg.input_scale)
        if len(real_ds) == 0:
            raise ValueError(f"{cfg.real}: no real captures found")
    val_ds = None
    if cfg.val is not None:
        val_ds = SampleDataset(cfg.val, size=model_cfg.image_size, input_scale=cfg.input_scale)
    if device.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True

    torch.manual_seed(cfg.seed)  # identical initial weights on every rank
    model = PolarInverseModel(model_cfg).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    torch.manual_seed(cfg.seed + 1 + dd.rank)  # per-rank stream for anything random after init
    start, losses, skipped_total, ckpt = 0, [], 0, None
    if cfg.resume and ckpt_path.is_file():
        ckpt = torch.load(ckpt_path, weights_only=True, map_location="cpu")
        if ckpt["config"] != model_cfg.to_dict():
            raise ValueError(f"{ckpt_path}: checkpoint config differs from --config {cfg.config} (and --overrides)")
        if checkpoint_inputs(ckpt) != cfg.inputs:
            raise ValueError(
                f"{ckpt_path}: checkpoint was trained with --inputs {checkpoint_inputs(ckpt)}, not {cfg.inputs}"
            )
        if checkpoint_input_scale(ckpt) != cfg.input_scale:
            raise ValueError(
                f"{ckpt_path}: checkpoint was trained with --input-scale {checkpoint_input_scale(ckpt)}, "
                f"not {cfg.input_scale}"
            )
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        start, losses, skipped_total = int(ckpt["step"]), list(ckpt["losses"]), int(ckpt.get("skipped", 0))
        rngs = ckpt.get("rng")
        if rngs is not None and len(rngs) == dd.world:
            set_rng_state(rngs[dd.rank], device)
        elif "torch_rng" in ckpt and dd.world == 1:
            torch.set_rng_state(ckpt["torch_rng"])
        else:
            log.warning("%s: saved RNG states are for another number of processes; resume is not bitwise", ckpt_path)
        if "format" not in ckpt:
            log.warning("%s: written by an older version: its data order differs from this one's", ckpt_path)
        sizes = ckpt.get("data", {})
        for name, d in (("synthetic", ds), ("real", real_ds)):
            if d is not None and sizes.get(name) not in (None, len(d)):
                log.warning("%s: the %s data had %s samples, now %d: the data order changes", ckpt_path, name,
                            sizes.get(name), len(d))  # fmt: skip
    elif ckpt_path.exists() and not cfg.resume:
        raise FileExistsError(f"{ckpt_path}: exists; pass --resume to continue or choose another --out")
    starts = dd.gather(start)
    if len(set(starts)) != 1:
        raise ValueError(f"{ckpt_path}: ranks resume from different steps {starts}; every node must see the checkpoint")
    if main:
        out.mkdir(parents=True, exist_ok=True)
        removed = remove_leftovers(out, OUT_FILES)  # of a killed run (a live writer's stay)
        if removed:
            log.info("removed %d temporary file(s) of a killed run from %s", len(removed), out)
        if start >= cfg.steps:  # nothing left to train: model.pt must still be the checkpoint's
            sync_model_file(out / "model.pt", ckpt)
        if ckpt is not None and cfg.val is not None:
            sync_best_file(out, ckpt)
    best_mae = min((mae for step, mae in val_rows(out / "val.csv") if step <= start), default=math.inf)
    ckpt = None  # the loaded copy (optimizer state included) is not needed any more
    dd.barrier()
    logs = Logs(out, start, cfg.resume, main, cfg.tensorboard)

    net: nn.Module = _PixelModel(model)
    if dd.active:
        net = nn.parallel.DistributedDataParallel(net, device_ids=[device.index] if device.type == "cuda" else None)
    decay = cfg.decay_steps or cfg.steps
    stop = cfg.steps if cfg.stop_after is None else min(cfg.steps, cfg.stop_after)
    steps = list(range(start, stop))
    syn_sampler = StepBatches(len(ds), cfg.seed, "synthetic", steps, cfg.batch_size, dd.rank, dd.world)
    syn_batches = _loader(ds, syn_sampler, cfg.workers)
    real_sampler = real_batches = None
    if real_ds is not None:
        real_steps = [s for s in steps if real_loss_weight(s, cfg.real_weight, cfg.real_start, cfg.real_warmup) > 0]
        real_sampler = StepBatches(len(real_ds), cfg.seed, "real", real_steps, cfg.batch_size, dd.rank, dd.world)
        real_batches = _loader(real_ds, real_sampler, cfg.workers)

    def prepare(batch: dict, loader: str, step: int, sampler: StepBatches) -> tuple[dict, torch.Tensor, torch.Tensor]:
        seeds = [pixel_seed(cfg.seed, loader, step, p) for p in sampler.positions(step)]
        pixels, valid = sample_batch_pixels(batch["mask"], model_cfg.train_pixels, seeds)
        batch = {k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
        return batch, pixels.to(device), valid.to(device)

    def forward(batch: dict, pixels: torch.Tensor, valid: torch.Tensor) -> dict:
        with torch.autocast(device_type=device.type, dtype=torch.bfloat16, enabled=cfg.bf16):
            # The network sees the variant's maps; the losses keep the measured ones.
            pred = net(apply_inputs(batch["maps"], cfg.inputs), batch["mask"].to(batch["maps"].dtype), pixels, valid)
        return {k: v.float() for k, v in pred.items()}  # losses and backward in float32, outside autocast

    bar = None
    if progress and main:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=cfg.steps, initial=start, desc=f"train {cfg.config}", unit="step")
    model.train()

    def skip(step: int, reason: str, row: dict) -> None:
        nonlocal skipped_total
        skipped_total += 1
        stats["skipped"] += 1
        log.warning("step %d: %s; step skipped (%d skipped so far)", step, reason, skipped_total)
        opt.zero_grad(set_to_none=True)
        logs.step({**row, "skipped": reason.replace(",", ";")}, {})
        if skipped_total > cfg.max_skipped:
            raise FloatingPointError(
                f"{skipped_total} steps skipped for non-finite values (more than --max-skipped {cfg.max_skipped}); "
                f"stopping at step {step}: {reason}"
            )

    def run_step(step: int) -> None:
        """One optimizer step (or a reported skip)."""
        t0 = time.perf_counter()
        lr = learning_rate(step, cfg.lr, cfg.warmup_steps, decay, cfg.min_lr_ratio)
        for group in opt.param_groups:
            group["lr"] = lr
        w_real = real_loss_weight(step, cfg.real_weight, cfg.real_start, cfg.real_warmup) if real_ds else 0.0
        row: dict[str, Any] = {"step": step, "lr": lr, "real_weight": w_real}
        syn, pix, valid = prepare(next(syn_batches), "synthetic", step, syn_sampler)
        stats["synthetic_batches"] += 1
        real = None
        if w_real > 0:  # the real batch is loaded only when its pass runs
            real, rpix, rvalid = prepare(next(real_batches), "real", step, real_sampler)
            stats["real_batches"] += 1
        bad = [f"synthetic {k}" for k in _nonfinite_keys(syn)]
        bad += [f"real {k}" for k in _nonfinite_keys(real)] if real is not None else []
        if dd.any_true(bool(bad), device):  # every rank skips together
            skip(step, f"non-finite input ({', '.join(bad) or 'on another rank'})", row)
            return

        opt.zero_grad(set_to_none=True)
        pred = forward(syn, pix, valid)
        target = {k: gather_pixels(syn[k], pix) for k in TARGET_KEYS}
        loss_syn, parts = synthetic_loss(pred, target, valid[:, None].float(), cfg.weights)
        loss_syn.backward()
        del pred
        loss_real, real_parts = torch.zeros((), device=device), {}
        if real is not None:
            rpred = forward(real, rpix, rvalid)
            loss_real, real_parts = real_loss(rpred, real, rpix, rvalid[:, None].float())
            (w_real * loss_real).backward()  # gradients accumulate onto the synthetic ones
            stats["real_passes"] += 1
            del rpred
        # After DDP's all-reduce the gradients, hence their norm, are the same on every rank.
        grad_norm = float(torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.clip))
        mean_syn, mean_real = dd.mean([float(loss_syn.detach()), float(loss_real.detach())], device)
        total = mean_syn + w_real * mean_real
        row.update(loss=total, synthetic=mean_syn, real=mean_real if real is not None else None, grad_norm=grad_norm)
        if not (math.isfinite(total) and math.isfinite(grad_norm)):
            skip(step, f"non-finite loss {total} or gradient norm {grad_norm}", row)
            return
        opt.step()
        losses.append(total)
        stats["steps"] += 1
        row["seconds"] = time.perf_counter() - t0
        row.update({k: parts.get(k) for k in (*TARGET_KEYS, "chromaticity")})
        scalars = {"loss/total": total, "loss/synthetic": mean_syn, "lr": lr, "grad_norm": grad_norm}
        scalars.update({f"synthetic/{k}": v for k, v in parts.items()})
        if real is not None:
            scalars.update({"loss/real": mean_real, "real_weight": w_real})
            scalars.update({f"real/{k}": v for k, v in real_parts.items()})
        logs.step(row, scalars)
        if bar is not None:
            bar.set_postfix(loss=f"{total:.4f}")

    def save(done: int, val_mae: float | None) -> None:
        nonlocal best_mae
        state = model.state_dict()
        shas = dd.gather(params_sha256(state))
        rngs = dd.gather(rng_state(device))
        if len(set(shas)) != 1:
            raise RuntimeError(f"step {done}: ranks hold different parameters (sha256 {shas})")
        if main:
            record = {
                "format": CHECKPOINT_FORMAT, "config": model_cfg.to_dict(), "inputs": cfg.inputs,
                "input_scale": cfg.input_scale, "model": state,
                "optimizer": opt.state_dict(), "step": done, "losses": losses, "skipped": skipped_total, "rng": rngs,
                "rank_params_sha256": shas, "world_size": dd.world,
                "data": {"synthetic": len(ds), "real": len(real_ds) if real_ds is not None else None},
                "train": _plain(cfg),
            }  # fmt: skip
            save_checkpoint(ckpt_path, record)  # first: a kill before model.pt is repaired by the resume
            save_checkpoint(out / "model.pt", model_file_state(record, shas[0]))
            if val_mae is not None and val_mae < best_mae:  # after the checkpoint: see sync_best_file
                best_mae = val_mae
                save_checkpoint(out / "best.pt", {**model_file_state(record, shas[0]), "val_normal_mae_deg": val_mae})
        dd.barrier()

    try:
        for step in steps:
            run_step(step)
            if bar is not None:
                bar.update()
            done = step + 1
            mae = None
            if val_ds is not None and (done % (cfg.val_every or cfg.checkpoint_every) == 0 or done == cfg.steps):
                if main:
                    mae = _validate(model, val_ds, cfg.val_samples, cfg.inputs, device)
                    logs.val(done, mae, min(cfg.val_samples, len(val_ds)))
                dd.barrier()
            if done % cfg.checkpoint_every == 0 or done in (cfg.steps, stop):
                save(done, mae)
    finally:
        if bar is not None:
            bar.close()
        logs.close()
    return losses


def _plain(cfg: TrainConfig) -> dict[str, Any]:
    """The run's settings as plain values (for the record; ``weights_only`` loadable)."""
    out = asdict(cfg)
    for k, v in out.items():
        if isinstance(v, Path):
            out[k] = str(v)
    return out
