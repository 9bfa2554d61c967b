"""Dark frames for rendered captures: the same bracket with the display off (ambient light, offset, noise).

A lab capture records, besides the bracket, the bracket with the display off, and the decoder
subtracts it (:func:`pbrdf.sensor.decode.subtract_dark`): that removes the room's unpolarized
ambient light, which the automatic foreground mask (:mod:`pbrdf.sensor.foreground`) would
otherwise take for the object over the whole frame. Rendered captures (``headless/render.py``
with raw brackets kept) have none. :func:`add_dark_frames` simulates them through the camera of
the rig the scene was *rendered* with (the sidecar's ``spec.rig``: the drawn rig of a
``--rig-jitter`` sample), so a pseudo-real capture carries what a careful lab's would; the
``capture.json`` keys the decoder reads (the rig it assumes, intrinsics, radiometry) are kept.

The noise comes from its own stream, ``numpy.random.default_rng([sample_seed, DARK_STREAM])``, so
the frames are a pure function of the sample. Run it after rendering (resumable: a capture that
has dark frames is skipped); the command line is ``headless/dark_frames.py --input DIR``.

Example:
    >>> from pbrdf.sensor.camera import CameraModel
    >>> d = dark_frames(CameraModel(ambient=(0.01, 0.0, 0.0)), (8, 8), sample_seed=1)
    >>> d.shape, d.dtype.name, bool(d[-1].mean() > d[0].mean() > 16)
    ((4, 8, 8), 'uint16', True)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import DTypeLike, NDArray

from pbrdf.data import capture as pcapture
from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.io.strict_json import read_json_object
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.rig import Rig

__all__ = ["DARK_STREAM", "add_dark_frames", "dark_frames"]

#: The random stream of the dark frames' noise (the camera noise uses 1, the rig draws 2).
DARK_STREAM = 3


def dark_frames(
    model: CameraModel,
    shape: tuple[int, int],
    sample_seed: int,
    *,
    stream: int = DARK_STREAM,
    dtype: DTypeLike = np.float64,
) -> NDArray[np.uint16]:
    """The raw bracket of ``model`` with no display light: ambient light (vignetted), black level and noise.

    Args:
        model: the camera model the scene was captured with (its exposures, sensor and ambient).
        shape: ``(H, W)`` of the raw mosaic (multiples of 4).
        sample_seed: the sample's seed (noise stream ``[sample_seed, stream]``).
        stream: the noise stream (:data:`DARK_STREAM` for rendered captures; the robustness sweep
            keeps its own).
        dtype: the float type the zero Stokes images are simulated in (that of the scene's
            Stokes images, so that a capture and its dark frames round alike).

    Returns:
        ``(E, H, W)`` uint16, one frame per exposure of ``model.exposures``.
    """
    rng = np.random.default_rng([int(sample_seed), int(stream)])
    return simulate_capture(np.zeros((*shape, 3, 4), dtype=dtype), model, rng=rng, noise=True)


def add_dark_frames(
    root: str | Path, *, overwrite: bool = False, progress: Callable[[int, int], None] | None = None
) -> int:
    """Give every raw capture of the rendered dataset ``root`` its dark frames.

    Args:
        root: a rendered dataset whose samples kept their raw brackets.
        overwrite: also replace dark frames a capture already has.
        progress: called as ``progress(done, total)`` after each raw capture (skipped ones too).

    Returns:
        The number of captures written.

    Raises:
        FileNotFoundError: ``root`` is not a folder.
        ValueError: a sidecar without ``spec.rig`` or ``sample_seed`` (message names the file), or
            no raw capture under ``root``.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: not a folder")
    captures = [
        psample.sample_paths(root, i)
        for i in sorted(pdataset.completed_indices(root))
        if (psample.sample_paths(root, i).raw / pcapture.CAPTURE_JSON).is_file()
    ]
    if not captures:
        raise ValueError(f"{root}: no raw captures (render with raw brackets kept)")
    written = 0
    for done, paths in enumerate(captures, start=1):
        written += _add_one(paths, overwrite)
        if progress is not None:
            progress(done, len(captures))
    return written


def _add_one(paths: psample.SamplePaths, overwrite: bool) -> bool:
    """Write one sample's dark frames into its raw capture; False where it has them already."""
    cap = pcapture.load_capture(paths.raw)
    if cap.dark is not None and not overwrite:
        return False
    meta = read_json_object(paths.sidecar)
    try:
        model = Rig.from_dict(meta["spec"]["rig"]).camera.model
        seed = int(meta["sample_seed"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{paths.sidecar}: no rendered rig (spec.rig) or sample_seed: {exc}") from None
    # The capture's exposures (sorted on load) are the scene camera's: simulate in that order.
    model = model.replace(exposures=cap.model.exposures)
    dark = dark_frames(model, cap.raws.shape[1:], seed)
    pcapture.save_capture(paths.raw, cap.raws, cap.model, extra=dict(cap.metadata), overwrite=True, dark=dark)
    return True
