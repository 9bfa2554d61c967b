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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor, nn
from torch.utils.data import ConcatDataset, DataLoader, Dataset

from pbrdf.data.splits import require_role
from pbrdf.io.atomic import remove_leftovers

from .checkpoint import (
    CHECKPOINT_FORMAT,
    init_from_checkpoint,
    model_file_state,
    params_sha256,
    require_trained_with,
    save_checkpoint,
)
from .config import get_config
from .data import INPUT_SCALES, TARGET_KEYS, SampleDataset, checkpoint_input_scale, gather_pixels
from .distill import Teacher, check_distill, distill_loss
from .distributed import DistContext, init_distributed, resolve_device, rng_state, set_rng_state
from .inputs import INPUT_VARIANTS, apply_inputs, checkpoint_inputs
from .losses import LossWeights, real_loss, synthetic_loss
from .metrics import normal_mae_deg
from .model.polar_model import PolarInverseModel
from .packed import PackedDataset, open_samples
from .realdata import RealDataset
from .schedules import StepBatches, learning_rate, pixel_seed, real_loss_weight, rewarm_factor, sample_batch_pixels
from .train_files import OUT_FILES, Logs, plain_settings, sync_best_file, sync_model_file, val_rows

__all__ = ["TrainConfig", "Trainer", "train"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainConfig:
    """Flags of ``headless/train.py`` (schedules: :mod:`network.schedules`).

    Attributes:
        data: rendered dataset folder (``headless/render.py``) or a pack of one (``headless/pack.py``,
            :mod:`network.packed`).
        indices: train on these sample indices of ``data`` only (None: every completed sample).
        also: more training datasets (folders or packs) whose every completed sample joins ``data``'s
            (e.g. replaying the data a fine-tuned model was trained on beside the new data).
        out: output folder (checkpoint, model, logs).
        config: model preset (``toy``, ``small``, ``medium``, ``paper``); ``overrides`` replace fields of it.
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
        workers: data-loading worker processes per loader (the batches do not depend on it: the sampler
            fixes each step's samples and the loader keeps their order).
        tensorboard: write TensorBoard events to ``OUT/tb`` (when tensorboard is installed).
        init_from: start from this checkpoint's weights (:func:`network.checkpoint.init_from_checkpoint`; e.g. a
            ``light_input`` model from a light-blind one, its light weights at zero); ignored once resumed.
        rewarm_from, rewarm_steps: a linear learning-rate re-warm over ``rewarm_steps`` steps from step
            ``rewarm_from`` (a chunk resumed with a fresh optimizer, :mod:`network.chunk_state`; 0: none).
        time_budget: end this invocation, validated and saved, after this many seconds (None: no limit).
        distill_from, distill_weight, distill_keys: a frozen teacher checkpoint whose maps ``distill_keys`` the
            model is also pulled towards, with that weight (:mod:`network.distill`; 0: off, no teacher pass).
    """

    data: Path
    out: Path
    indices: tuple[int, ...] | None = None
    also: tuple[Path, ...] = ()
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
    init_from: Path | None = None
    rewarm_from: int = 0
    rewarm_steps: int = 0
    time_budget: float | None = None
    distill_from: Path | None = None
    distill_weight: float = 0.0
    distill_keys: tuple[str, ...] = ("metallic",)

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "checkpoint_every", "val_samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a positive integer. Got {value!r}")
        for name in ("warmup_steps", "real_start", "real_warmup", "val_every", "max_skipped", "workers", "seed",
                     "rewarm_from", "rewarm_steps"):  # fmt: skip
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer. Got {value!r}")
        if self.indices is not None:
            object.__setattr__(self, "indices", tuple(int(i) for i in self.indices))
            if not self.indices or min(self.indices) < 0 or len(set(self.indices)) != len(self.indices):
                raise ValueError("indices must be a non-empty list of distinct sample indices >= 0")
        if self.stop_after is not None and (not isinstance(self.stop_after, int) or self.stop_after < 1):
            raise ValueError(f"stop_after must be a positive integer or None. Got {self.stop_after!r}")
        if self.time_budget is not None and not (math.isfinite(self.time_budget) and self.time_budget > 0):
            raise ValueError(f"time_budget must be a finite number of seconds > 0 or None. Got {self.time_budget!r}")
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
        check_distill(self.distill_from, self.distill_weight, self.distill_keys)


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

    def forward(self, maps: Tensor, mask: Tensor, pixels: Tensor, valid: Tensor, light: Tensor | None = None) -> dict:
        features = self.model.encode(maps, mask, light)
        return self.model.decode_pixels(features, maps, pixels, valid, light)


