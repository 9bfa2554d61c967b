"""Dataset samples as tensors for the network (channel-first inside network/).

Reads the renderer's samples (:mod:`pbrdf.data.dataset`) and, for real captures, the decoder's output.
Input normalisation lives here once (:func:`normalize_maps`), used by training and inference.
The unpol and LP maps are radiometric; CP is already a ratio in [-1, 1] and is kept. Two input
scales (:data:`INPUT_SCALES`; a checkpoint records its own under ``"input_scale"``):

``"calibrated"``
    The maps are divided by the display's radiance in their units (the rig's
    ``display.radiance``; decoded captures are already divided by exposure time and the sensor's
    radiometric scale) and multiplied by :data:`CALIBRATED_GAIN`. Brightness is absolute, so the
    network can tell a dark object from a dim exposure: albedo is absolute.
``"exposure-invariant"``
    The maps are divided by one robust level per image (a quantile of ``unpol + LP``): any
    exposure or display brightness gives the same input, and albedo can only be relative. Used
    for captures whose ``radiometry`` is ``"relative"`` (:mod:`pbrdf.data.capture`) and by
    checkpoints trained before calibrated input existed.

:data:`CALIBRATED_GAIN` puts the median training image's level near the exposure-invariant
level 1, so a calibrated model given an uncalibrated capture (:func:`input_radiance` falls back
to the exposure-invariant scale, with a warning) sees inputs of the usual size.

:class:`SampleDataset` checks every item it loads (target ranges, unit normals inside the mask,
a non-empty mask): a sample whose sidecar hash matches can still hold wrong values, and one bad
item must stop training with a message naming the file, not train on wrong labels.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch.utils.data import Dataset

from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.data.capture_meta import display_radiance

from .light_input import sample_light

__all__ = [
    "CALIBRATED_GAIN",
    "INPUT_SCALES",
    "MAP_LIMIT",
    "SCALE_FLOOR",
    "checkpoint_input_scale",
    "exposure_radiance",
    "input_radiance",
    "normalize_maps",
    "check_item",
    "sample_to_tensors",
    "SampleDataset",
    "resize_batch",
    "gather_pixels",
]

TARGET_KEYS = ("normal", "albedo", "roughness", "metallic")
#: Largest magnitude of a normalised map value; a pixel brighter than this many times the
#: ``quantile`` total (a hot pixel, a saturated glint over a dark object) is clamped to it. Well
#: inside float16's 65504, so the output survives a cast to half precision.
MAP_LIMIT = 1e4
#: Smallest scale: an image whose ``quantile`` total is below it (all dark) is divided by it.
SCALE_FLOOR = 1e-8
#: Input scales a model can be trained with (see the module docs).
INPUT_SCALES = ("calibrated", "exposure-invariant")
#: Calibrated maps are ``maps * CALIBRATED_GAIN / radiance``. The 95 % quantile of ``unpol + LP``
#: (summed over colours) has a median of 0.29 display radiances on the train-engine split (5-95 %:
#: 0.12-0.84), so 3.5 brings a typical image to the exposure-invariant level 1.
CALIBRATED_GAIN = 3.5


def checkpoint_input_scale(ckpt: Mapping) -> str:
    """The input scale a checkpoint was trained with (``"exposure-invariant"`` when it does not say)."""
    scale = ckpt.get("input_scale", "exposure-invariant")
    if scale not in INPUT_SCALES:
        raise ValueError(f"checkpoint has unknown input_scale {scale!r}; expected one of {INPUT_SCALES}")
    return scale


def input_radiance(input_scale: str, radiance: float | None, where: str = "input") -> float | None:
    """The ``radiance`` argument of :func:`normalize_maps` for a model and a capture.

    Args:
        input_scale: the model's input scale (:data:`INPUT_SCALES`).
        radiance: the display radiance in the maps' units
            (:func:`pbrdf.data.capture_meta.display_radiance`), None for an uncalibrated capture.
        where: the capture, named in the warning.

    Returns:
        ``radiance`` for a calibrated model and capture; None (exposure-invariant) otherwise. A
        calibrated model given an uncalibrated capture warns that albedo will be relative.

    Example:
        >>> input_radiance("calibrated", 2.0), input_radiance("exposure-invariant", 2.0)
        (2.0, None)
    """
    if input_scale not in INPUT_SCALES:
        raise ValueError(f"unknown input scale {input_scale!r}; choose one of {INPUT_SCALES}")
    if input_scale == "exposure-invariant":
        return None
    if radiance is None:
        warnings.warn(
            f"{where}: radiometry is 'relative' (uncalibrated): the model's calibrated input falls back to the "
            "exposure-invariant scale, so albedo is relative, not absolute",
            stacklevel=2,
        )
        return None
    if not (math.isfinite(radiance) and radiance > 0):
        raise ValueError(f"{where}: display radiance must be positive and finite; got {radiance!r}")
    return float(radiance)


def normalize_maps(
    maps: torch.Tensor,
    mask: torch.Tensor,
    *,
    radiance: float | torch.Tensor | None = None,
    quantile: float = 0.95,
) -> torch.Tensor:
    """Scale the unpol and LP maps to the network's input level; CP is kept.

    Calibrated (``radiance`` given): ``maps * CALIBRATED_GAIN / radiance``. Exposure-invariant
    (``radiance`` None): divided by the ``quantile`` of the masked ``unpol + LP`` total.

    Finite input gives finite output in every float dtype: float16 and bfloat16 are computed in
    float32 (float64 in float64); finite values beyond an eighth of the working dtype's largest
    value (e.g. 3e38 in float32) are clamped to it, so the six channels sum without overflow; the
    scale is at least :data:`SCALE_FLOOR` (an all-dark image gives 0, not 0/0); the result is
    clamped to ``[-MAP_LIMIT, MAP_LIMIT]`` before the mask is applied. Non-finite input is not
    cleaned: NaN and Inf propagate, so that :func:`network.train.train`'s guard sees and skips
    the batch.

    Args:
        maps: ``(*, 9, H, W)`` nine maps in :data:`pbrdf.sensor.decode.NINE_MAP_NAMES` order.
        mask: ``(*, 1, H, W)`` valid pixels (0/1).
        radiance: the display radiance in the maps' units: a positive number, or a tensor
            broadcasting to ``(*)`` (one per image); None for the exposure-invariant scale.
        quantile: exposure-invariant scale: which quantile of ``unpol + LP`` (summed over colours)
            becomes 1.

    Returns:
        ``(*, 9, H, W)`` normalised maps in the dtype of ``maps``, in ``[-MAP_LIMIT, MAP_LIMIT]``
        and 0 outside the mask (for finite input).

    Example:
        >>> maps = torch.ones(9, 2, 2)
        >>> normalize_maps(maps, torch.ones(1, 2, 2), radiance=2.0)[:, 0, 0].tolist()
        [1.75, 1.75, 1.75, 1.75, 1.75, 1.75, 1.0, 1.0, 1.0]
        >>> round(normalize_maps(maps, torch.ones(1, 2, 2))[0, 0, 0].item(), 6)  # total 6 -> 1
        0.166667
    """
    dtype = maps.dtype
    work = maps.to(torch.promote_types(dtype, torch.float32))
    big = torch.finfo(work.dtype).max / 8  # six of them still sum without overflow
    work = torch.where(work.isfinite(), work.clamp(-big, big), work)
    m = mask.to(work.dtype)
    if radiance is not None:
        r = torch.as_tensor(radiance, dtype=work.dtype, device=work.device)
        if not bool(torch.all(torch.isfinite(r) & (r > 0))):
            raise ValueError(f"radiance must be positive and finite; got {radiance!r}")
        gain = (CALIBRATED_GAIN / r).reshape(*r.shape, 1, 1, 1)
        out = torch.cat([work[..., :6, :, :] * gain, work[..., 6:, :, :]], dim=-3).clamp(-MAP_LIMIT, MAP_LIMIT)
        return (out * m).to(dtype)
    scale = _quantile_scale(work, m, quantile).reshape(*work.shape[:-3], 1, 1, 1)
    out = torch.cat([work[..., :6, :, :] / scale, work[..., 6:, :, :]], dim=-3).clamp(-MAP_LIMIT, MAP_LIMIT)
    return (out * m).to(dtype)


def _quantile_scale(work: torch.Tensor, m: torch.Tensor, quantile: float) -> torch.Tensor:
    total = (work[..., :6, :, :].sum(dim=-3, keepdim=True) * m).flatten(-3)  # (*, H*W)
    scales = []
    for row, mrow in zip(total.reshape(-1, total.shape[-1]), m.reshape(-1, total.shape[-1]), strict=True):
        vals = row[mrow > 0]
        scales.append(torch.quantile(vals, quantile) if vals.numel() else row.new_tensor(1.0))
    return torch.stack(scales).reshape(total.shape[:-1]).clamp_min(SCALE_FLOOR)


def exposure_radiance(maps: torch.Tensor, mask: torch.Tensor, *, quantile: float = 0.95) -> torch.Tensor:
    """The radiance that makes the calibrated scale equal the exposure-invariant one.

    ``normalize_maps(x, k, radiance=exposure_radiance(maps, mask))`` scales any ``x`` exactly as
    ``normalize_maps(maps, mask)`` scales ``maps`` (to float rounding), e.g. full-resolution maps
    by the scale measured on their resized copy.

    Args:
        maps: ``(*, 9, H, W)`` finite nine maps.
        mask: ``(*, 1, H, W)`` valid pixels (0/1).
        quantile: as in :func:`normalize_maps`.

    Returns:
        ``(*)`` positive radiances, float32 or float64.

    Example:
        >>> maps = torch.ones(9, 2, 2)
        >>> x = torch.rand(9, 4, 4)
        >>> k = torch.ones(1, 2, 2)
        >>> r = exposure_radiance(maps, k)
        >>> bool(torch.allclose(normalize_maps(x, torch.ones(1, 4, 4), radiance=r)[:6], x[:6] / 6))
        True
    """
    work = maps.to(torch.promote_types(maps.dtype, torch.float32))
    big = torch.finfo(work.dtype).max / 8
    work = work.clamp(-big, big)
    return CALIBRATED_GAIN * _quantile_scale(work, mask.to(work.dtype), quantile)


def _first_pixel(bad: np.ndarray) -> str:
    r, c = np.argwhere(bad)[0][:2]
    return f"(row {int(r)}, col {int(c)})"


def check_item(sample: dict[str, np.ndarray], where: str) -> None:
    """Raise one ValueError naming ``where`` and the field unless a loaded item is usable for training.

    Checks the keys present among ``mask``, ``normal``, ``albedo``, ``roughness`` and
    ``metallic``: the targets finite; ``albedo``, ``roughness`` and ``metallic`` in [0, 1];
    ``normal`` of unit length inside the mask (to :data:`pbrdf.data.sample.NORMAL_TOLERANCE`); a
    mask with at least one pixel. Non-finite ``maps`` are left to the training loop, which skips
    such batches and stops after ``--max-skipped`` of them (:mod:`network.train`).

    Args:
        sample: channel-last arrays as :func:`pbrdf.data.sample.read_sample` returns them.
        where: the sample's file, first in the message.

    Raises:
        ValueError: ``"<where>: <field> ..."``, the first problem found.
    """
    for key in TARGET_KEYS:
        if key not in sample:
            continue
        a = sample[key]
        bad = ~np.isfinite(a)
        if bad.any():
            bad = bad.reshape(*a.shape[:2], -1).any(axis=-1)
            raise ValueError(
                f"{where}: {key} holds non-finite values ({int(bad.sum())} pixels, first at {_first_pixel(bad)})"
            )
    for key in ("albedo", "roughness", "metallic"):
        if key in sample:
            lo, hi = float(sample[key].min()), float(sample[key].max())
            if lo < 0 or hi > 1:
                raise ValueError(f"{where}: {key} values must be in [0, 1]; got [{lo:g}, {hi:g}]")
    mask = sample.get("mask")
    if mask is not None and not mask.any():
        raise ValueError(f"{where}: mask is empty (no valid pixel to train on)")
    if mask is not None and "normal" in sample:
        length = np.linalg.norm(sample["normal"].astype(np.float64), axis=-1)
        off = mask.astype(bool) & (np.abs(length - 1) > psample.NORMAL_TOLERANCE)
        if off.any():
            raise ValueError(
                f"{where}: normal must be unit vectors inside the mask (|n| = 1 +- {psample.NORMAL_TOLERANCE:g}); "
                f"{int(off.sum())} are not, e.g. |n| = {float(length[off][0]):.6g} at {_first_pixel(off)}"
            )


def gather_pixels(maps: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """``(B, C, H, W)`` maps at flat pixel indices ``(B, P)`` (``row * W + col``) -> ``(B, C, P)``.

    Example:
        >>> maps = torch.arange(6.0).reshape(1, 1, 2, 3)
        >>> gather_pixels(maps, torch.tensor([[5, 0]]))  # pixels (1, 2) and (0, 0)
        tensor([[[5., 0.]]])
    """
    b, c = maps.shape[:2]
    return maps.reshape(b, c, -1).gather(2, pixels[:, None, :].expand(-1, c, -1))


def sample_to_tensors(sample: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Channel-last sample arrays -> channel-first float tensors (mask as float 0/1)."""
    out = {"maps": torch.from_numpy(np.ascontiguousarray(sample["maps"].transpose(2, 0, 1)))}
    out["mask"] = torch.from_numpy(sample["mask"].astype(np.float32))[None]
    for k in TARGET_KEYS:
        if k in sample:
            a = sample[k]
            a = a[..., None] if a.ndim == 2 else a
            out[k] = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))
    return out


