"""Benchmark ``loader``: training samples per second from EXR samples and from a pack, next to the model's step rate.

Per size: the first ``count`` samples of a rendered split are written at that size as EXR samples
(resized as training resizes them, every channel but the raw frames kept, so each EXR decodes as
much as one rendered at that size) and packed from there (:func:`network.packed.pack_split`,
float16). Each loader row iterates the training loop's loader (:func:`network.train._loader`
over :class:`network.schedules.StepBatches`: the same batches in the same order) over
:class:`network.data.SampleDataset` or :class:`network.packed.PackedDataset`, calibrated input,
with 0..N worker processes; the files are in the page cache (just written). Timed under
:mod:`network.bench.timing`: blocks of consecutive batches (workers deliver in bursts), after one
untimed block that starts the workers; samples per second = samples per block / median seconds.

The model rows time one training step as :class:`network.train.Trainer` runs it (training
pixels drawn from the batch's mask, forward at those pixels, the synthetic loss, backward, gradient
clipping, AdamW) on a batch from the pack, randomly initialised weights (cost only), at each
batch size; samples per second = batch / median seconds. ``headroom`` is a loader row's rate over
the model's at the same size: above 1 the loader keeps up. The ``item`` rows time ``dataset[i]``
alone in one thread (CPU time, so they hold on a shared machine): ``items_per_cpu_second`` times the
cores a machine gives the workers bounds what its loader can deliver.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from network.bench.timing import RULE, machine, time_call

__all__ = ["LoaderBench", "run"]


@dataclass(frozen=True)
class LoaderBench:
    """What the ``loader`` benchmark runs (the flags of ``headless/bench.py loader``).

    Attributes:
        source: a rendered split (read only).
        count: how many of its samples to copy and pack per size.
        sizes: sample sizes in pixels.
        workers: loader worker counts to time.
        batch: samples per loader batch.
        batches: batches per timed block of a loader row (at least two per worker); ``repeat`` timed blocks
            after one untimed block (which starts the workers).
        config: model preset of the model rows (``image_size`` set to each size).
        step_batches: batch sizes of the model rows; ``step_repeat`` timed steps each, after one warm-up.
        device: ``"cpu"`` or ``"cuda[:N]"`` for the model rows (bf16 autocast on CUDA).
        threads: torch CPU threads (None: torch's default).
        work: folder for the copies and packs (None: a temporary folder, removed at the end).
    """

    source: Path
    count: int = 16
    sizes: tuple[int, ...] = (192, 384)
    workers: tuple[int, ...] = (0, 1, 2)
    batch: int = 8
    batches: int = 4
    repeat: int = 3
    config: str = "small"
    step_batches: tuple[int, ...] = (4, 8)
    step_repeat: int = 2
    device: str = "cpu"
    threads: int | None = None
    work: Path | None = None
    seed: int = 0
    overrides: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("count", "batch", "batches", "repeat", "step_repeat"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1; got {getattr(self, name)!r}")
        if min(self.workers, default=0) < 0 or not self.sizes or not self.workers:
            raise ValueError(f"workers must be >= 0 and workers and sizes non-empty; got workers={self.workers}, "
                             f"sizes={self.sizes}")  # fmt: skip


def _copy_at_size(source: Path, dest: Path, count: int, size: int) -> list[int]:
    """The first ``count`` completed samples of ``source`` written into ``dest`` at ``size`` (all channels but raw)."""
    import torch  # noqa: PLC0415
    import torch.nn.functional as F  # noqa: N812, PLC0415

    from pbrdf.data import dataset as pdataset  # noqa: PLC0415
    from pbrdf.data import sample as psample  # noqa: PLC0415

    done = sorted(pdataset.completed_indices(source))[:count]
    if not done:
        raise ValueError(f"{source}: no completed samples")
    for i in done:
        channels = json.loads(psample.sample_paths(source, i).sidecar.read_text())["channels"]
        keys = [k for k in psample.SAMPLE_KEYS if k != "raw" and all(c in channels for c in psample.CHANNELS[k])]
        sample, meta = psample.read_sample(source, i, keys=keys)
        out = {}
        for key, a in sample.items():
            x = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).reshape(*a.shape[:2], -1)
            x = x.permute(2, 0, 1)[None]
            nearest = key in ("mask", "object", "depth")
            y = F.interpolate(x, size=(size, size), mode="nearest" if nearest else "bilinear", align_corners=None
                              if nearest else False)[0].permute(1, 2, 0).numpy()  # fmt: skip
            if key == "normal":
                y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-8)
            out[key] = y.reshape(size, size, *a.shape[2:]).astype(a.dtype)
        out["normal"] = np.where(out["mask"][..., None] > 0, out["normal"], 0).astype(np.float32)
        for key in ("albedo", "roughness", "metallic"):
            out[key] = np.clip(out[key], 0, 1)
        drop = {*psample.SIDECAR_KEYS, "camera_model", "intrinsics"}  # intrinsics: of the rendered grid
        meta = {k: v for k, v in meta.items() if k not in drop}
        psample.write_sample(dest, i, out, meta)
    return done


def _loader_row(ds, s: LoaderBench, workers: int, what: str) -> dict:
    """Blocks of consecutive batches (workers deliver in bursts, so single batches have no useful median)."""
    from network.schedules import StepBatches  # noqa: PLC0415
    from network.train import _loader  # noqa: PLC0415

    block = max(s.batches, 2 * workers)  # at least two rounds of every worker per timed block
    steps = list(range(block * (1 + s.repeat)))
    it = _loader(ds, StepBatches(len(ds), s.seed, "synthetic", steps, s.batch, 0, 1), workers)
    what = f"{block} consecutive batches of {what}"
    timing, _ = time_call(lambda: [next(it) for _ in range(block)], what, repeat=s.repeat, warmup=1)
    return {**timing.to_dict(), "workers": workers, "samples_per_second": block * s.batch / timing.median}


def _item_rows(datasets: dict, s: LoaderBench, size: int) -> dict:
    """CPU seconds per item in one thread (as in a loader worker), EXR and pack alternating (robust to sharing)."""
    import torch  # noqa: PLC0415

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # what a DataLoader worker runs with
    try:
        cpu: dict[str, list[float]] = {kind: [] for kind in datasets}
        wall: dict[str, list[float]] = {kind: [] for kind in datasets}
        for _ in range(s.repeat):
            for i in range(len(datasets["exr"])):
                for kind, ds in datasets.items():
                    c0, w0 = time.thread_time(), time.perf_counter()
                    ds[i]
                    cpu[kind].append(time.thread_time() - c0)
                    wall[kind].append(time.perf_counter() - w0)
    finally:
        torch.set_num_threads(threads)
    rows = {}
    for kind in datasets:
        med = float(np.median(cpu[kind]))
        rows[kind] = {
            "what": f"dataset[i] at {size} px ({kind}), calibrated, 1 torch thread; CPU time of this thread "
            f"(time.thread_time) and wall time, {s.repeat} passes over the {len(datasets[kind])} samples",
            "cpu_seconds_median": med,
            "wall_seconds_median": float(np.median(wall[kind])),
            "cpu_seconds_all": cpu[kind],
            "items_per_cpu_second": 1.0 / med,
        }
    rows["pack_over_exr_cpu"] = rows["exr"]["cpu_seconds_median"] / rows["pack"]["cpu_seconds_median"]
    return rows


def _model_rows(pack: Path, s: LoaderBench, size: int) -> dict:
    """One training step per batch size, as the trainer runs it, on a batch from the pack."""
    import torch  # noqa: PLC0415

    from network.config import get_config  # noqa: PLC0415
    from network.data import TARGET_KEYS, gather_pixels  # noqa: PLC0415
    from network.losses import LossWeights, synthetic_loss  # noqa: PLC0415
    from network.model.polar_model import PolarInverseModel  # noqa: PLC0415
    from network.packed import PackedDataset  # noqa: PLC0415
    from network.schedules import sample_batch_pixels  # noqa: PLC0415
    from network.train import _collate, _PixelModel  # noqa: PLC0415

    cfg = get_config(s.config, **{**s.overrides, "image_size": size})
    torch.manual_seed(s.seed)
    device = torch.device(s.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else None
    net = _PixelModel(PolarInverseModel(cfg)).to(device).train()
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4)
    ds = PackedDataset(pack, size=size, input_scale="calibrated", verify=False)
    rows = {}
    for b in s.step_batches:
        batch = _collate([ds[i % len(ds)] for i in range(b)])
        pixels, valid = sample_batch_pixels(batch["mask"], cfg.train_pixels, list(range(b)))
        batch = {k: v.to(device) for k, v in batch.items()}
        pixels, valid = pixels.to(device), valid.to(device)

        def step(batch=batch, pixels=pixels, valid=valid):
            opt.zero_grad(set_to_none=True)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=device.type == "cuda"):
                pred = net(batch["maps"], batch["mask"], pixels, valid)
            pred = {k: v.float() for k, v in pred.items()}
            target = {k: gather_pixels(batch[k], pixels) for k in TARGET_KEYS}
            loss, _ = synthetic_loss(pred, target, valid[:, None].float(), LossWeights())
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()

        bf16 = ", bf16 autocast" if device.type == "cuda" else ""
        what = (f"one training step of {s.config!r} at {size} px (image_size={size}, {cfg.train_pixels} training "
                f"pixels per image): forward at the pixels, synthetic loss, backward, clip, AdamW; "
                f"batch {b}{bf16}")  # fmt: skip
        timing, _ = time_call(step, what, repeat=s.step_repeat, warmup=1, sync=sync)
        rows[f"batch_{b}"] = {**timing.to_dict(), "samples_per_second": b / timing.median}
    return rows


def _size_entry(s: LoaderBench, size: int, work: Path) -> dict:
    """Copy, pack, time every loader row and the model rows at one size."""
    from network.data import SampleDataset  # noqa: PLC0415
    from network.packed import PackedDataset, pack_split  # noqa: PLC0415

    exr, pack = work / f"exr-{size}", work / f"pack-{size}"
    shutil.rmtree(exr, ignore_errors=True)
    shutil.rmtree(pack, ignore_errors=True)
    done = _copy_at_size(Path(s.source), exr, s.count, size)
    t0 = time.perf_counter()
    pack_split(exr, pack, shard_samples=max(1, s.count // 2))
    pack_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    datasets = {"exr": SampleDataset(exr, size=size, input_scale="calibrated")}
    exr_open = time.perf_counter() - t0
    t0 = time.perf_counter()
    datasets["pack"] = PackedDataset(pack, size=size, input_scale="calibrated")
    pack_open = time.perf_counter() - t0
    entry: dict = {
        "samples": len(done),
        "exr_bytes_per_sample": sum(p.stat().st_size for p in (exr / "samples").glob("*.exr")) / len(done),
        "pack_bytes_per_sample": sum(p.stat().st_size for p in pack.glob("shard-*.bin")) / len(done),
        "pack_seconds_per_sample": pack_seconds / len(done),
        "open_seconds": {"exr (hash every EXR)": exr_open, "pack (hash every shard)": pack_open},
        "loader": {},
    }
    entry["item"] = _item_rows(datasets, s, size)
    for kind, ds in datasets.items():
        name = "SampleDataset (EXR decode, check_item" if kind == "exr" else "PackedDataset (memmap slice, float16"
        for w in s.workers:
            what = (f"{s.batch} at {size} px from the training loader over {name}, calibrated normalisation, "
                    f"collate), {w} worker processes")  # fmt: skip
            entry["loader"][f"{kind}/workers_{w}"] = _loader_row(ds, s, w, what)
    entry["model"] = _model_rows(pack, s, size) if s.step_batches else {}
    best = max(s.step_batches, default=None)
    if best is not None:
        model_rate = entry["model"][f"batch_{best}"]["samples_per_second"]
        entry[f"headroom_over_model_batch_{best}"] = {
            k: row["samples_per_second"] / model_rate for k, row in entry["loader"].items()
        }
    for w in s.workers:
        entry.setdefault("pack_over_exr", {})[f"workers_{w}"] = (
            entry["loader"][f"pack/workers_{w}"]["samples_per_second"]
            / entry["loader"][f"exr/workers_{w}"]["samples_per_second"]
        )
    return entry


def run(settings: LoaderBench | None = None, **overrides) -> dict:
    """Run the benchmark (see the module docs).

    Returns:
        The JSON-ready result: per size ``exr_bytes_per_sample``, ``pack_bytes_per_sample``,
        ``pack_seconds_per_sample``, ``open_seconds``, ``loader`` rows (``"exr|pack/workers_N"``: timing and
        ``samples_per_second``), ``model`` rows (``batch_B``), ``headroom_over_model_batch_B`` and
        ``pack_over_exr`` ratios; ``timing_rule``, the load average and ``machine``.
    """
    import dataclasses  # noqa: PLC0415

    import torch  # noqa: PLC0415

    s = dataclasses.replace(settings, **overrides) if settings is not None else LoaderBench(**overrides)
    if s.device.startswith("cuda") and not torch.cuda.is_available():
        raise RuntimeError("--device cuda: no CUDA device is available to torch")
    if s.threads:
        torch.set_num_threads(s.threads)
    result: dict = {
        "benchmark": "loader",
        "source": str(s.source),
        "device": torch.cuda.get_device_name(s.device) if s.device.startswith("cuda") else "cpu",
        "threads": torch.get_num_threads(),
        "load_average_at_start": list(os.getloadavg()),
        "input": f"the first {s.count} samples of the source, written at each size as EXR samples and packed "
        "(float16); loader rows: batches of the training loader; model rows: randomly initialised model (cost only)",
        "timing_rule": RULE,
        "sizes": {},
    }
    with tempfile.TemporaryDirectory(dir=s.work) as tmp:
        for size in s.sizes:
            result["sizes"][str(size)] = _size_entry(s, size, Path(tmp))
    result["load_average_at_end"] = list(os.getloadavg())
    result["machine"] = machine(torch=torch.__version__)
    return result
