"""Blender images from arrays and back: exact float images, map-file channels, image sequences.

Blender's row 0 is the bottom of an image; every function here takes and returns arrays with
row 0 at the top, as the rest of the project does.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import bpy
import numpy as np

from .core import map_io

__all__ = ["image_from_array", "read_channels", "read_channels_blender", "sequence_image"]


def image_from_array(name: str, array: np.ndarray, *, colorspace: str = "Non-Color", pack: bool = True):
    """A float Blender image holding ``array`` exactly.

    Args:
        name: image name (Blender makes it unique).
        array: ``(H, W)``, ``(H, W, 3)`` or ``(H, W, 4)``, row 0 at the top; a single channel is
            copied to R, G and B; alpha is 1 unless given.
        colorspace: ``"Non-Color"`` for data, ``"Linear Rec.709"`` for linear colour.
        pack: pack it into the .blend file (as a float EXR) so it survives saving.

    Returns:
        The ``bpy.types.Image``.
    """
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[-1] not in (1, 3, 4):
        raise ValueError(f"image {name!r}: expected (H, W), (H, W, 3) or (H, W, 4); got {a.shape}")
    h, w, c = a.shape
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = a[..., :3] if c >= 3 else a[..., :1]
    if c == 4:
        rgba[..., 3] = a[..., 3]
    img = bpy.data.images.new(name, width=w, height=h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = colorspace
    img.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())  # Blender's row 0 is the bottom
    if pack:
        img.file_format = "OPEN_EXR"
        img.pack()
    return img


def read_channels(path: Path) -> tuple[dict[str, np.ndarray], bool]:
    """Channels of a map file: :func:`blender_addon.core.map_io.read_channels`, or Blender's loader.

    Blender's bundled Python has numpy but neither Pillow nor OpenEXR: without Pillow, PNG/JPEG
    files are read with ``bpy.data.images.load`` (raw code values / 255); EXR needs OpenEXR.
    """
    if Path(path).suffix.lower() == ".exr" or importlib.util.find_spec("PIL") is not None:
        return map_io.read_channels(path)
    return read_channels_blender(path)


def read_channels_blender(path: Path) -> tuple[dict[str, np.ndarray], bool]:
    """PNG/JPEG channels ``R, G, B, A`` as float32 ``(H, W)`` in [0, 1] via ``bpy.data.images.load``."""
    try:
        img = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as e:
        raise ValueError(f"{path}: not a readable image: {e}") from None
    try:
        img.colorspace_settings.name = "Non-Color"  # raw code values / 255, no transfer function
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        px = px.reshape(h, w, 4)[::-1]  # Blender's row 0 is the bottom
        return {c: np.ascontiguousarray(px[..., i]) for i, c in enumerate("RGBA")}, False
    finally:
        bpy.data.images.remove(img)


def sequence_image(path: Path, kind: str):
    """An image sequence starting at ``path`` (frame 1's file), read from disk as the frames play.

    Colour spaces as :func:`image_from_array` gives them: albedo scene-linear from EXR (sRGB from
    PNG/JPEG), the rest ``Non-Color``.
    """
    try:
        img = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as e:
        raise ValueError(f"{path}: not a readable image: {e}") from None
    img.source = "SEQUENCE"
    float_file = Path(path).suffix.lower() == ".exr"
    img.colorspace_settings.name = ("Linear Rec.709" if float_file else "sRGB") if kind == "albedo" else "Non-Color"
    return img
