"""Real captures (and rendered samples without their ground truth) for the re-rendering loss.

:class:`RealDataset` reads a folder of capture folders (``pdir-capture/1``, decoded with
:func:`pbrdf.data.capture_decode.decode_capture` exactly like the synthetic data) and/or rendered datasets
(``pdir-dataset/1``; only their nine maps, mask, depth and sidecar geometry are used). Every item
is cropped to a square around the mask (:func:`network.infer.mask_bbox`, as at inference),
resized to the model size ``S`` and normalised (:func:`network.data.normalize_maps`, at the model's
input scale); the camera
geometry follows the crop and the resize, so the re-renderer sees the right rays.

Items (all tensors, so ``torch.stack`` collates them):

=============  ============  ===================================================================
key            shape         meaning
=============  ============  ===================================================================
``maps``       (9, S, S)     normalised nine maps, 0 outside the mask
``mask``       (1, S, S)     0/1
``points``     (3, S, S)     camera-frame surface points in m (OpenGL axes; camera at origin)
``patches``    (N, 11)       display quadrature patches, camera frame
                             (:meth:`network.rerender.Patches.pack`, ``N = 3 nx ny``)
``intrinsics`` (3, 3)        pinhole matrix of the ``S x S`` grid (OpenCV axes, pixel centres
                             at ``i + 0.5``)
=============  ============  ===================================================================

Geometry per source:

* rendered sample without raw brackets: the sidecar's ``rig`` and ``intrinsics`` (of the rendered
  crop, which is the maps' grid) and, with ``use_depth``, the sample's ``depth`` map as the depth
  prior; a sample *with* raw brackets is read as its capture folder (:func:`find_real_inputs`):
  decoded with the rig its ``capture.json`` names (for a jittered rig, the nominal one the
  decoder assumes), the automatic foreground mask, no depth and no sidecar, so no ground truth
  reaches training;
* capture folder: optional keys of ``capture.json`` (parsed into :class:`pbrdf.data.capture_meta.CaptureMeta`):
  ``rig`` (a partial rig dict, :meth:`pbrdf.sensor.rig.Rig.from_dict`; default the
  default rig), ``intrinsics`` (3x3 pinhole matrix of the raw mosaic's pixel grid; default the
  rig camera's focal length with the principal point at the raw image's centre) and
  ``distance_m`` (object distance along the viewing axis; default ``distance``). The decoder's
  half grid has the intrinsics of the raw grid halved (pixel ``(i, j)`` is raw block
  ``(2i..2i+1, 2j..2j+1)``). Without a depth prior every pixel sits on the fronto-parallel plane
  at that distance (the approximation discussed in :mod:`network.rerender`).

Background depth is filled with the median depth of the mask before resizing, so bilinear
resizing never mixes in zeros at the silhouette.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from numpy.typing import NDArray
from torch.utils.data import Dataset

from pbrdf.data import capture as pcapture
from pbrdf.data import capture_decode as pdecode_capture
from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M
from pbrdf.data.sample import sample_intrinsics
from pbrdf.sensor.projection import crop_intrinsics
from pbrdf.sensor.rig import Rig

from .data import INPUT_SCALES, input_radiance, normalize_maps
from .infer import mask_bbox
from .rerender import DEFAULT_PATCHES, display_patches, points_from_depth

__all__ = ["RealDataset", "find_real_inputs", "load_real_input"]


def _is_capture(path: Path) -> bool:
    return path.is_dir() and (path / pcapture.CAPTURE_JSON).is_file()


def _is_dataset(path: Path) -> bool:
    return path.is_dir() and (path / psample.SAMPLES_DIR).is_dir()


def _dataset_samples(root: Path) -> list[Path]:
    """Each completed sample's capture folder when it kept its raw brackets, else its sidecar."""
    out = []
    for i in sorted(pdataset.completed_indices(root)):
        paths = psample.sample_paths(root, i)
        out.append(paths.raw if _is_capture(paths.raw) else paths.sidecar)
    return out


