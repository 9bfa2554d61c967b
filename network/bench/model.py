"""Benchmark ``network``: inference and training time and memory per model config, and stride error.

Per model config (:func:`network.config.get_config`) at its input size (384 for ``small`` and
``paper``) on smooth synthetic maps with a centred disc mask (``mask_fraction`` of the image) and a
randomly initialised model (only the cost is measured there): parameters and FLOPs, the
training-mode forward with gradients enabled (as in training) and one AdamW step, the encoder, and
dense decoding per stride (:meth:`network.model.PolarInverseModel.decode_dense`) with total time,
frames per second, decoded pixels per second and peak memory (:mod:`network.bench.memory`);
optionally the reference (straightforward) dense decoder and its difference.

The error of each stride against stride 1 is measured where it means something: with the shipped
model (``models/small/model.pt``, :func:`network.checkpoint.load_checkpoint`) on real-path input
(``examples/capture`` through :func:`network.infer.load_input`), by :func:`network.infer.predict`
per stride, with its time (the ``predict`` entry). Every timing follows
:mod:`network.bench.timing`; ``device="cuda"`` times the same on a GPU (the fps figure is the
interactive rate).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from network.bench.memory import resident_peak_mib
from network.bench.timing import RULE, machine, time_call
from network.metrics import normal_angle_deg

__all__ = ["EXAMPLE_CAPTURE", "SHIPPED_CHECKPOINT", "TARGETS_CPU_SECONDS", "ModelBench", "run", "smooth_input"]

_ROOT = Path(__file__).resolve().parents[2]
#: The shipped model (the same file as :data:`network.infer.DEFAULT_CHECKPOINT`).
SHIPPED_CHECKPOINT = _ROOT / "models" / "small" / "model.pt"
#: The real-format example capture folder (raw brackets + ``capture.json``).
EXAMPLE_CAPTURE = _ROOT / "examples" / "capture"

#: Run-time goals for one 384 x 384 capture on 2 CPU cores, seconds (interactive use of ``small``;
#: ``paper`` within a minute).
TARGETS_CPU_SECONDS = {"small": 1.0, "paper": 60.0}


@dataclass(frozen=True)
class ModelBench:
    """What the ``network`` benchmark runs (the flags of ``headless/bench.py network``).

    Attributes:
        configs: model configs to time.
        size: input size; None for each config's own.
        mask_fraction: image fraction inside the disc mask, in (0, 1].
        strides: decoding strides (1 is always added).
        repeat: timed calls per measurement.
        warmup: untimed calls before them.
        threads: torch CPU threads; None for torch's default.
        device: ``"cpu"`` or ``"cuda[:N]"``.
        bf16: CUDA only: inference under bf16 autocast.
        reference: also time the reference dense decoder (not for ``paper`` unless ``paper_reference``).
        paper_reference: time the reference decoder for ``paper`` too (slow).
        skip_dense: skip inference except for ``toy``.
        train: time the training forward and step.
        checkpoint: trained model for :func:`network.infer.predict` and the stride error; None (or a missing
            file) skips them.
        capture: capture folder or sample for :func:`network.infer.predict` (through
            :func:`network.infer.load_input`); None skips it.
        seed: seed of the model initialisation.
    """

    configs: tuple[str, ...] = ("toy", "small")
    size: int | None = None
    mask_fraction: float = 0.5
    strides: tuple[int, ...] = (1, 2, 4)
    repeat: int = 1
    warmup: int = 1
    threads: int | None = None
    device: str = "cpu"
    bf16: bool = False
    reference: bool = True
    paper_reference: bool = False
    skip_dense: bool = False
    train: bool = True
    checkpoint: Path | None = SHIPPED_CHECKPOINT
    capture: Path | None = EXAMPLE_CAPTURE
    seed: int = 0

    def __post_init__(self) -> None:
        if min(self.strides) < 1 or self.repeat < 1 or self.warmup < 0 or not 0 < self.mask_fraction <= 1:
            raise ValueError("strides and repeat must be >= 1, warmup >= 0 and mask_fraction in (0, 1]")


def smooth_input(size: int, fraction: float, device: str = "cpu"):
    """Nine smooth maps and a centred disc mask.

    Args:
        size: image size in pixels (square).
        fraction: image fraction inside the mask.
        device: torch device.

    Returns:
        ``(maps, mask)``: ``(1, 9, S, S)`` float32 with values in [0.1, 0.5] and ``(1, 1, S, S)``
        float32 in {0, 1}.
    """
    import torch  # noqa: PLC0415

    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    u, v = yy / size, xx / size
    maps = torch.stack([0.3 + 0.2 * torch.sin(3 * u + k) * torch.cos(2 * v - k) for k in range(9)])[None]
    radius2 = fraction * size * size / np.pi
    mask = ((yy - size / 2 + 0.5) ** 2 + (xx - size / 2 + 0.5) ** 2 < radius2)[None, None]
    return maps.float().to(device), mask.float().to(device)


def _decoded_pixels(model, mask, stride: int) -> int:
    """How many pixels :meth:`PolarInverseModel.decode_dense` runs through the decoder at ``stride`` (batch 1)."""
    import torch  # noqa: PLC0415

    from network.model import context_pixels, fill_from_decoded, grid_pixels  # noqa: PLC0415

    h, w = mask.shape[-2:]
    inside = mask[0, 0].reshape(-1) > 0
    idx = torch.nonzero(inside).squeeze(1)
    if stride == 1:
        return int(idx.numel())
    decoded = torch.zeros(h * w, dtype=torch.bool, device=mask.device)
    decoded[context_pixels(idx, model.config.train_pixels)] = True
    decoded[grid_pixels(idx, w, stride)] = True
    _, weight = fill_from_decoded(torch.zeros(1, h, w, device=mask.device), decoded.reshape(h, w), stride)
    return int(decoded.sum()) + int((inside & ~decoded & (weight.reshape(-1) == 0)).sum())


def _stride_error(ref: dict, pred: dict, mask: np.ndarray) -> dict:
    """Error of ``pred`` against ``ref`` (stride 1) inside ``mask``: normal angle (degrees), BRDF mean abs error.

    Args:
        ref: :func:`network.infer.predict` output at stride 1, ``(H, W, C)`` arrays.
        pred: its output at another stride.
        mask: ``(H, W)`` bool.
    """
    deg = normal_angle_deg(ref["normal"], pred["normal"])[mask]
    out = {
        "normal_deg_mean": float(deg.mean()),
        "normal_deg_p99": float(np.quantile(deg, 0.99)),
        "normal_deg_max": float(deg.max()),
    }
    for key in ("albedo", "roughness", "metallic"):
        diff = np.abs(ref[key] - pred[key])[mask]
        out[f"{key}_mae"] = float(diff.mean())
        out[f"{key}_max_abs"] = float(diff.max())
    return out


def _sync(device: str):
    """``torch.cuda.synchronize`` on CUDA, else None (for :func:`~network.bench.timing.time_call`)."""
    import torch  # noqa: PLC0415

    return torch.cuda.synchronize if device.startswith("cuda") else None


def _bench_predict(s: ModelBench) -> dict:
    """:func:`network.infer.predict` with a trained checkpoint on real-path input: time and error per stride."""
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import load_input, predict  # noqa: PLC0415
    from network.model.dense import REFINE_DEG  # noqa: PLC0415

    model, ckpt = load_checkpoint(s.checkpoint)
    inp = load_input(s.capture)
    maps, mask = inp.maps, inp.mask
    inputs, scale, radiance = ckpt["inputs"], ckpt["input_scale"], inp.radiance
    result: dict = {
        "checkpoint": str(s.checkpoint),
        "capture": str(s.capture),
        "masked_pixels": int(mask.sum()),
        "error": "error_vs_stride_1: the trained model's prediction at each stride against its own at stride 1, "
        "inside the mask of network.infer.load_input (normal angle in degrees, BRDF mean and max abs error)",
    }
    ref = None
    # stride_s: edge-aware (the default refine_deg); stride_s_plain: plain interpolation (refine_deg=None).
    runs = [(st, refine, f"stride_{st}{suffix}") for st in sorted(set(s.strides) | {1}) for refine, suffix in
            ([(REFINE_DEG, "")] if st == 1 else [(REFINE_DEG, ""), (None, "_plain")])]  # fmt: skip
    for stride, refine, name in runs:
        how = "plain interpolation" if refine is None else f"edge-aware, refine_deg {refine:g}"
        timing, pred = time_call(
            lambda st=stride, r=refine: predict(
                model, maps, mask, inputs=inputs, input_scale=scale, radiance=radiance, stride=st, refine_deg=r
            ),
            f"network.infer.predict of {Path(s.capture).name} at stride {stride}"
            + ("" if stride == 1 else f" ({how})")
            + " (CPU, checkpoint's input variant)",
            repeat=s.repeat,
            warmup=s.warmup,
        )
        entry = {**timing.to_dict(), "seconds": timing.median}
        if stride == 1:
            ref = pred
        else:
            entry["error_vs_stride_1"] = _stride_error(ref, pred, mask)
        result[name] = entry
    return result


def _train_entry(model, maps, mask, s: ModelBench, size: int) -> dict:
    """Training-mode forward with gradients enabled (as in training) and one AdamW step: timings."""
    import torch  # noqa: PLC0415

    sync = _sync(s.device)
    model.train()

    def forward():
        with torch.enable_grad():  # as in training: the autograd graph is recorded
            return model(maps, mask)

    fwd, out = time_call(forward, f"training-mode forward with gradients enabled (autograd graph recorded, no "
                       f"backward), batch 1, {size} px", repeat=s.repeat, warmup=s.warmup, sync=sync)  # fmt: skip
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)

    def step():
        out = model(maps, mask)
        loss = sum(out[k].float().mean() for k in ("normal", "albedo", "roughness", "metallic"))
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)

    stp, _ = time_call(step, f"training step (forward, backward, AdamW), batch 1, {size} px", repeat=s.repeat,
                       warmup=s.warmup, sync=sync)  # fmt: skip
    return {
        "train_forward": {**fwd.to_dict(), "grad_enabled": bool(out["normal"].requires_grad)},
        "train_forward_seconds": fwd.median,
        "train_step": stp.to_dict(),
        "train_step_seconds": stp.median,
    }


def _bench_config(name: str, s: ModelBench, strides: list[int], amp) -> dict:
    """One config's entry of :func:`run`."""
    import torch  # noqa: PLC0415

    from network.config import get_config  # noqa: PLC0415
    from network.model import PolarInverseModel, count_parameters, estimate_flops  # noqa: PLC0415

    device, sync = s.device, _sync(s.device)
    cfg = get_config(name)
    torch.manual_seed(s.seed)
    model = PolarInverseModel(cfg).to(device)
    size = s.size or cfg.image_size
    maps, mask = smooth_input(size, s.mask_fraction, device)
    masked = int(mask.sum())
    flops = estimate_flops(cfg, size, masked_pixels=masked)
    entry: dict = {
        "parameters": count_parameters(model),
        "image_size": size,
        "masked_pixels": masked,
        "gflop": {k: flops[k] / 1e9 for k in ("encoder", "decoder_train", "decoder_dense", "dense")},
    }
    if s.train:
        entry.update(_train_entry(model, maps, mask, s, size))
    model.eval()
    if s.skip_dense and name != "toy":
        return entry
    ctx = amp if amp is not None else contextlib.nullcontext()
    with torch.inference_mode(), ctx:
        peak, how, (enc, feats) = resident_peak_mib(
            lambda: time_call(
                lambda: model.encode(maps, mask),
                f"model.encode, batch 1, {size} px",
                repeat=s.repeat,
                warmup=s.warmup,
                sync=sync,
            ),
            device,
        )
        entry.update(encode=enc.to_dict(), encode_seconds=enc.median, encode_peak_mib=peak, peak_memory=how)
        ref_out = None
        if s.reference and (name != "paper" or s.paper_reference):
            ref_t, ref_out = time_call(
                lambda: model.decode_dense_reference(feats, maps, mask),
                "model.decode_dense_reference at stride 1 (one call: the slow reference)",
                repeat=1,
                warmup=0,
                sync=sync,
            )
            entry.update(reference_decode=ref_t.to_dict(), reference_decode_seconds=ref_t.median)
        inference: dict = {}
        for stride in strides:
            peak, _, (dec, out) = resident_peak_mib(
                lambda st=stride: time_call(
                    lambda: model.decode_dense(feats, maps, mask, stride=st),
                    f"model.decode_dense at stride {st} on cached encoder features, {masked} masked pixels",
                    repeat=s.repeat,
                    warmup=s.warmup,
                    sync=sync,
                ),
                device,
            )
            decoded = _decoded_pixels(model, mask, stride)
            total = enc.median + dec.median
            row = {
                "decode": dec.to_dict(),
                "decode_seconds": dec.median,
                "total_seconds": total,
                "fps": 1.0 / total,
                "decoded_pixels": decoded,
                "decoded_pixels_per_second": decoded / dec.median,
                "masked_pixels_per_second": masked / dec.median,
                "decode_peak_mib": peak,
            }
            if stride == 1 and ref_out is not None:
                row["max_abs_difference_to_reference"] = max(float((out[k] - ref_out[k]).abs().max()) for k in out)
                row["speedup_over_reference"] = entry["reference_decode_seconds"] / dec.median
            if name in TARGETS_CPU_SECONDS and device == "cpu":
                row["meets_cpu_target"] = total < TARGETS_CPU_SECONDS[name]
            inference[f"stride_{stride}"] = row
    entry["inference"] = inference
    # Compatibility keys: the stride-1 dense forward (encode + decode every masked pixel).
    entry["dense_forward_seconds"] = inference["stride_1"]["total_seconds"]
    entry["decoder_pixels_per_second"] = inference["stride_1"]["masked_pixels_per_second"]
    if name in TARGETS_CPU_SECONDS and device == "cpu":
        ok = [st for st in strides if inference[f"stride_{st}"]["meets_cpu_target"]]
        entry["smallest_stride_meeting_target"] = ok[0] if ok else None
    return entry


