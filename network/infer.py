"""Inference at any input size: crop to the mask, resize to the network, decode masked pixels, map back.

Inputs are either a dataset sample (EXR with the nine maps and mask) or a capture folder (raw
HDR brackets + ``capture.json``), which goes through :mod:`pbrdf.sensor.decode` exactly like the
synthetic data did. Outputs are full-size ``(H, W, C)`` float32 maps, zero outside the mask,
written with :func:`pbrdf.data.predictions.write_predictions`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812

from pbrdf.data import capture as pcapture
from pbrdf.data import capture_decode as pdecode_capture
from pbrdf.data import sample as psample
from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M, display_radiance
from pbrdf.data.predictions import OUTPUT_CHANNELS
from pbrdf.data.sample import sample_intrinsics
from pbrdf.io.errors import NothingToReconstruct
from pbrdf.sensor.rig import Rig

from .data import exposure_radiance, input_radiance, normalize_maps
from .inputs import apply_inputs
from .light_input import LightGeometry, crop_light, sidecar_rig
from .model import PolarInverseModel
from .model.dense import REFINE_DEG, auto_stride

__all__ = [
    "RESOLUTIONS",
    "InferenceInput",
    "relief_depth",
    "auto_refine_deg",
    "FRAME_REFINE_DEG",
    "load_input",
    "predict",
    "mask_bbox",
    "DEFAULT_CHECKPOINT",
]

#: The shipped model (see models/small/MODEL_CARD.md).
DEFAULT_CHECKPOINT = Path(__file__).resolve().parents[1] / "models" / "small" / "model.pt"


#: :func:`predict`'s decoding resolutions: the maps' own (default), or the network's input size.
RESOLUTIONS = ("full", "network")

#: :func:`predict`'s ``refine_deg`` for a capture-sized object at stride 4 (:func:`auto_refine_deg`): cells whose
#: decoded corners' normals differ by less than this are interpolated (measured within issue 30's tolerance of
#: stride 1 on a full-frame capture, with less decoding than :data:`REFINE_DEG`: docs/measurements/fullframe.md).
FRAME_REFINE_DEG = 8.0

# |CP| may exceed 1 by float rounding in someone else's resampling; beyond this it is not CP.
_CP_SLACK = 1e-3
# Radiance maps with a larger peak are scaled down (by a power of two) before normalisation.
_RADIANCE_PEAK = 2.0**64


@dataclass(frozen=True)
class InferenceInput:
    """One input of :func:`predict`, with what its files say about radiometry and geometry.

    Attributes:
        maps: ``(H, W, 9)`` nine maps (:data:`pbrdf.sensor.decode.NINE_MAP_NAMES` order).
        mask: ``(H, W)`` bool, the pixels to reconstruct.
        radiance: the display radiance in the maps' units, or None for an uncalibrated capture
            (``capture.json``'s ``radiometry``; a rendered sample is always calibrated).
        intrinsics: ``K (3, 3)`` of the maps' grid.
        distance_m: the capture's object distance in m, or None (a sample's own depth is ground
            truth, not an input).
        rig: the capture's or sample's rig (:class:`pbrdf.sensor.rig.Rig`), for the light input and
            :mod:`network.refine`'s re-rendering; None where the input has none.
    """

    maps: np.ndarray
    mask: np.ndarray
    radiance: float | None
    intrinsics: np.ndarray
    distance_m: float | None = None
    rig: Rig | None = None

    @classmethod
    def of_capture(cls, cap: pcapture.Capture, dec: pdecode_capture.DecodedCapture) -> InferenceInput:
        """A capture folder's input from its read capture and decoded maps (:func:`load_input`'s capture route)."""
        k = cap.meta.grid_intrinsics(cap.raws.shape[1:], dec.maps.shape[:2])
        return cls(dec.maps, dec.input_mask, cap.meta.radiance, k, cap.meta.distance_m, cap.meta.rig)


def load_input(path: str | Path, *, require_object: bool = False, rig: Rig | None = None) -> InferenceInput:
    """The nine maps, mask, display radiance and camera of a sample EXR/JSON or a capture folder.

    A capture folder is read once (:func:`pbrdf.data.capture.load_capture`: the raws and
    ``capture.json`` with its ``rig``, ``radiometry``, ``intrinsics`` and ``distance_m``) and
    decoded. Its mask is the object (its ``mask.png``, else the automatic foreground mask of
    :mod:`pbrdf.sensor.foreground`) restricted to the measured pixels
    (:attr:`pbrdf.data.capture_decode.DecodedCapture.input_mask`, not the decoder's validity
    mask); its intrinsics are ``capture.json``'s (of the raw grid, default the rig camera's)
    scaled to the decoded grid. A rendered sample gives its sidecar's intrinsics
    (:func:`pbrdf.data.sample.sample_intrinsics`) and display radiance.

    Args:
        path: a sample ``.exr``/``.json`` or a capture folder.
        require_object: refuse an input with nothing to reconstruct (an empty mask; for a capture,
            :func:`pbrdf.data.capture_decode.check_usable` says why: all dark, all saturated, no object).
        rig: a calibrated rig file's rig to decode a capture folder with
            (:func:`pbrdf.data.capture_rig.with_rig`), or None (``capture.json``'s own).

    Raises:
        FileNotFoundError: ``path`` is neither.
        ValueError: bad content, or nothing to reconstruct with ``require_object`` (one line
            naming the file).
    """
    path = Path(path)
    if path.is_dir() and (path / pcapture.CAPTURE_JSON).is_file():
        cap, dec = pdecode_capture.load_and_decode(path, rig=rig)
        if require_object:
            pdecode_capture.check_usable(dec, cap, need_object=True)
        return InferenceInput.of_capture(cap, dec)
    if path.suffix in (".exr", ".json") and path.exists():
        if rig is not None:
            raise ValueError(f"{path}: a rig file decodes a capture folder; a rendered sample has its own rig")
        sample, meta = psample.read_sample(path, keys=("maps", "mask"))
        if require_object and not sample["mask"].any():
            raise NothingToReconstruct(f"{path}: the sample's mask is empty: nothing to reconstruct")
        where = path.with_suffix(".json")
        radiance = display_radiance(meta, str(where))
        k = sample_intrinsics(meta, sample["mask"].shape, where)
        return InferenceInput(sample["maps"], sample["mask"], radiance, k, None, sidecar_rig(meta, str(where)))
    raise FileNotFoundError(f"{path}: not a sample (.exr/.json) or a capture folder with {pcapture.CAPTURE_JSON}")


def relief_depth(pred: dict[str, np.ndarray], intrinsics: np.ndarray, distance: float | None = None) -> np.ndarray:
    """``(H, W, 1)`` depth in m of the predicted surface: its normals integrated over its mask.

    :func:`pbrdf.geometry.normal_integration.integrate_normals` (discontinuity-aware); the median
    depth is ``distance`` (the capture's ``distance_m``; default :data:`pbrdf.data.capture_meta.DEFAULT_DISTANCE_M`, the
    middle of the rig's 0.5-1.0 m working range). The Blender import builds a relief mesh from it.
    """
    from pbrdf.geometry.normal_integration import integrate_normals  # noqa: PLC0415

    mask = pred["mask"][..., 0] > 0
    depth = integrate_normals(pred["normal"], mask, intrinsics, DEFAULT_DISTANCE_M if distance is None else distance)
    return depth[..., None]


def auto_refine_deg(mask_pixels: int) -> float:
    """The default ``refine_deg`` of :func:`predict` for a mask of ``mask_pixels`` pixels (beside its stride).

    :data:`FRAME_REFINE_DEG` where :func:`network.model.dense.auto_stride` picks stride 4 (capture-sized
    objects), else :data:`REFINE_DEG`.

    Example:
        >>> auto_refine_deg(9_000), auto_refine_deg(650_000)
        (4.0, 8.0)
    """
    return FRAME_REFINE_DEG if auto_stride(mask_pixels) == 4 else REFINE_DEG


def mask_bbox(mask: np.ndarray, margin: float = 0.05) -> tuple[int, int, int, int]:
    """Square ``(y0, x0, y1, x1)`` around the mask with a margin, clipped to the image.

    Args:
        mask: ``(H, W)`` bool.
        margin: Margin on each side, as a fraction of the mask's larger extent.

    Returns:
        The box, ``y1 - y0 == x1 - x0`` unless clipped by the image (at least 8 pixels).

    Raises:
        ValueError: If the mask is empty.

    Example:
        >>> mask = np.zeros((100, 100), bool)
        >>> mask[40:60, 30:50] = True
        >>> mask_bbox(mask)
        (39, 29, 61, 51)
    """
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        raise NothingToReconstruct("the mask is empty: nothing to reconstruct")
    h, w = mask.shape
    cy, cx = (ys.min() + ys.max() + 1) / 2, (xs.min() + xs.max() + 1) / 2
    side = max(ys.max() - ys.min() + 1, xs.max() - xs.min() + 1) * (1 + 2 * margin)
    side = int(min(max(side, 8), max(h, w)))
    y0 = int(np.clip(round(cy - side / 2), 0, max(h - side, 0)))
    x0 = int(np.clip(round(cx - side / 2), 0, max(w - side, 0)))
    return y0, x0, min(y0 + side, h), min(x0 + side, w)


@torch.inference_mode()
def predict(
    model: PolarInverseModel,
    maps: np.ndarray,
    mask: np.ndarray,
    *,
    inputs: str = "full",
    input_scale: str = "exposure-invariant",
    radiance: float | None = None,
    stride: int = 1,
    resolution: str = "full",
    refine_deg: float | None = REFINE_DEG,
    light: LightGeometry | None = None,
) -> dict[str, np.ndarray]:
    """Normal, albedo, roughness, metallic ``(H, W, C)`` for nine maps of any size.

    The masked region is cropped (square). The encoder sees the crop resized to the model's input
    size, as in training. With ``resolution="full"`` the per-pixel decoder then reads every masked
    pixel of the crop at its own resolution (its map values, and the encoder's features sampled
    at its position), so the maps keep the capture's detail; with ``"network"`` it decodes the
    resized crop and the result is resized back (faster for crops much larger than the input
    size, blurrier). ``inputs`` is the checkpoint's
    input variant (:mod:`network.inputs`): the maps it was not trained on are zeroed here too.
    ``input_scale`` is the checkpoint's (:mod:`network.data`): a calibrated model reads absolute
    brightness from ``radiance``, the display radiance in the maps' units
    (:attr:`InferenceInput.radiance`); None (an uncalibrated capture) falls back to the
    exposure-invariant scale with a warning.
    ``stride`` trades accuracy for speed: s > 1 decodes every s-th row and column of the network's
    input grid and interpolates the rest (:meth:`PolarInverseModel.decode_dense`), about s^2 times
    less decoder work (``headless/bench.py network`` reports time and error per stride); the
    interpolation is edge-aware (``refine_deg``): pixels where it is unreliable are decoded exactly.

    Args:
        model: the network, on any device (the maps are moved to it, the results come back).
        maps: ``(H, W, 9)`` nine maps (:data:`pbrdf.sensor.decode.NINE_MAP_NAMES` order): finite,
            the CP maps in ``[-1, 1]``; the radiance maps (unpol, LP) at any scale (they are
            normalised; peaks above ``2**64`` are first scaled down by a power of two, exactly).
        mask: ``(H, W)`` bool, the pixels to reconstruct; not empty, and the maps not all zero on it.
        inputs: the checkpoint's input variant.
        input_scale: the checkpoint's ``"input_scale"``.
        radiance: the display radiance in the maps' units, or None (relative radiometry).
        stride: 1, 2 or 4.
        resolution: ``"full"`` (decode at the maps' resolution) or ``"network"`` (at the input size).
        refine_deg: stride > 1: decode the pixels whose decoded neighbours' normals differ by more
            than this (degrees), whose BRDF differs, or that the mask's edge cuts; None interpolates all.
        light: rig, intrinsics of ``maps`` and object distance (:class:`network.light_input.LightGeometry`):
            required by a ``light_input`` model (its light channels are computed for the crop), ignored otherwise.

    Returns:
        ``{"normal": (H, W, 3), "albedo": (H, W, 3), "roughness": (H, W, 1), "metallic": (H, W, 1),
        "mask": (H, W, 1)}`` float32, finite, zero outside the mask; normals unit length inside it.

    Raises:
        NothingToReconstruct: an empty mask, maps that are zero on it, or a mask that vanishes at
            the network's input size.
        ValueError: maps or mask out of range (above), or a network output that is not finite (a
            broken checkpoint), with a one-line message.
    """
    _check_maps(maps, mask)
    box = mask_bbox(mask)
    if not np.any(maps[mask]):
        raise NothingToReconstruct("maps are zero on every mask pixel: nothing to reconstruct")
    maps, radiance = _scaled_radiance(maps, input_radiance(input_scale, radiance))
    if resolution not in RESOLUTIONS:
        raise ValueError(f"resolution must be one of {', '.join(RESOLUTIONS)}; got {resolution!r}")
    if model.config.light_input and light is None:
        raise ValueError("light: a light_input model needs the rig, intrinsics and object distance (LightGeometry)")
    crop = _Crop.of(maps, mask, box, model, light if model.config.light_input else None)
    model.eval()
    decode = _decode_full if resolution == "full" else _decode_network
    pred = decode(model, crop, inputs=inputs, radiance=radiance, stride=stride, refine_deg=refine_deg)
    return _paste_back(pred, mask, box)


def _check_maps(maps: np.ndarray, mask: np.ndarray) -> None:
    """ValueError unless ``maps (H, W, 9)`` are finite with CP in [-1, 1] and ``mask`` is ``(H, W)``."""
    if maps.ndim != 3 or maps.shape[-1] != 9 or mask.shape != maps.shape[:2]:
        raise ValueError(f"expected maps (H, W, 9) and mask (H, W); got {maps.shape} and {mask.shape}")
    if not np.all(np.isfinite(maps)):
        raise ValueError("maps contain NaN or Inf")
    cp = float(np.abs(maps[..., 6:]).max(initial=0.0))
    if cp > 1.0 + _CP_SLACK:
        raise ValueError(f"maps: the CP maps (R_CP, G_CP, B_CP) must lie in [-1, 1]; got |CP| up to {cp:.3g}")


def _scaled_radiance(maps: np.ndarray, radiance: float | None) -> tuple[np.ndarray, float | None]:
    """Maps whose radiance peak exceeds ``2**64`` scaled down by a power of two (exact), the radiance alike.

    Float32 sums of 3e38 overflow; float64 maps may hold up to 1e308.
    """
    peak = float(np.abs(maps[..., :6]).max())
    if peak <= _RADIANCE_PEAK:
        return maps, radiance
    factor = 2.0 ** -math.ceil(math.log2(peak))
    maps = maps.copy()
    maps[..., :6] *= factor
    return maps, None if radiance is None else radiance * factor


@dataclass(frozen=True)
class _Crop:
    """The mask's square crop on the model's device: at its own size and resized to the network's input.

    Attributes:
        maps: ``(1, 9, h, w)`` the crop's maps.
        mask: ``(1, 1, h, w)`` its mask (0/1).
        net_maps: ``(1, 9, S, S)`` bilinearly resized to the input size S.
        net_mask: ``(1, 1, S, S)`` nearest-resized.
        light: ``(1, 9, h, w)`` light channels of the crop (a ``light_input`` model), else None.
        net_light: ``(1, 9, S, S)`` the same on the network's grid.
    """

    maps: torch.Tensor
    mask: torch.Tensor
    net_maps: torch.Tensor
    net_mask: torch.Tensor
    light: torch.Tensor | None = None
    net_light: torch.Tensor | None = None

    @classmethod
    def of(cls, maps: np.ndarray, mask: np.ndarray, box: tuple[int, int, int, int], model: PolarInverseModel,
           light: LightGeometry | None = None) -> _Crop:  # fmt: skip
        y0, x0, y1, x1 = box
        size = model.config.image_size
        device = next(model.parameters()).device  # the model's device (CPU or GPU); results come back as numpy
        m = torch.from_numpy(np.ascontiguousarray(maps[y0:y1, x0:x1].transpose(2, 0, 1)))[None].float().to(device)
        k = torch.from_numpy(mask[y0:y1, x0:x1].astype(np.float32))[None, None].to(device)
        net_m = F.interpolate(m, size=(size, size), mode="bilinear", align_corners=False)
        net_k = F.interpolate(k, size=(size, size), mode="nearest")
        if not bool(net_k.any()):
            raise NothingToReconstruct("the mask vanishes at the network's input size: nothing to reconstruct")
        if light is None:
            return cls(m, k, net_m, net_k)
        lt, net_lt = (crop_light(light, box, hw).to(device) for hw in (tuple(m.shape[-2:]), (size, size)))
        return cls(m, k, net_m, net_k, lt, net_lt)


def _decode_full(model, crop: _Crop, *, inputs, radiance, stride, refine_deg) -> dict[str, torch.Tensor]:
    """``{name: (C, h, w)}`` at the crop's own resolution: the decoder reads every crop pixel."""
    # One scale at both resolutions: the one the encoder's (resized) input defines.
    scale = radiance if radiance is not None else exposure_radiance(crop.net_maps, crop.net_mask)
    features = model.encode(
        apply_inputs(normalize_maps(crop.net_maps, crop.net_mask, radiance=scale), inputs), crop.net_mask,
        crop.net_light,
    )  # fmt: skip
    pixel_maps = apply_inputs(normalize_maps(crop.maps, crop.mask, radiance=scale), inputs)
    pred = model.decode_dense(features, pixel_maps, crop.mask, stride=stride, refine_deg=refine_deg, light=crop.light)
    _check_finite(pred)
    return {name: pred[name][0] for name in OUTPUT_CHANNELS}


def _decode_network(model, crop: _Crop, *, inputs, radiance, stride, refine_deg) -> dict[str, torch.Tensor]:
    """``{name: (C, h, w)}``: decoded at the network's input size, then resized to the crop.

    The predictions are first extended past the (downsampled) mask with their nearest valid
    value, so that upsampling never blends in the zeros outside it: thin parts of the full-size
    mask that the network's grid lost still get a prediction (and normals stay unit length).
    """
    from scipy import ndimage  # noqa: PLC0415

    x = apply_inputs(normalize_maps(crop.net_maps, crop.net_mask, radiance=radiance), inputs)
    pred = model(x, crop.net_mask, stride=stride, refine_deg=refine_deg, light=crop.net_light)
    _check_finite(pred)
    invalid = crop.net_mask[0, 0].cpu().numpy() == 0
    _, (iy, ix) = ndimage.distance_transform_edt(invalid, return_indices=True)
    device = crop.net_mask.device
    iy, ix = torch.from_numpy(iy).to(device), torch.from_numpy(ix).to(device)
    out = {}
    for name in OUTPUT_CHANNELS:
        filled = pred[name][:, :, iy, ix]
        up = F.interpolate(filled, size=crop.mask.shape[-2:], mode="bilinear", align_corners=False)[0]
        out[name] = up / up.norm(dim=0, keepdim=True).clamp_min(1e-8) if name == "normal" else up
    return out


def _paste_back(
    pred: dict[str, torch.Tensor], mask: np.ndarray, box: tuple[int, int, int, int]
) -> dict[str, np.ndarray]:
    """Full-size ``(H, W, C)`` float32 maps: the crop's ``(C, h, w)`` predictions at ``box``, zero outside the mask."""
    y0, x0, y1, x1 = box
    out = {}
    for name, c in OUTPUT_CHANNELS.items():
        full = np.zeros((*mask.shape, c), np.float32)
        full[y0:y1, x0:x1] = pred[name].permute(1, 2, 0).cpu().numpy()
        full[~mask] = 0.0
        out[name] = full
    out["mask"] = mask.astype(np.float32)[..., None]
    return out


def _check_finite(pred: dict[str, torch.Tensor]) -> None:
    for name in OUTPUT_CHANNELS:
        if not bool(torch.isfinite(pred[name]).all()):
            raise ValueError(
                f"the network predicted NaN or Inf {name} for this input (broken checkpoint weights, or maps far "
                "outside the training range)"
            )
