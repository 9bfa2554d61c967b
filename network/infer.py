"""Inference at any input size: crop to the mask, resize to the network, decode masked pixels, map back.

Inputs are either a dataset sample (EXR with the nine maps and mask) or a capture folder (raw
HDR brackets + ``capture.json``), which goes through :mod:`pbrdf.sensor.decode` exactly like the
synthetic data did. Outputs are full-size ``(H, W, C)`` float32 maps, zero outside the mask.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812

from pbrdf.data import capture as pcapture
from pbrdf.data import capture_decode as pdecode_capture
from pbrdf.data import dataset as pdataset
from pbrdf.io.atomic import fsync_path, temporary_path
from pbrdf.io.errors import NothingToReconstruct
from pbrdf.io.exr import write_exr
from pbrdf.sensor.rig import Rig

from .data import exposure_radiance, input_radiance, normalize_maps
from .inputs import apply_inputs
from .model import PolarInverseModel
from .model.dense import REFINE_DEG

__all__ = [
    "OUTPUTS",
    "RESOLUTIONS",
    "DEFAULT_DISTANCE",
    "input_display_radiance",
    "input_geometry",
    "relief_depth",
    "load_input",
    "predict",
    "mask_bbox",
    "write_predictions",
    "camera_record",
    "DEFAULT_CHECKPOINT",
]

#: The shipped model (``make train-model``; see models/small/MODEL_CARD.md).
DEFAULT_CHECKPOINT = Path(__file__).resolve().parents[1] / "models" / "small" / "model.pt"

#: Object distance in m when a capture does not give one: the middle of the rig's 0.5 - 1.0 m.
DEFAULT_DISTANCE = 0.75

#: Output maps and their channel counts.
OUTPUTS = {"normal": 3, "albedo": 3, "roughness": 1, "metallic": 1}
#: :func:`predict`'s decoding resolutions: the maps' own (default), or the network's input size.
RESOLUTIONS = ("full", "network")

# |CP| may exceed 1 by float rounding in someone else's resampling; beyond this it is not CP.
_CP_SLACK = 1e-3
# Radiance maps with a larger peak are scaled down (by a power of two) before normalisation.
_RADIANCE_PEAK = 2.0**64


def load_input(path: str | Path, *, require_object: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Nine maps ``(H, W, 9)`` and mask ``(H, W)`` from a sample EXR/JSON or a capture folder.

    For a capture folder the mask is the object (its ``mask.png``, else the automatic foreground
    mask of :mod:`pbrdf.sensor.foreground`) restricted to the measured pixels:
    :attr:`pbrdf.data.capture_decode.DecodedCapture.input_mask`, not the decoder's validity mask.

    Args:
        path: a sample ``.exr``/``.json`` or a capture folder.
        require_object: refuse an input with nothing to reconstruct (an empty mask; for a capture,
            :func:`pbrdf.data.capture_decode.check_usable` says why: all dark, all saturated, no object).

    Raises:
        FileNotFoundError: ``path`` is neither.
        ValueError: bad content, or nothing to reconstruct with ``require_object`` (one line
            naming the file).
    """
    path = Path(path)
    if path.is_dir() and (path / pcapture.CAPTURE_JSON).is_file():
        cap = pcapture.load_capture(path)
        dec = pdecode_capture.decode_capture(cap)
        if require_object:
            pdecode_capture.check_usable(dec, cap, need_object=True)
        return dec.maps, dec.input_mask
    if path.suffix in (".exr", ".json") and path.exists():
        sample, _ = pdataset.read_sample(path, keys=("maps", "mask"))
        if require_object and not sample["mask"].any():
            raise NothingToReconstruct(f"{path}: the sample's mask is empty: nothing to reconstruct")
        return sample["maps"], sample["mask"]
    raise FileNotFoundError(f"{path}: not a sample (.exr/.json) or a capture folder with {pcapture.CAPTURE_JSON}")


def input_display_radiance(path: str | Path) -> float | None:
    """The display radiance in :func:`load_input`'s map units, or None for an uncalibrated capture.

    Reads ``capture.json`` of a capture folder (:func:`pbrdf.data.capture.display_radiance`: its
    ``radiometry`` and ``rig`` keys) or a rendered sample's sidecar (always calibrated).

    Raises:
        FileNotFoundError: ``path`` is neither a capture folder nor a sample.
        ValueError: an unreadable file or invalid ``radiometry``/``rig`` (one line naming the file).
    """
    path = Path(path)
    if path.is_dir() and (path / pcapture.CAPTURE_JSON).is_file():
        where = path / pcapture.CAPTURE_JSON
    elif path.suffix in (".exr", ".json") and path.with_suffix(".json").is_file():
        where = path.with_suffix(".json")
    else:
        raise FileNotFoundError(f"{path}: not a sample (.exr/.json) or a capture folder with {pcapture.CAPTURE_JSON}")
    return pcapture.display_radiance(_json_object(where), str(where))