def find_real_inputs(root: str | Path) -> list[Path]:
    """Capture folders and sample sidecars under ``root``, sorted.

    ``root`` may itself be a capture folder or a rendered dataset, or hold such folders one level
    down (other entries are ignored). A rendered sample that kept its raw brackets
    (``NNNNNN_raw/``) is listed as that capture folder, so it is read like a real capture (the
    pseudo-real data of docs/measurements/pseudo_real.md): nothing of its sidecar is read.

    Raises:
        FileNotFoundError: ``root`` is not a folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: real-data folder not found")
    if _is_capture(root):
        return [root]
    if _is_dataset(root):
        return _dataset_samples(root)
    out: list[Path] = []
    for sub in sorted(root.iterdir()):
        if _is_capture(sub):
            out.append(sub)
        elif _is_dataset(sub):
            out.extend(_dataset_samples(sub))
    return out


def load_real_input(path: Path, *, use_depth: bool = True) -> tuple[
    NDArray[np.float32], NDArray[np.bool_], NDArray[np.float64], Rig, NDArray[np.float32] | None, float | None,
    float | None,
]:  # fmt: skip
    """One input at its own resolution.

    Returns:
        ``(maps (H, W, 9), mask (H, W), intrinsics (3, 3) of the maps' grid, rig, depth (H, W) or
        None, distance_m or None, radiance)``: ``radiance`` is the display radiance in the maps'
        units, None for a capture whose radiometry is relative
        (:func:`pbrdf.data.capture_meta.display_radiance`).

    Raises:
        FileNotFoundError, ValueError: unreadable input or bad geometry keys (message names the path).
    """
    if _is_capture(path):
        cap = pcapture.load_capture(path)  # checks rig, radiometry, intrinsics, distance_m
        dec = pdecode_capture.decode_capture(cap)
        k = cap.meta.grid_intrinsics(cap.raws.shape[1:], dec.maps.shape[:2])
        return dec.maps, dec.input_mask, k, cap.meta.rig, None, cap.meta.distance_m, cap.meta.radiance
    keys = ("maps", "mask", "depth") if use_depth else ("maps", "mask")
    sample, meta = psample.read_sample(path, keys=keys)
    try:
        rig = Rig.from_dict(meta["rig"])
        if "intrinsics" not in meta:  # required here: the rendered crop's camera, no default
            raise KeyError("intrinsics")
        k = sample_intrinsics(meta, sample["mask"].shape, path)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: sidecar lacks a valid rig/intrinsics: {exc}") from None
    return sample["maps"], sample["mask"], k, rig, sample.get("depth"), None, float(rig.display.radiance)


class RealDataset(Dataset):
    """Captures and rendered samples as items for :func:`network.losses.real_loss` (module docs).

    Args:
        root: folder (see :func:`find_real_inputs`).
        size: model input size ``S``.
        distance: object distance in m where an input has no depth prior and no ``distance_m``.
        use_depth: use a rendered sample's depth map as the depth prior (False: fixed distance).
        patches: ``(nx, ny)`` display patches per colour region.
        margin: crop margin around the mask (as :func:`network.infer.mask_bbox`).
        input_scale: the model's input scale (:data:`network.data.INPUT_SCALES`); a relative
            capture falls back to the exposure-invariant scale (:func:`network.data.input_radiance`).

    Raises:
        FileNotFoundError: ``root`` is missing.
        ValueError: nothing usable under ``root``, or bad ``size``/``distance``.
    """

    def __init__(
        self,
        root: str | Path,
        size: int,
        *,
        distance: float = DEFAULT_DISTANCE_M,
        use_depth: bool = True,
        patches: tuple[int, int] = DEFAULT_PATCHES,
        margin: float = 0.05,
        input_scale: str = "exposure-invariant",
    ) -> None:
        if input_scale not in INPUT_SCALES:
            raise ValueError(f"unknown input scale {input_scale!r}; choose one of {INPUT_SCALES}")
        self.input_scale = input_scale
        if int(size) < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        if not distance > 0:
            raise ValueError(f"distance must be > 0 m, got {distance}")
        self.root = Path(root)
        self.paths = find_real_inputs(self.root)
        if not self.paths:
            raise ValueError(f"{self.root}: no capture folders ({pcapture.CAPTURE_JSON}) or rendered samples found")
        self.size = int(size)
        self.distance = float(distance)
        self.use_depth = use_depth
        self.patches = tuple(patches)
        self.margin = margin
        self._patch_cache: dict[str, torch.Tensor] = {}

    def __len__(self) -> int:
        return len(self.paths)

    def _patches(self, rig: Rig) -> torch.Tensor:
        key = json.dumps(rig.to_dict(), sort_keys=True)
        if key not in self._patch_cache:
            self._patch_cache[key] = display_patches(rig, self.patches).pack()
        return self._patch_cache[key]

    def __getitem__(self, i: int) -> dict[str, Any]:
        path = self.paths[i]
        maps, mask, k, rig, depth, distance, radiance = load_real_input(path, use_depth=self.use_depth)
        try:
            y0, x0, y1, x1 = mask_bbox(mask, self.margin)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
        s = self.size
        m = torch.from_numpy(np.ascontiguousarray(maps[y0:y1, x0:x1].transpose(2, 0, 1))).float()[None]
        kmask = torch.from_numpy(mask[y0:y1, x0:x1].astype(np.float32))[None, None]
        m = F.interpolate(m, size=(s, s), mode="bilinear", align_corners=False)
        kmask = F.interpolate(kmask, size=(s, s), mode="nearest")
        k_out = crop_intrinsics(k, (y0, x0, y1, x1), (s, s))
        if depth is not None and np.any(mask & (depth > 0)):
            d = np.where(mask & (depth > 0), depth, np.median(depth[mask & (depth > 0)]))[y0:y1, x0:x1]
            d_t = F.interpolate(torch.from_numpy(np.ascontiguousarray(d, dtype=np.float32))[None, None],
                                size=(s, s), mode="bilinear", align_corners=False)[0]  # fmt: skip
        else:
            d_t = torch.full((1, s, s), distance or self.distance)
        return {
            "maps": normalize_maps(m, kmask, radiance=input_radiance(self.input_scale, radiance, str(path)))[0],
            "mask": kmask[0],
            "points": points_from_depth(d_t, k_out),
            "patches": self._patches(rig),
            "intrinsics": torch.as_tensor(k_out, dtype=torch.float32),
        }