def resize_batch(batch: dict[str, torch.Tensor], size: int) -> dict[str, torch.Tensor]:
    """Resize every map of a (batched or not) sample to ``size x size``.

    Bilinear for the maps and targets, nearest for the mask; normals are renormalised and the
    outputs zeroed outside the resized mask.
    """
    out = {}
    for k, v in batch.items():
        x = v[None] if v.ndim == 3 else v
        if k == "mask":
            y = F.interpolate(x, size=(size, size), mode="nearest")
        else:
            y = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)
        out[k] = y if v.ndim == 4 else y[0]
    mask = out["mask"]
    if "normal" in out:
        n = out["normal"]
        out["normal"] = n / n.norm(dim=-3, keepdim=True).clamp_min(1e-8)
    for k in out:
        if k != "mask":
            out[k] = out[k] * mask
    return out


class SampleDataset(Dataset):
    """The completed samples of a rendered dataset folder, as normalised tensors.

    Every item is checked when it is loaded (:func:`check_item`); a bad one raises ValueError
    naming the sample's EXR and the field.

    Args:
        root: dataset folder written by ``headless/render.py``.
        size: resize every sample to ``size x size`` (None keeps the rendered size).
        indices: which sample indices to use (default: all completed ones, sorted).
        input_scale: :data:`INPUT_SCALES`; ``"calibrated"`` reads the display radiance from each
            sample's sidecar rig.
        light_input: also give ``light`` ``(9, size, size)`` (:func:`network.light_input.sample_light`: the
            display's irradiance at ONE distance, the median of the sample's depth over its mask, as a tape
            measure would give it) and ``distance`` (a 0-d tensor, m).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        size: int | None = None,
        indices: list[int] | None = None,
        input_scale: str = "exposure-invariant",
        light_input: bool = False,
    ) -> None:
        self.light_input = light_input
        if input_scale not in INPUT_SCALES:
            raise ValueError(f"unknown input scale {input_scale!r}; choose one of {INPUT_SCALES}")
        self.input_scale = input_scale
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: dataset folder not found")
        done = sorted(pdataset.completed_indices(self.root))
        if not done:
            raise ValueError(f"{self.root}: no completed samples (render some with headless/render.py)")
        self.indices = done if indices is None else [i for i in indices if i in set(done)]
        self.size = size

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        index = self.indices[i]
        depth = ("depth",) if self.light_input else ()
        sample, meta = psample.read_sample(self.root, index, keys=("maps", "mask", *TARGET_KEYS, *depth))
        where = str(psample.sample_paths(self.root, index).exr)
        check_item(sample, where)
        t = sample_to_tensors({k: v for k, v in sample.items() if k != "depth"})
        if self.size is not None and t["maps"].shape[-1] != self.size:
            t = resize_batch(t, self.size)
        radiance = None
        if self.input_scale == "calibrated":
            radiance = display_radiance(meta, where)
        t["maps"] = normalize_maps(t["maps"], t["mask"], radiance=radiance)
        if self.light_input:
            light, dist = sample_light(meta, sample["depth"], sample["mask"], tuple(t["mask"].shape[-2:]), where)
            t["light"], t["distance"] = light, torch.tensor(dist, dtype=torch.float32)
        return t
