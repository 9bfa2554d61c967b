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
has dark frames is skipped)::

    python -m pbrdf.data.dark_frames DIR

Example:
    >>> from pbrdf.sensor.camera import CameraModel
    >>> d = dark_frames(CameraModel(ambient=(0.01, 0.0, 0.0)), (8, 8), sample_seed=1)
    >>> d.shape, d.dtype.name, bool(d[-1].mean() > d[0].mean() > 16)
    ((4, 8, 8), 'uint16', True)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pbrdf.data import capture as pcapture
from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.io.strict_json import read_json_object
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.rig import Rig

__all__ = ["DARK_STREAM", "add_dark_frames", "dark_frames", "main"]

#: The random stream of the dark frames' noise (the camera noise uses 1, the rig draws 2).
DARK_STREAM = 3


def dark_frames(model: CameraModel, shape: tuple[int, int], sample_seed: int) -> NDArray[np.uint16]:
    """The raw bracket of ``model`` with no display light: ambient light (vignetted), black level and noise.

    Args:
        model: the camera model the scene was captured with (its exposures, sensor and ambient).
        shape: ``(H, W)`` of the raw mosaic (multiples of 4).
        sample_seed: the sample's seed (noise stream ``[sample_seed, DARK_STREAM]``).

    Returns:
        ``(E, H, W)`` uint16, one frame per exposure of ``model.exposures``.
    """
    rng = np.random.default_rng([int(sample_seed), DARK_STREAM])
    return simulate_capture(np.zeros((*shape, 3, 4)), model, rng=rng, noise=True)


def add_dark_frames(root: str | Path, *, overwrite: bool = False) -> int:
    """Give every raw capture of the rendered dataset ``root`` its dark frames.

    Args:
        root: a rendered dataset whose samples kept their raw brackets.
        overwrite: also replace dark frames a capture already has.

    Returns:
        The number of captures written.

    Raises:
        ValueError: a sidecar without ``spec.rig`` or ``sample_seed`` (message names the file), or
            no raw capture under ``root``.
    """
    root = Path(root)
    written = found = 0
    for i in sorted(pdataset.completed_indices(root)):
        paths = psample.sample_paths(root, i)
        if not (paths.raw / pcapture.CAPTURE_JSON).is_file():
            continue
        found += 1
        cap = pcapture.load_capture(paths.raw)
        if cap.dark is not None and not overwrite:
            continue
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
        written += 1
    if not found:
        raise ValueError(f"{root}: no raw captures (render with raw brackets kept)")
    return written


def main(argv: list[str] | None = None) -> int:
    """``python -m pbrdf.data.dark_frames DIR [--overwrite]``: exit status 0, or 2 with one line on an error."""
    parser = argparse.ArgumentParser(prog="python -m pbrdf.data.dark_frames", description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="rendered dataset with raw captures")
    parser.add_argument("--overwrite", action="store_true", help="replace existing dark frames")
    args = parser.parse_args(argv)
    try:
        n = add_dark_frames(args.root, overwrite=args.overwrite)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.root}: dark frames written for {n} captures")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