# ------------------------------------------------------------------------------------------------
# Validation


@torch.no_grad()
def _validate(
    model: PolarInverseModel, ds: SampleDataset | PackedDataset, count: int, inputs: str, device: torch.device
) -> float:
    """Mean normal MAE (degrees) of dense predictions over the first ``count`` samples."""
    was_training = model.training
    model.eval()
    errors = []
    for i in range(min(count, len(ds))):
        item = ds[i]
        maps = apply_inputs(item["maps"][None].to(device), inputs)
        light = item["light"][None].to(device) if "light" in item else None
        pred = model(maps, item["mask"][None].to(device), light=light)
        mask = item["mask"][0].numpy() > 0
        normal = pred["normal"][0].float().permute(1, 2, 0).cpu().numpy()
        errors.append(normal_mae_deg(normal, item["normal"].permute(1, 2, 0).numpy(), mask))
    model.train(was_training)
    return float(sum(errors) / len(errors))


# ------------------------------------------------------------------------------------------------
# Training


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
        result = Trainer(cfg, stats, dd, device).run(progress)
        if dd.owned and dist.is_initialized():
            dist.barrier()  # every rank done before any tears its connections down (gloo aborts otherwise)
        return result
    finally:
        if dd.owned and dist.is_initialized():
            dist.destroy_process_group()


@dataclass(frozen=True)
class _Data:
    """The run's datasets: synthetic training samples, real captures (optional), validation samples (optional)."""

    synthetic: SampleDataset | PackedDataset | ConcatDataset
    real: RealDataset | None
    val: SampleDataset | PackedDataset | None

    def sizes(self) -> dict[str, int | None]:
        """What a checkpoint records of the training data (a change of size changes the data order)."""
        return {"synthetic": len(self.synthetic), "real": len(self.real) if self.real is not None else None}


def _datasets(cfg: TrainConfig, image_size: int) -> _Data:
    """Open the run's datasets after checking their roles (test splits are read by the final evaluation only)."""
    for folder in (cfg.data, *cfg.also):
        require_role(folder, ("train",), "training")
    if cfg.val is not None:
        require_role(cfg.val, ("val",), "validation")
    if cfg.real is not None:
        require_role(cfg.real, ("train",), "training (real-data loss)")
    light = get_config(cfg.config, **cfg.overrides).light_input
    if light and cfg.real is not None:
        raise ValueError("real captures (real) cannot train a light_input model yet (no distance per capture)")
    ds = open_samples(
        cfg.data, size=image_size, input_scale=cfg.input_scale, light_input=light,
        indices=list(cfg.indices) if cfg.indices is not None else None,
    )  # fmt: skip
    if cfg.indices is not None and len(ds) != len(cfg.indices):
        missing = sorted(set(cfg.indices) - set(ds.indices))
        raise ValueError(f"{cfg.data}: {len(missing)} of the requested indices are not completed samples "
                         f"(first: {missing[0]})")  # fmt: skip
    if cfg.also:  # in order: data's samples first, then each extra dataset's
        more = [open_samples(f, size=image_size, input_scale=cfg.input_scale, light_input=light) for f in cfg.also]
        ds = ConcatDataset([ds, *more])
    real = None
    if cfg.real is not None:
        real = RealDataset(cfg.real, size=image_size, input_scale=cfg.input_scale)
        if len(real) == 0:
            raise ValueError(f"{cfg.real}: no real captures found")
    val = None
    if cfg.val is not None:
        val = open_samples(cfg.val, size=image_size, input_scale=cfg.input_scale, light_input=light)
    return _Data(ds, real, val)