def run(settings: ModelBench | None = None, **overrides) -> dict:
    """Run the benchmark.

    Args:
        settings: what to run; default :class:`ModelBench`'s defaults.
        **overrides: fields of :class:`ModelBench` to replace.

    Returns:
        The JSON-ready result: ``configs`` (per config: ``parameters``, ``gflop``, training
        timings, ``encode``, ``inference`` per stride, compatibility keys
        ``dense_forward_seconds`` and ``decoder_pixels_per_second``), ``predict`` when the
        checkpoint and capture exist (time and ``error_vs_stride_1`` per stride with the trained
        model on real-path input), ``timing_rule``, the load average at start and end and ``machine``.

    Raises:
        RuntimeError: CUDA requested but not available.
    """
    import dataclasses  # noqa: PLC0415

    import torch  # noqa: PLC0415

    s = dataclasses.replace(settings or ModelBench(), **overrides)
    device = s.device
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise RuntimeError("--device cuda: no CUDA device is available to torch")
    if s.threads:
        torch.set_num_threads(s.threads)
    strides = sorted(set(s.strides) | {1})
    result: dict = {
        "benchmark": "network",
        "device": torch.cuda.get_device_name(device) if device.startswith("cuda") else "cpu",
        "threads": torch.get_num_threads(),
        "load_average_at_start": list(os.getloadavg()),
        "input": f"configs: smooth synthetic maps, centred disc mask covering {s.mask_fraction:.0%} of the image, "
        "randomly initialised model (cost only); predict: the checkpoint on the capture (time and stride error)",
        "timing_rule": RULE,
        "targets_cpu_2_cores_seconds": TARGETS_CPU_SECONDS,
        "configs": {},
    }
    amp = torch.autocast("cuda", dtype=torch.bfloat16) if s.bf16 and device.startswith("cuda") else None
    for name in dict.fromkeys(s.configs):
        result["configs"][name] = _bench_config(name, s, strides, amp)
    if s.checkpoint and Path(s.checkpoint).is_file() and s.capture and Path(s.capture).exists():
        result["predict"] = _bench_predict(s)
    result["load_average_at_end"] = list(os.getloadavg())
    result["machine"] = machine(torch=torch.__version__)
    return result
