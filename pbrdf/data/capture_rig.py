"""A capture decoded with a calibrated rig file (``headless/calibrate.py``'s ``rig.json``).

The calibration measures the optics (QWP, analyzers, cross-talk, vignetting, ambient light, the
display's polarization) once; every later object capture keeps its own bracket and sensor
settings. :func:`with_rig` therefore takes from the rig file everything but the capture's
``exposures``, ``sensor`` and ``pattern_offset`` (which ``capture.json`` gives), and the rig
(display and camera geometry, display radiance) whole. ``headless/infer.py --rig`` and
``headless/decode.py --rig`` read it; the capture's dark frames (``dark_files``) are still needed
for the ambient light (the decoder subtracts frames, never ``ambient`` itself).

Example:
    >>> import numpy as np
    >>> from pbrdf.data.capture import Capture
    >>> from pbrdf.sensor.camera import CameraModel
    >>> from pbrdf.sensor.rig import CameraSpec
    >>> cap = Capture(raws=np.zeros((1, 4, 4), np.uint16), model=CameraModel(exposures=(0.05,)))
    >>> rig = Rig(camera=CameraSpec(model=CameraModel(qwp_angle=0.02, exposures=(1.0, 2.0))))
    >>> out = with_rig(cap, rig)
    >>> out.model.qwp_angle, out.model.exposures, out.meta.rig == rig
    (0.02, (0.05,), True)
"""

from __future__ import annotations

import dataclasses
import os

from pbrdf.data.capture import Capture
from pbrdf.sensor.rig import Rig

__all__ = ["CAPTURE_OWN_FIELDS", "with_rig", "read_rig"]

#: Camera-model fields a capture keeps from its own ``capture.json`` (its bracket and sensor settings).
CAPTURE_OWN_FIELDS = ("exposures", "sensor", "pattern_offset")


def with_rig(capture: Capture, rig: Rig) -> Capture:
    """``capture`` decoded with ``rig``: its camera model's optics and the rig replace the capture's.

    Args:
        capture: a loaded capture (:func:`pbrdf.data.capture.load_capture`).
        rig: the calibrated rig (:func:`read_rig`).

    Returns:
        A new :class:`~pbrdf.data.capture.Capture`: ``model`` is ``rig.camera.model`` with the
        capture's :data:`CAPTURE_OWN_FIELDS`; ``meta.rig`` is ``rig`` (intrinsics, distance and
        radiometry stay the capture's).
    """
    own = {k: getattr(capture.model, k) for k in CAPTURE_OWN_FIELDS}
    model = dataclasses.replace(rig.camera.model, **own)
    return dataclasses.replace(capture, model=model, meta=dataclasses.replace(capture.meta, rig=rig))


def read_rig(path: str | os.PathLike) -> Rig:
    """The rig file at ``path`` (:meth:`pbrdf.sensor.rig.Rig.load`; one-line errors naming the file).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a rig file (invalid JSON, unknown keys or out-of-range values).
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: rig file not found")
    return Rig.load(path)
