"""Decoding a capture folder into the nine maps, with its object mask.

:func:`decode_capture` runs :func:`pbrdf.sensor.decode.decode` on a capture
(:mod:`pbrdf.data.capture`) and adds what a user's capture needs before the network: which pixels
were measured, and which belong to the object.

An optional ``mask.png`` (:data:`MASK_FILE`) in the folder marks the object: an 8- or 16-bit
greyscale PNG (a bilevel one also works), nonzero on the object, the size of the decoded grid
(``(H/2, W/2)`` for the default ``"half"`` grid, ``(H, W)`` for ``"full"``) or of the raw frames
``(H, W)``; a raw-size mask is reduced to the half grid by 2x2 blocks (a block is object when at
least two of its four pixels are). It replaces the automatic object mask of
:mod:`pbrdf.sensor.foreground` (:attr:`DecodedCapture.foreground`); without it the object mask
is found from the capture alone.

:func:`check_usable` refuses a capture that decodes to nothing usable and warns
(:class:`CaptureWarning`) when no object stands out, or when the automatic mask covers more than
:data:`FULL_FRAME_FRACTION` of the frame in a capture without dark frames: room light on the
background then passes as object and the maps would show the wall.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pbrdf.data.capture import CAPTURE_JSON, Capture, load_capture, read_capture_files, validate_capture
from pbrdf.data.capture_rig import with_rig
from pbrdf.data.raw_files import open_image
from pbrdf.io.errors import NothingToReconstruct
from pbrdf.sensor.decode import Decoded, decode
from pbrdf.sensor.foreground import capture_foreground
from pbrdf.sensor.rig import Rig

__all__ = [
    "MASK_FILE",
    "DecodedCapture",
    "decode_capture",
    "load_mask",
    "object_mask",
    "CaptureWarning",
    "FULL_FRAME_FRACTION",
    "check_usable",
    "load_and_decode",
    "check_sequence",
]

#: Optional object mask inside a capture folder (overrides the automatic foreground mask).
MASK_FILE = "mask.png"
#: An automatic object mask covering more than this fraction of the frame, in a capture without dark frames,
#: warns (:func:`check_usable`): 1/1000 of the display's radiance as room light already fills the frame
#: (tests/pbrdf/data/test_capture_decode.py), while an object framed with any background left stays well below.
FULL_FRAME_FRACTION = 0.95
# Pillow modes accepted for mask.png: bilevel, 8-bit and 16-bit greyscale.
_MASK_MODES = ("1", "L", "I;16", "I;16L", "I;16B", "I;16N", "I")


@dataclass
class DecodedCapture(Decoded):
    """:class:`pbrdf.sensor.decode.Decoded` of a capture, with its object mask.

    ``maps``, ``mask`` and ``stokes`` are exactly those of :func:`pbrdf.sensor.decode.decode`
    (``mask``: measured and ``s0`` above ``min_signal``; ``maps`` are 0 outside it).

    Attributes:
        measured: ``(H', W')`` bool, the pixels the decoder measured: some exposure unsaturated
            over the whole demosaic support and finite maps (no signal threshold: the dark
            background is "measured" too).
        foreground: ``(H', W')`` bool, the object: the folder's ``mask.png`` if there is one,
            else the automatic mask of :func:`pbrdf.sensor.foreground.capture_foreground`.
        foreground_source: the path of the ``mask.png`` used, or ``"auto"``.
    """

    measured: NDArray[np.bool_]
    foreground: NDArray[np.bool_]
    foreground_source: str

    @property
    def input_mask(self) -> NDArray[np.bool_]:
        """``(H', W')`` bool, the pixels to give the network: ``foreground & measured``."""
        return self.foreground & self.measured


def load_mask(path: str | os.PathLike, shape: tuple[int, int], raw_shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Read an object mask (``mask.png``, see the module docs) onto the decoded grid.

    Args:
        path: the mask image: 8- or 16-bit greyscale (or bilevel) PNG, nonzero = object.
        shape: ``(H', W')`` of the decoded grid.
        raw_shape: ``(H, W)`` of the raw frames; a mask of this size is reduced to the half grid
            by 2x2 blocks (object where at least two of the four pixels are).

    Returns:
        ``(H', W')`` bool.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a readable single-frame greyscale image, wrong size or no object pixel
            (one line naming the file).
    """
    from PIL import UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: mask file does not exist")
    try:
        with open_image(path, "mask") as img:
            if getattr(img, "n_frames", 1) != 1:
                raise ValueError(f"{path}: mask has {img.n_frames} frames; expected one greyscale image")
            if img.mode not in _MASK_MODES:
                raise ValueError(
                    f"{path}: mask must be an 8- or 16-bit greyscale image (nonzero = object); got mode {img.mode!r}"
                )
            img.load()
            mask = np.array(img) != 0
    except UnidentifiedImageError as e:
        raise ValueError(f"{path}: mask is not a readable PNG image") from e
    except (OSError, SyntaxError) as e:
        if isinstance(e, FileNotFoundError | PermissionError):
            raise
        raise ValueError(f"{path}: cannot read mask image ({e})") from e
    shape, raw_shape = tuple(shape), tuple(raw_shape)
    if mask.shape != shape:
        h, w = raw_shape
        if mask.shape != raw_shape or shape != (h // 2, w // 2):
            raise ValueError(
                f"{path}: mask size {mask.shape[1]}x{mask.shape[0]} matches neither the decoded grid "
                f"{shape[1]}x{shape[0]} nor the raw frames {w}x{h}"
            )
        count = mask[0::2, 0::2].astype(np.uint8) + mask[0::2, 1::2] + mask[1::2, 0::2] + mask[1::2, 1::2]
        mask = count >= 2
    if not mask.any():
        raise ValueError(f"{path}: mask has no object pixel (nonzero marks the object)")
    return mask


def object_mask(capture: Capture, decoded: Decoded, *, grid: str = "half") -> tuple[NDArray[np.bool_], str]:
    """The object mask of a decoded capture: its folder's ``mask.png``, else the automatic one.

    Args:
        capture: the capture (its ``folder`` is searched for :data:`MASK_FILE`; None: automatic).
        decoded: its decoded maps on ``grid``.
        grid: the decode grid, ``"half"`` or ``"full"``.

    Returns:
        ``(mask (H', W') bool, source)``, ``source`` the mask file's path or ``"auto"``.

    Raises:
        ValueError: a bad ``mask.png`` (one line naming the file).
    """
    if capture.folder is not None and (Path(capture.folder) / MASK_FILE).exists():
        path = Path(capture.folder) / MASK_FILE
        return load_mask(path, decoded.mask.shape, capture.raws.shape[1:]), str(path)
    return capture_foreground(decoded, capture.model, grid=grid), "auto"


def decode_capture(
    capture: Capture | str | os.PathLike,
    *,
    grid: str = "half",
    eps: float = 1e-6,
    min_signal: float = 0.0,
) -> DecodedCapture:
    """Load (if given a folder) and decode a capture into the nine maps and its object mask.

    Args:
        capture: a :class:`Capture` or the path of a capture folder.
        grid: ``"half"`` (``(H/2, W/2)`` output) or ``"full"`` (``(H, W)``); see
            :func:`pbrdf.sensor.decode.decode`.
        eps: CP regulariser (:func:`pbrdf.sensor.decode.nine_maps`).
        min_signal: pixels whose total ``s0`` is not above this are left out of ``mask`` (and
            their maps are 0), as in :func:`pbrdf.sensor.decode.decode`.

    The capture's dark frames (``dark_files``), if any, are subtracted before the inversion.

    Returns:
        :class:`DecodedCapture` with ``maps`` ``(H', W', 9)`` float32, ``mask`` ``(H', W')`` bool
        and ``stokes`` ``(H', W', 3, 3)`` float32 exactly as :func:`pbrdf.sensor.decode.decode`
        gives them, plus ``measured``, ``foreground`` and ``input_mask`` (the network's mask).

    Raises:
        ValueError: bad capture content, raw frames larger than the rig camera's sensor, or a bad
            ``mask.png``.
    """
    cap = capture if isinstance(capture, Capture) else load_capture(capture)
    if isinstance(capture, Capture):
        validate_capture(cap)
    _check_sensor_size(cap)
    # Decode without a signal threshold (the measured pixels), then apply it exactly as decode().
    dec = decode(cap.raws, cap.model, grid=grid, eps=eps, min_signal=-np.inf, dark=cap.dark)
    measured = dec.mask
    st = np.moveaxis(dec.stokes, (2, 3), (0, 1))  # decode()'s own (colour, component, H', W') layout
    mask = measured & (st[:, 0].sum(axis=0) > min_signal)
    maps = dec.maps
    if not mask.all():
        maps[~mask] = 0.0
    out = Decoded(maps=maps, mask=mask, stokes=dec.stokes)
    foreground, source = object_mask(cap, out, grid=grid)
    return DecodedCapture(
        maps=maps, mask=mask, stokes=dec.stokes, measured=measured, foreground=foreground, foreground_source=source
    )


def _check_sensor_size(cap: Capture) -> None:
    """Refuse raw frames larger than the rig camera's sensor (``rig.camera.sensor_*_px``): no frame of that camera."""
    cam = cap.meta.rig.camera
    h, w = cap.raws.shape[1:]
    if h > cam.sensor_height_px or w > cam.sensor_width_px:
        where = cap.folder if cap.folder is not None else "capture"
        raise ValueError(
            f"{where}: raw frames are {w}x{h}, larger than the camera's {cam.sensor_width_px}x{cam.sensor_height_px} "
            "sensor (capture.json rig.camera.sensor_width_px / sensor_height_px): not a frame of this camera"
        )


class CaptureWarning(UserWarning):
    """A decoded capture that is usable but suspicious (see :func:`check_usable`)."""


def check_usable(decoded: DecodedCapture, capture: Capture, *, need_object: bool = False) -> None:
    """Refuse a decoded capture that holds nothing usable; warn when no object stands out.

    A capture whose brackets are all dark, all saturated or jump from dark to saturated (or
    whose ``black_level`` is at or above the data) decodes to an empty ``mask`` and all-zero
    maps; this says so and why, instead of letting the caller write meaningless output.

    Args:
        decoded: :func:`decode_capture` of ``capture``.
        capture: the capture (its raws and camera model explain an empty mask).
        need_object: also refuse an empty :attr:`DecodedCapture.input_mask` (no object found:
            nothing for the network); otherwise that only warns.

    Raises:
        ValueError: one line naming the capture and the reason.

    Warns:
        CaptureWarning: (``need_object`` False) the mask is not empty but the object mask is:
            the maps hold background only. Also (either way) the automatic object mask covers
            more than :data:`FULL_FRAME_FRACTION` of the frame and the capture has no dark frames.
    """
    where = capture.folder if capture.folder is not None else "capture"
    sensor = capture.model.sensor
    black, threshold = sensor.black_level, sensor.saturation * sensor.white_level
    if not decoded.measured.any():
        raise ValueError(
            f"{where}: nothing usable: every pixel is saturated (at or above {threshold:g} DN, saturation x "
            "white_level) in every exposure; use shorter exposures"
        )
    if not decoded.mask.any():
        raws = np.asarray(capture.raws)
        if raws.max() <= black:
            reason = f"every raw value is at or below black_level {black:g} DN (all dark, or black_level too high)"
        else:
            reason = (
                f"no pixel has signal above black_level {black:g} DN in an exposure where it is below saturation "
                f"({threshold:g} DN): the bracket goes from dark to saturated; add exposures in between"
            )
        raise ValueError(f"{where}: nothing usable: {reason}")
    if not decoded.input_mask.any():
        if decoded.foreground_source == "auto":
            reason = (
                "no object stands out from the background above the noise floor (the automatic foreground mask "
                f"is empty); mark the object with {MASK_FILE}"
            )
        else:
            reason = f"{decoded.foreground_source} covers no measured pixel"
        if need_object:
            raise NothingToReconstruct(f"{where}: nothing to reconstruct: {reason}")
        warnings.warn(f"{where}: {reason}", CaptureWarning, stacklevel=2)
    elif decoded.foreground_source == "auto" and capture.dark is None:
        covered = np.count_nonzero(decoded.foreground) / decoded.foreground.size
        if covered > FULL_FRAME_FRACTION:
            # Without dark frames nothing removes room light (pbrdf.sensor.decode.subtract_dark), and the
            # mask's background level assumes some dark background is left in the frame.
            warnings.warn(
                f"{where}: the automatic object mask covers {covered:.0%} of the frame and the capture has no dark "
                "frames, so light on the background probably passes as object (the maps would show the wall); "
                "record one dark frame per exposure with the display off and list them as dark_files in "
                f"{CAPTURE_JSON} (rendered captures: headless/dark_frames.py), or mark the object with {MASK_FILE}",
                CaptureWarning,
                stacklevel=2,
            )


def load_and_decode(folder: str | os.PathLike, *, rig: Rig | None = None) -> tuple[Capture, DecodedCapture]:
    """Read a capture folder, optionally with a calibrated rig, and decode it (:func:`check_usable` is the caller's).

    The capture route of :func:`network.infer.load_input` without torch (``headless/infer.py`` decodes on the
    main thread while the model loads on another).

    Args:
        folder: a capture folder.
        rig: a calibrated rig file's rig (:func:`pbrdf.data.capture_rig.with_rig`), or None (``capture.json``'s).

    Returns:
        ``(capture, decoded)``.

    Raises:
        FileNotFoundError, ValueError: as :func:`pbrdf.data.capture.load_capture`.
    """
    cap = load_capture(folder)
    cap = cap if rig is None else with_rig(cap, rig)
    return cap, decode_capture(cap)


def check_sequence(folders: Sequence[str | os.PathLike]) -> None:
    """Refuse a sequence of capture folders whose frames do not belong together, before any is decoded.

    Every frame must list the first frame's exposure times, and its raw files must exist and have
    the first frame's size (read from the file headers, not the pixels, so this is quick). Content
    this cannot read is left to :func:`pbrdf.data.capture.load_capture`, which names it.

    Args:
        folders: the frames' capture folders, in order.

    Raises:
        FileNotFoundError: a raw file listed in a frame's ``capture.json`` is missing.
        ValueError: a frame whose exposures or raw size differ from the first frame's (one line
            naming both frames).
    """
    first = None
    for folder in map(Path, folders):
        try:
            exposures, names = read_capture_files(folder)
        except (OSError, ValueError):
            continue  # load_capture says what is wrong with it
        missing = [n for n in names if not (folder / n).is_file()]
        if missing:
            raise FileNotFoundError(f"{folder / missing[0]}: raw file listed in {CAPTURE_JSON} does not exist")
        size = _raw_size(folder / names[0]) if names else None
        if first is None:
            first = (folder, exposures, size)
            continue
        if exposures != first[1]:
            raise ValueError(f"{folder}: exposures_s {exposures} differ from {first[1]} of the sequence's first frame "
                             f"{first[0].name}; a sequence is captured with one bracket")  # fmt: skip
        if size is not None and first[2] is not None and size != first[2]:
            raise ValueError(f"{folder}: raw size {size[0]}x{size[1]} differs from {first[2][0]}x{first[2][1]} of the "
                             f"sequence's first frame {first[0].name}")  # fmt: skip


def _raw_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of a raw file from its header, or None where the header cannot be read."""
    from PIL import Image, UnidentifiedImageError  # noqa: PLC0415

    try:
        if path.suffix.lower() == ".npy":
            shape = np.load(path, mmap_mode="r").shape
            return (int(shape[-1]), int(shape[-2])) if len(shape) >= 2 else None
        with Image.open(path) as img:
            return img.size
    except (OSError, ValueError, UnidentifiedImageError):
        return None
