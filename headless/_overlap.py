"""headless/infer.py's overlapped stages: the model loads while a capture decodes, the relief while the maps write.

The route is otherwise serial: torch's import and the checkpoint (Python and file reads) need no decoded maps, and
reading and decoding the raw brackets (PNG decoding and numpy, which release the GIL most of the time) need no
torch, so :func:`decode_while_loading` runs the first on a thread while this one decodes. The relief depth
(:func:`network.infer.relief_depth`, scipy's sparse solves) needs only the predicted normals and mask, so
:func:`relief_later` integrates it on a thread while :func:`pbrdf.data.predictions.write_predictions` encodes the
other maps (its ``pending``): the files are the same as the serial route's, written together (the timings are in
docs/measurements/fullframe.md).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from pbrdf.data.capture import CAPTURE_JSON

__all__ = ["decode_while_loading", "relief_later"]


def decode_while_loading(source: Path, rig_path: Path | None, load: Callable[[], Any]) -> tuple[Any, Any]:
    """``load()`` (the model: torch's import and the checkpoint) on a thread while a capture folder is decoded.

    Args:
        source: ``--input``: a capture folder is read and decoded here (:func:`network.infer.load_input`'s
            capture route, the object required); anything else is left to ``load_input`` (None returned).
        rig_path: ``--rig`` (a calibrated rig file), or None.
        load: the model loader; its error comes first when both fail (the serial route's order).

    Returns:
        ``(load(), InferenceInput or None)``.
    """
    if not (source.is_dir() and (source / CAPTURE_JSON).is_file()):
        return load(), None
    with ThreadPoolExecutor(1, thread_name_prefix="load-model") as pool:
        loading = pool.submit(load)
        try:
            cap, dec = _decode(source, rig_path)
        except BaseException:
            loading.result()  # a bad checkpoint is reported before a bad capture, as in the serial route
            raise
        loaded = loading.result()
    from network.infer import InferenceInput  # noqa: PLC0415 (torch is imported by now)

    return loaded, InferenceInput.of_capture(cap, dec)


def _decode(source: Path, rig_path: Path | None):
    """The capture and its decoded maps, refused when nothing is usable (without importing torch)."""
    from pbrdf.data.capture_decode import check_usable, load_and_decode  # noqa: PLC0415
    from pbrdf.data.capture_rig import read_rig  # noqa: PLC0415

    cap, dec = load_and_decode(source, rig=None if rig_path is None else read_rig(rig_path))
    check_usable(dec, cap, need_object=True)
    return cap, dec


def relief_later(pred: dict[str, np.ndarray], intrinsics: np.ndarray, distance: float | None) -> Future:
    """:func:`network.infer.relief_depth` of ``pred`` started on its own thread: a future of ``{"depth": (H, W, 1)}``.

    ``pred``'s normal and mask are read, never written, while the thread runs (the caller writes the maps
    meanwhile); pass the future to :func:`pbrdf.data.predictions.write_predictions`'s ``pending``.
    """
    from network.infer import relief_depth  # noqa: PLC0415

    pool = ThreadPoolExecutor(1, thread_name_prefix="relief")
    try:
        return pool.submit(lambda: {"depth": relief_depth(pred, intrinsics, distance)})
    finally:
        pool.shutdown(wait=False)  # the thread ends with its one job