def input_geometry(path: str | Path, grid_shape: tuple[int, int]) -> tuple[np.ndarray, float | None]:
    """Pinhole matrix of :func:`load_input`'s map grid and the object distance, for a capture or sample.

    A capture folder: ``capture.json``'s optional ``intrinsics`` (of the raw mosaic's grid;
    default the rig camera's focal length with the principal point at the image centre) scaled to
    the decoded grid, and ``distance_m`` (None without it). A rendered sample: its sidecar's
    ``intrinsics`` (of the rendered crop, the maps' grid; without them the default camera's field of
    view across the map) and no distance (the sample's own depth is ground truth, not an input).

    Args:
        path: the capture folder or sample.
        grid_shape: ``(H, W)`` of the decoded maps.

    Raises:
        FileNotFoundError: neither a capture folder nor a sample.
        ValueError: bad ``rig``, ``intrinsics`` or ``distance_m`` (one line naming the file).
    """
    path = Path(path)
    if path.is_dir() and (path / pcapture.CAPTURE_JSON).is_file():
        where = path / pcapture.CAPTURE_JSON
        meta = _json_object(where)
        try:
            rig = Rig.from_dict(meta["rig"]) if "rig" in meta else Rig()
            raw_h = 2 * grid_shape[0]  # the decoder's half grid: one pixel per 2 x 2 raw block
            if "intrinsics" in meta:
                k = np.asarray(meta["intrinsics"], dtype=np.float64)
                if k.shape != (3, 3) or not np.all(np.isfinite(k)):
                    raise ValueError(f"intrinsics must be a finite 3x3 matrix, got shape {k.shape}")
            else:
                f = rig.camera.focal_length_px
                k = np.array([[f, 0.0, grid_shape[1]], [0.0, f, grid_shape[0]], [0.0, 0.0, 1.0]])
            distance = float(meta["distance_m"]) if "distance_m" in meta else None
            if distance is not None and not (math.isfinite(distance) and distance > 0):
                raise ValueError(f"distance_m must be > 0, got {distance}")
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        k = k.copy()
        k[:2] *= grid_shape[0] / raw_h  # pixel centres scale with the grid
        return k, distance
    if path.suffix in (".exr", ".json") and path.with_suffix(".json").is_file():
        where = path.with_suffix(".json")
        meta = _json_object(where)
        if "intrinsics" in meta:
            k = np.asarray(meta["intrinsics"], dtype=np.float64)
            if k.shape != (3, 3) or not np.all(np.isfinite(k)):
                raise ValueError(f"{where}: intrinsics must be a finite 3x3 matrix")
            return k, None
        # No intrinsics: the default camera's field of view across the map's width.
        cam = Rig().camera
        f = cam.focal_length_px * grid_shape[1] / cam.sensor_width_px
        return np.array([[f, 0.0, grid_shape[1] / 2], [0.0, f, grid_shape[0] / 2], [0.0, 0.0, 1.0]]), None
    raise FileNotFoundError(f"{path}: not a sample (.exr/.json) or a capture folder with {pcapture.CAPTURE_JSON}")