class Trainer:
    """One training run: the model, its optimizer, the data and the counters a checkpoint records.

    :meth:`run` resumes (:meth:`resume`), prepares the output folder, then calls :meth:`step` for
    every step of this invocation, validating and saving (:meth:`save`) at their steps.

    Args:
        cfg: the run's settings.
        stats: counters of this call (see :func:`train`), updated in place.
        dd: the process group (one process: a no-op context).
        device: where the model runs.
    """

    def __init__(self, cfg: TrainConfig, stats: dict, dd: DistContext, device: torch.device) -> None:
        self.cfg, self.stats, self.dd, self.device = cfg, stats, dd, device
        self.out = Path(cfg.out)
        self.ckpt_path = self.out / "checkpoint.pt"
        self.main = dd.rank == 0
        self.model_cfg = get_config(cfg.config, **cfg.overrides)
        self.data = _datasets(cfg, self.model_cfg.image_size)
        if device.type == "cuda":
            torch.backends.cuda.matmul.allow_tf32 = True
            torch.backends.cudnn.allow_tf32 = True
        torch.manual_seed(cfg.seed)  # identical initial weights on every rank
        self.model = PolarInverseModel(self.model_cfg)
        if cfg.init_from is not None:  # fine-tuning; a resumed checkpoint overrides these weights
            ckpt = init_from_checkpoint(self.model, cfg.init_from)
            require_trained_with(ckpt, cfg.init_from, "init_from", cfg.inputs, cfg.input_scale)
        self.model = self.model.to(device)
        self.teacher = None  # a frozen teacher only when its term has a weight
        if cfg.distill_weight > 0:
            self.teacher = Teacher(cfg.distill_from, cfg.inputs, cfg.input_scale, device, cfg.bf16)
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        torch.manual_seed(cfg.seed + 1 + dd.rank)  # per-rank stream for anything random after init
        self.start, self.losses, self.skipped = 0, [], 0
        self.best_mae = math.inf
        self.logs: Logs | None = None
        self.bar = None

    # -- resume and the output folder

    def resume(self) -> dict | None:
        """Load ``checkpoint.pt`` when resuming (weights, optimizer, step, losses, RNG); return it (None: fresh run).

        Raises:
            FileExistsError: a checkpoint exists and ``resume`` is off.
            ValueError: the checkpoint's model config, input variant or input scale differ from the settings.
        """
        cfg, path = self.cfg, self.ckpt_path
        if not cfg.resume:
            if path.exists():
                raise FileExistsError(f"{path}: exists; pass resume=True to continue or choose another out")
            return None
        if not path.is_file():
            return None
        ckpt = torch.load(path, weights_only=True, map_location="cpu")
        trained = {"inputs": checkpoint_inputs(ckpt), "input_scale": checkpoint_input_scale(ckpt)}
        if ckpt["config"] != self.model_cfg.to_dict():
            raise ValueError(f"{path}: checkpoint config differs from config={cfg.config!r} with "
                             f"overrides={cfg.overrides}")  # fmt: skip
        for name, value in trained.items():
            if value != getattr(cfg, name):
                raise ValueError(f"{path}: checkpoint was trained with {name}={value!r}, not {getattr(cfg, name)!r}")
        self.model.load_state_dict(ckpt["model"])
        self.opt.load_state_dict(ckpt["optimizer"])
        self.start, self.losses, self.skipped = int(ckpt["step"]), list(ckpt["losses"]), int(ckpt["skipped"])
        if len(ckpt["rng"]) == self.dd.world:
            set_rng_state(ckpt["rng"][self.dd.rank], self.device)
        else:
            log.warning("%s: saved RNG states are for another number of processes; resume is not bitwise", path)
        for name, size in self.data.sizes().items():
            if size is not None and ckpt["data"].get(name) not in (None, size):
                log.warning("%s: the %s data had %s samples, now %d: the data order changes", path, name,
                            ckpt["data"].get(name), size)  # fmt: skip
        return ckpt

    def prepare_out(self, ckpt: dict | None) -> None:
        """Rank 0: create ``out``, remove a killed run's temporaries, repair ``model.pt``/``best.pt`` from ``ckpt``."""
        starts = self.dd.gather(self.start)
        if len(set(starts)) != 1:
            raise ValueError(f"{self.ckpt_path}: ranks resume from different steps {starts}; "
                             "every node must see the checkpoint")  # fmt: skip
        out = self.out
        if self.main:
            out.mkdir(parents=True, exist_ok=True)
            removed = remove_leftovers(out, OUT_FILES)  # of a killed run (a live writer's stay)
            if removed:
                log.info("removed %d temporary file(s) of a killed run from %s", len(removed), out)
            if self.start >= self.cfg.steps:  # nothing left to train: model.pt must still be the checkpoint's
                sync_model_file(out / "model.pt", ckpt)
            if ckpt is not None and self.cfg.val is not None:
                sync_best_file(out, ckpt)
        self.best_mae = min((mae for step, mae in val_rows(out / "val.csv") if step <= self.start), default=math.inf)
        self.dd.barrier()

    # -- one step

    def _batches(self, steps: list[int]) -> None:
        """The loaders of this invocation's ``steps`` (the real one only over steps whose real weight is > 0)."""
        cfg, dd = self.cfg, self.dd
        self.syn_sampler = StepBatches(len(self.data.synthetic), cfg.seed, "synthetic", steps, cfg.batch_size,
                                       dd.rank, dd.world)  # fmt: skip
        self.syn_batches = _loader(self.data.synthetic, self.syn_sampler, cfg.workers)
        self.real_sampler = self.real_batches = None
        if self.data.real is not None:
            real_steps = [s for s in steps if self._real_weight(s) > 0]
            self.real_sampler = StepBatches(len(self.data.real), cfg.seed, "real", real_steps, cfg.batch_size,
                                            dd.rank, dd.world)  # fmt: skip
            self.real_batches = _loader(self.data.real, self.real_sampler, cfg.workers)

    def _real_weight(self, step: int) -> float:
        cfg = self.cfg
        if self.data.real is None:
            return 0.0
        return real_loss_weight(step, cfg.real_weight, cfg.real_start, cfg.real_warmup)

    def _prepare(self, batch: dict, loader: str, step: int, sampler: StepBatches) -> tuple[dict, Tensor, Tensor]:
        """Move a batch to the device and draw its training pixels (a pure function of seed, loader, step, position)."""
        seeds = [pixel_seed(self.cfg.seed, loader, step, p) for p in sampler.positions(step)]
        pixels, valid = sample_batch_pixels(batch["mask"], self.model_cfg.train_pixels, seeds)
        device = self.device
        batch = {k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
        return batch, pixels.to(device), valid.to(device)

    def _forward(self, batch: dict, pixels: Tensor, valid: Tensor) -> dict:
        with torch.autocast(device_type=self.device.type, dtype=torch.bfloat16, enabled=self.cfg.bf16):
            # The network sees the variant's maps; the losses keep the measured ones.
            maps = apply_inputs(batch["maps"], self.cfg.inputs)
            pred = self.net(maps, batch["mask"].to(batch["maps"].dtype), pixels, valid, batch.get("light"))
        return {k: v.float() for k, v in pred.items()}  # losses and backward in float32, outside autocast

    def _skip(self, step: int, reason: str, row: dict) -> None:
        """Report a skipped step (log, ``log.csv``); more than ``max_skipped`` stop the run."""
        self.skipped += 1
        self.stats["skipped"] += 1
        log.warning("step %d: %s; step skipped (%d skipped so far)", step, reason, self.skipped)
        self.opt.zero_grad(set_to_none=True)
        self.logs.step({**row, "skipped": reason.replace(",", ";")}, {})
        if self.skipped > self.cfg.max_skipped:
            raise FloatingPointError(
                f"{self.skipped} steps skipped for non-finite values (more than max_skipped={self.cfg.max_skipped}); "
                f"stopping at step {step}: {reason}"
            )

    def step(self, step: int) -> None:
        """One optimizer step (or a reported skip): synthetic pass, real pass (weight > 0), clip, AdamW."""
        cfg, stats, device = self.cfg, self.stats, self.device
        t0 = time.perf_counter()
        lr = learning_rate(step, cfg.lr, cfg.warmup_steps, cfg.decay_steps or cfg.steps, cfg.min_lr_ratio)
        lr *= rewarm_factor(step, cfg.rewarm_from, cfg.rewarm_steps)
        for group in self.opt.param_groups:
            group["lr"] = lr
        w_real = self._real_weight(step)
        row: dict[str, Any] = {"step": step, "lr": lr, "real_weight": w_real}
        syn, pix, valid = self._prepare(next(self.syn_batches), "synthetic", step, self.syn_sampler)
        stats["synthetic_batches"] += 1
        real = None
        if w_real > 0:  # the real batch is loaded only when its pass runs
            real, rpix, rvalid = self._prepare(next(self.real_batches), "real", step, self.real_sampler)
            stats["real_batches"] += 1
        bad = [f"synthetic {k}" for k in _nonfinite_keys(syn)]
        bad += [f"real {k}" for k in _nonfinite_keys(real)] if real is not None else []
        if self.dd.any_true(bool(bad), device):  # every rank skips together
            self._skip(step, f"non-finite input ({', '.join(bad) or 'on another rank'})", row)
            return

        self.opt.zero_grad(set_to_none=True)
        pred = self._forward(syn, pix, valid)
        target = {k: gather_pixels(syn[k], pix) for k in TARGET_KEYS}
        loss_syn, parts = synthetic_loss(pred, target, valid[:, None].float(), cfg.weights)
        if self.teacher is not None:  # the teacher's maps at the same pixels, a second target
            term = distill_loss(pred, self.teacher(syn["maps"], syn["mask"], pix, valid, syn.get("light")),
                                valid[:, None].float(), cfg.distill_keys)  # fmt: skip
            loss_syn, parts["distill"] = loss_syn + cfg.distill_weight * term, float(term.detach())
        loss_syn.backward()
        del pred
        loss_real, real_parts = torch.zeros((), device=device), {}
        if real is not None:
            rpred = self._forward(real, rpix, rvalid)
            loss_real, real_parts = real_loss(rpred, real, rpix, rvalid[:, None].float())
            (w_real * loss_real).backward()  # gradients accumulate onto the synthetic ones
            stats["real_passes"] += 1
            del rpred
        # After DDP's all-reduce the gradients, hence their norm, are the same on every rank.
        grad_norm = float(torch.nn.utils.clip_grad_norm_(self.model.parameters(), cfg.clip))
        mean_syn, mean_real = self.dd.mean([float(loss_syn.detach()), float(loss_real.detach())], device)
        total = mean_syn + w_real * mean_real
        row.update(loss=total, synthetic=mean_syn, real=mean_real if real is not None else None, grad_norm=grad_norm)
        if not (math.isfinite(total) and math.isfinite(grad_norm)):
            self._skip(step, f"non-finite loss {total} or gradient norm {grad_norm}", row)
            return
        self.opt.step()
        self.losses.append(total)
        stats["steps"] += 1
        row["seconds"] = time.perf_counter() - t0
        row.update({k: parts.get(k) for k in (*TARGET_KEYS, "chromaticity")})
        scalars = {"loss/total": total, "loss/synthetic": mean_syn, "lr": lr, "grad_norm": grad_norm}
        scalars.update({f"synthetic/{k}": v for k, v in parts.items()})
        if real is not None:
            scalars.update({"loss/real": mean_real, "real_weight": w_real})
            scalars.update({f"real/{k}": v for k, v in real_parts.items()})
        self.logs.step(row, scalars)
        if self.bar is not None:
            self.bar.set_postfix(loss=f"{total:.4f}")

    # -- validation and checkpoints

    def validate(self, done: int, due: bool = False) -> float | None:
        """Rank 0: the validation normal MAE after step ``done`` when one is due (else None, and on other ranks)."""
        cfg, val = self.cfg, self.data.val
        if val is None or not (due or done % (cfg.val_every or cfg.checkpoint_every) == 0 or done == cfg.steps):
            return None
        mae = None
        if self.main:
            mae = _validate(self.model, val, cfg.val_samples, cfg.inputs, self.device)
            self.logs.val(done, mae, min(cfg.val_samples, len(val)))
        self.dd.barrier()
        return mae

    def save(self, done: int, val_mae: float | None) -> None:
        """Write ``checkpoint.pt``, then ``model.pt`` (and ``best.pt`` on a new best validation) on rank 0."""
        cfg, dd = self.cfg, self.dd
        state = self.model.state_dict()
        shas = dd.gather(params_sha256(state))
        rngs = dd.gather(rng_state(self.device))
        if len(set(shas)) != 1:
            raise RuntimeError(f"step {done}: ranks hold different parameters (sha256 {shas})")
        if self.main:
            record = {
                "format": CHECKPOINT_FORMAT, "config": self.model_cfg.to_dict(), "inputs": cfg.inputs,
                "input_scale": cfg.input_scale, "model": state, "optimizer": self.opt.state_dict(), "step": done,
                "losses": self.losses, "skipped": self.skipped, "rng": rngs, "rank_params_sha256": shas,
                "world_size": dd.world, "data": self.data.sizes(), "train": plain_settings(cfg),
            }  # fmt: skip
            save_checkpoint(self.ckpt_path, record)  # first: a kill before model.pt is repaired by the resume
            save_checkpoint(self.out / "model.pt", model_file_state(record, shas[0]))
            if val_mae is not None and val_mae < self.best_mae:  # after the checkpoint: see sync_best_file
                self.best_mae = val_mae
                best = {**model_file_state(record, shas[0]), "val_normal_mae_deg": val_mae}
                save_checkpoint(self.out / "best.pt", best)
        dd.barrier()

    # -- the run

    def run(self, progress: bool) -> list[float]:
        """Resume, then train up to ``steps`` (or ``stop_after``); returns the losses of every completed step."""
        cfg, dd, device = self.cfg, self.dd, self.device
        self.prepare_out(self.resume())  # the loaded checkpoint (optimizer state included) is dropped here
        self.logs = Logs(self.out, self.start, cfg.resume, self.main, cfg.tensorboard)
        self.net: nn.Module = _PixelModel(self.model)
        if dd.active:
            ids = [device.index] if device.type == "cuda" else None
            self.net = nn.parallel.DistributedDataParallel(self.net, device_ids=ids)
        stop = cfg.steps if cfg.stop_after is None else min(cfg.steps, cfg.stop_after)
        steps = list(range(self.start, stop))
        self._batches(steps)
        if progress and self.main:
            from tqdm import tqdm  # noqa: PLC0415

            self.bar = tqdm(total=cfg.steps, initial=self.start, desc=f"train {cfg.config}", unit="step")
        self.model.train()
        t_start = time.monotonic()
        try:
            for step in steps:
                self.step(step)
                if self.bar is not None:
                    self.bar.update()
                done = step + 1
                late = cfg.time_budget is not None and self.dd.any_true(
                    time.monotonic() - t_start >= cfg.time_budget, device)  # fmt: skip
                mae = self.validate(done, due=late)
                if late or done % cfg.checkpoint_every == 0 or done in (cfg.steps, stop):
                    self.save(done, mae)
                if late:
                    log.info("time_budget %.0f s spent: stopping after step %d", cfg.time_budget, done)
                    break
        finally:
            if self.bar is not None:
                self.bar.close()
            self.logs.close()
        return self.losses