def _json_object(where: Path) -> dict:
    try:
        meta = json.loads(where.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{where}: unreadable JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{where}: expected a JSON object")
    return meta


def relief_depth(pred: dict[str, np.ndarray], intrinsics: np.ndarray, distance: float | None = None) -> np.ndarray:
    """``(H, W, 1)`` depth in m of the predicted surface: its normals integrated over its mask.

    :func:`pbrdf.geometry.normal_integration.integrate_normals` (discontinuity-aware); the median
    depth is ``distance`` (the capture's ``distance_m``; default :data:`DEFAULT_DISTANCE`, the
    middle of the rig's 0.5-1.0 m working range). The Blender import builds a relief mesh from it.
    """
    from pbrdf.geometry.normal_integration import integrate_normals  # noqa: PLC0415

    mask = pred["mask"][..., 0] > 0
    depth = integrate_normals(pred["normal"], mask, intrinsics, DEFAULT_DISTANCE if distance is None else distance)
    return depth[..., None]


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
    (:func:`input_display_radiance`); None (an uncalibrated capture) falls back to the
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

    Returns:
        ``{"normal": (H, W, 3), "albedo": (H, W, 3), "roughness": (H, W, 1), "metallic": (H, W, 1),
        "mask": (H, W, 1)}`` float32, finite, zero outside the mask; normals unit length inside it.

    Raises:
        ValueError: maps or mask out of range (above), or a network output that is not finite (a
            broken checkpoint), with a one-line message.
    """
    if maps.ndim != 3 or maps.shape[-1] != 9 or mask.shape != maps.shape[:2]:
        raise ValueError(f"expected maps (H, W, 9) and mask (H, W); got {maps.shape} and {mask.shape}")
    if not np.all(np.isfinite(maps)):
        raise ValueError("maps contain NaN or Inf")
    cp = float(np.abs(maps[..., 6:]).max(initial=0.0))
    if cp > 1.0 + _CP_SLACK:
        raise ValueError(f"maps: the CP maps (R_CP, G_CP, B_CP) must lie in [-1, 1]; got |CP| up to {cp:.3g}")
    y0, x0, y1, x1 = mask_bbox(mask)
    if not np.any(maps[mask]):
        raise NothingToReconstruct("maps are zero on every mask pixel: nothing to reconstruct")
    radiance = input_radiance(input_scale, radiance)
    peak = float(np.abs(maps[..., :6]).max())
    if peak > _RADIANCE_PEAK:  # float32 sums of 3e38 overflow: scale maps and radiance alike
        factor = 2.0 ** -math.ceil(math.log2(peak))  # exact: a power of two (float64 maps: up to 1e308)
        maps = maps.copy()
        maps[..., :6] *= factor
        radiance = None if radiance is None else radiance * factor
    if resolution not in RESOLUTIONS:
        raise ValueError(f"resolution must be one of {', '.join(RESOLUTIONS)}; got {resolution!r}")
    size = model.config.image_size
    device = next(model.parameters()).device  # the model's device (CPU or GPU); results come back as numpy
    m_crop = torch.from_numpy(np.ascontiguousarray(maps[y0:y1, x0:x1].transpose(2, 0, 1)))[None].float().to(device)
    k_crop = torch.from_numpy(mask[y0:y1, x0:x1].astype(np.float32))[None, None].to(device)
    m = F.interpolate(m_crop, size=(size, size), mode="bilinear", align_corners=False)
    k = F.interpolate(k_crop, size=(size, size), mode="nearest")
    model.eval()
    if resolution == "full":
        if not bool(k.any()):
            raise NothingToReconstruct("the mask vanishes at the network's input size: nothing to reconstruct")
        # One scale at both resolutions: the one the encoder's (resized) input defines.
        scale = radiance if radiance is not None else exposure_radiance(m, k)
        with torch.no_grad():
            features = model.encode(apply_inputs(normalize_maps(m, k, radiance=scale), inputs), k)
            pixel_maps = apply_inputs(normalize_maps(m_crop, k_crop, radiance=scale), inputs)
            pred = model.decode_dense(features, pixel_maps, k_crop, stride=stride, refine_deg=refine_deg)
        _check_finite(pred)
        h, w = mask.shape
        out = {}
        for name, c in OUTPUTS.items():
            full = np.zeros((h, w, c), np.float32)
            full[y0:y1, x0:x1] = pred[name][0].permute(1, 2, 0).cpu().numpy()
            full[~mask] = 0.0
            out[name] = full
        out["mask"] = mask.astype(np.float32)[..., None]
        return out
    with torch.no_grad():
        pred = model(
            apply_inputs(normalize_maps(m, k, radiance=radiance), inputs), k, stride=stride, refine_deg=refine_deg
        )
    _check_finite(pred)
    # Extend the predictions past the (downsampled) mask with their nearest valid value, so that
    # upsampling never blends in the zeros outside it: thin parts of the full-size mask that the
    # network's grid lost still get a prediction (and normals stay unit length).
    from scipy import ndimage  # noqa: PLC0415

    invalid = k[0, 0].cpu().numpy() == 0
    if invalid.all():
        raise NothingToReconstruct("the mask vanishes at the network's input size: nothing to reconstruct")
    _, (iy, ix) = ndimage.distance_transform_edt(invalid, return_indices=True)
    iy, ix = torch.from_numpy(iy).to(device), torch.from_numpy(ix).to(device)
    h, w = mask.shape
    out = {}
    for name, c in OUTPUTS.items():
        filled = pred[name][:, :, iy, ix]
        x = F.interpolate(filled, size=(y1 - y0, x1 - x0), mode="bilinear", align_corners=False)[0]
        if name == "normal":
            x = x / x.norm(dim=0, keepdim=True).clamp_min(1e-8)
        full = np.zeros((h, w, c), np.float32)
        full[y0:y1, x0:x1] = x.permute(1, 2, 0).cpu().numpy()
        full[~mask] = 0.0
        out[name] = full
    out["mask"] = mask.astype(np.float32)[..., None]
    return out


def _check_finite(pred: dict[str, torch.Tensor]) -> None:
    for name in OUTPUTS:
        if not bool(torch.isfinite(pred[name]).all()):
            raise ValueError(
                f"the network predicted NaN or Inf {name} for this input (broken checkpoint weights, or maps far "
                "outside the training range)"
            )


def _png(img: np.ndarray) -> bytes:
    from PIL import Image  # noqa: PLC0415

    a = np.clip(np.nan_to_num(img), 0, 1)
    a = (a[..., 0] if a.shape[-1] == 1 else a) * 255
    buf = io.BytesIO()
    Image.fromarray(np.rint(a).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def camera_record(intrinsics: np.ndarray, shape: tuple[int, int], distance: float | None) -> dict:
    """The ``<name>_camera.json`` content: the maps' pinhole camera, for a matching Blender camera.

    Args:
        intrinsics: ``K (3, 3)`` of the maps' grid, pixel centres at integer + 0.5 (OpenCV convention).
        shape: ``(H, W)`` of the maps.
        distance: the capture's ``distance_m``, or None.

    Returns:
        ``{"intrinsics": K as nested lists, "width": W, "height": H, "distance_m": d or null}``.
    """
    k = np.asarray(intrinsics, dtype=np.float64)
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or not (k[0, 0] > 0 and k[1, 1] > 0):
        raise ValueError(f"intrinsics must be a finite 3x3 matrix with positive focal lengths; got {k.tolist()}")
    return {"intrinsics": k.tolist(), "width": int(shape[1]), "height": int(shape[0]),
            "distance_m": None if distance is None else float(distance)}  # fmt: skip


def write_predictions(
    out: str | Path, name: str, pred: dict[str, np.ndarray], camera: dict | None = None
) -> list[Path]:
    """Write ``<name>_<map>.exr`` (float32) and ``.png`` previews for every predicted map.

    File names follow the Blender import's token rules (``_normal``, ``_albedo``, ``_roughness``,
    ``_metallic``, ``_mask``). Normals are camera-space unit vectors (x right, y up, z toward the
    camera; channels X, Y, Z); the PNG preview maps them from [-1, 1] to [0, 1].

    Everything is checked and encoded first, into a temporary folder inside ``out``; only then
    are the files renamed into place. On any error nothing is written (``out`` is created only
    when the files are ready, and the temporary folder is removed).

    Args:
        out: the output folder (created if missing).
        name: the file name prefix.
        pred: ``{map: (H, W, C) float32}`` as :func:`predict` returns, all finite.
        camera: :func:`camera_record` of the maps, written as ``<name>_camera.json`` (the Blender
            import gives its camera these intrinsics, so a relief mesh keeps the capture's shape).

    Returns:
        The written paths (EXR then PNG per map).

    Raises:
        ValueError: a map that is not ``(H, W, C)`` or holds NaN/Inf (nothing written).
        OSError: the folder cannot be written (nothing left behind).
    """
    out = Path(out)
    for key, img in pred.items():
        if img.ndim != 3 or not np.all(np.isfinite(img)):
            raise ValueError(f"predicted {key} map is not a finite (H, W, C) array; nothing written")
    mask = pred["mask"][..., 0] > 0 if "mask" in pred else None
    files: list[tuple[str, dict[str, np.ndarray] | bytes]] = []
    for key, img in pred.items():
        chans = "XYZ" if key == "normal" else ("RGB" if img.shape[-1] == 3 else "Y")
        files.append((f"{name}_{key}.exr", {f"{key}.{c}": img[..., i] for i, c in enumerate(chans)}))
        preview = img * 0.5 + 0.5 if key == "normal" else img
        if key == "depth":  # near = bright, far = dark, over the mask's range
            inside = img[..., 0][mask] if mask is not None and mask.any() else img[..., 0].ravel()
            lo, hi = float(inside.min()), float(inside.max())
            preview = (hi - img) / (hi - lo) if hi > lo else np.ones_like(img)
        if mask is not None:
            preview = preview * mask[..., None]
        files.append((f"{name}_{key}.png", _png(preview)))
    if camera is not None:
        files.append((f"{name}_camera.json", (json.dumps(camera, indent=1) + "\n").encode()))
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: output path exists and is not a folder")
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    staging = temporary_path(out / name)
    try:
        staging.mkdir()
        for file_name, content in files:
            if isinstance(content, bytes):
                with open(staging / file_name, "wb") as f:
                    f.write(content)
                    f.flush()
                    os.fsync(f.fileno())
            else:
                write_exr(staging / file_name, content)
        paths = []
        for file_name, _ in files:
            os.replace(staging / file_name, out / file_name)
            paths.append(out / file_name)
        fsync_path(out, directory=True)
    except BaseException:
        if created:  # leave no empty output folder behind either
            shutil.rmtree(staging, ignore_errors=True)
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return paths
