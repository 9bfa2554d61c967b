"""The radiometry and geometry of a capture: the ``capture.json`` keys that say what its pixels mean.

Radiometry. ``"radiometry"`` says whether absolute brightness can be trusted:
``"calibrated"`` (the default when absent) means the camera model's radiometric scale
(``sensor.electrons_per_unit``, gain) and the rig's display radiance (``rig.display.radiance``,
default 1.0) were measured, so the decoded maps are in the renderer's radiance units and
:func:`display_radiance` gives the level a fully lit display channel has in them; the network
then reads absolute albedo. ``"relative"`` (an uncalibrated camera or display) means only ratios
are meaningful: inference falls back to the exposure-invariant input scale and albedo is relative.

Geometry. The optional ``"rig"`` (a partial rig, :meth:`pbrdf.sensor.rig.Rig.from_dict`; default
the default rig), ``"intrinsics"`` (the 3x3 pinhole matrix of the raw mosaic's pixel grid;
default the rig camera's focal length with the principal point at the image centre) and
``"distance_m"`` (the object's distance along the viewing axis in m) place the pixels in the rig.

:func:`parse_capture_meta` turns these keys of a parsed ``capture.json`` into :class:`CaptureMeta`;
the file itself is read only by :mod:`pbrdf.data.capture` (``load_capture``, ``read_capture_meta``).
:func:`parse_intrinsics` and :func:`display_radiance` also read a rendered sample's sidecar.

Errors: :class:`ValueError` with a one-line message that starts with the file.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.data._common import json_number, short_repr
from pbrdf.sensor.projection import crop_intrinsics, pinhole_intrinsics
from pbrdf.sensor.rig import Rig

__all__ = [
    "DEFAULT_DISTANCE_M",
    "RADIOMETRY_MODES",
    "CaptureMeta",
    "parse_capture_meta",
    "parse_intrinsics",
    "display_radiance",
]

#: Object distance in m when a capture does not give one (``distance_m``): the middle of the rig's 0.5 - 1.0 m.
DEFAULT_DISTANCE_M = 0.75
#: Values of the optional ``"radiometry"`` key (the first is the default).
RADIOMETRY_MODES = ("calibrated", "relative")


@dataclass(frozen=True)
class CaptureMeta:
    """The radiometry and geometry keys of ``capture.json``, parsed and checked.

    Attributes:
        rig: the ``"rig"`` key over the default rig (the default rig without it).
        radiometry: one of :data:`RADIOMETRY_MODES`.
        intrinsics: ``K (3, 3)`` of the raw mosaic's pixel grid as given, or None (the rig
            camera's default: :meth:`raw_intrinsics`).
        distance_m: the object's distance along the viewing axis in m, or None.
    """

    rig: Rig = field(default_factory=Rig)
    radiometry: str = RADIOMETRY_MODES[0]
    intrinsics: NDArray[np.float64] | None = None
    distance_m: float | None = None

    @property
    def radiance(self) -> float | None:
        """The display radiance in the decoded maps' units, or None for ``"relative"`` radiometry."""
        return None if self.radiometry == "relative" else float(self.rig.display.radiance)

    def raw_intrinsics(self, raw_shape: tuple[int, int]) -> NDArray[np.float64]:
        """``K (3, 3)`` of the raw grid ``(H, W)``: the given intrinsics, else the rig camera's default.

        The default has the rig camera's focal length and the principal point at the image centre.
        """
        if self.intrinsics is not None:
            return self.intrinsics.copy()
        return pinhole_intrinsics(self.rig.camera.focal_length_px, raw_shape[1], raw_shape[0])

    def grid_intrinsics(self, raw_shape: tuple[int, int], grid_shape: tuple[int, int]) -> NDArray[np.float64]:
        """``K (3, 3)`` of the decoded maps' grid ``(h, w)`` (the half grid: one pixel per 2 x 2 raw block).

        Example:
            >>> k = CaptureMeta(intrinsics=np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]]))
            >>> k.grid_intrinsics((48, 64), (24, 32))[:2]
            array([[50.,  0., 16.],
                   [ 0., 50., 12.]])
        """
        box = (0, 0, int(raw_shape[0]), int(raw_shape[1]))
        return crop_intrinsics(self.raw_intrinsics(raw_shape), box, (int(grid_shape[0]), int(grid_shape[1])))


def parse_capture_meta(metadata: dict[str, Any], where: str | os.PathLike) -> CaptureMeta:
    """The radiometry and geometry keys of a parsed ``capture.json``, checked.

    Args:
        metadata: the sidecar's keys (other keys are ignored).
        where: the file, first in error messages.

    Returns:
        :class:`CaptureMeta` (defaults for the keys that are absent).

    Raises:
        ValueError: a key with a bad value (the message names ``where`` and the key).

    Example:
        >>> parse_capture_meta({"distance_m": 0.6, "radiometry": "relative"}, "capture.json").distance_m
        0.6
    """
    intrinsics = parse_intrinsics(metadata["intrinsics"], where) if "intrinsics" in metadata else None
    distance = None
    if "distance_m" in metadata:
        distance = json_number(metadata["distance_m"], "distance_m", where)
        if not (math.isfinite(distance) and distance > 0):
            raise ValueError(f"{where}: distance_m must be > 0, got {distance}")
    return CaptureMeta(_rig(metadata, where), _radiometry(metadata, where), intrinsics, distance)


def parse_intrinsics(value: Any, where: str | os.PathLike) -> NDArray[np.float64]:
    """A pinhole matrix ``K (3, 3)`` from a JSON value (``capture.json``, a sample sidecar).

    Args:
        value: the JSON value (nested lists).
        where: the file, first in the error message.

    Returns:
        ``(3, 3)`` float64, finite.

    Raises:
        ValueError: not a finite 3x3 matrix of numbers.

    Example:
        >>> parse_intrinsics([[100, 0, 32], [0, 100, 24], [0, 0, 1]], "capture.json")[0]
        array([100.,   0.,  32.])
    """
    try:
        k = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: intrinsics must be a finite 3x3 matrix, got {short_repr(value, 60)}") from None
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise ValueError(f"{where}: intrinsics must be a finite 3x3 matrix, got shape {k.shape}")
    return k


def _radiometry(metadata: dict[str, Any], where: str | os.PathLike) -> str:
    mode = metadata.get("radiometry", RADIOMETRY_MODES[0])
    if mode not in RADIOMETRY_MODES:
        raise ValueError(f"{where}: radiometry must be one of {list(RADIOMETRY_MODES)}; got {short_repr(mode)}")
    return mode


def _rig(metadata: dict[str, Any], where: str | os.PathLike) -> Rig:
    try:
        return Rig.from_dict(metadata["rig"]) if "rig" in metadata else Rig()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: invalid rig: {exc}") from None


def display_radiance(metadata: dict[str, Any], where: str = "capture") -> float | None:
    """The display's radiance in the decoded maps' units, or None for a ``"relative"`` capture.

    Reads the optional ``"radiometry"`` and ``"rig"`` keys of a capture's metadata (or of a
    rendered sample's sidecar, which is always calibrated).

    Args:
        metadata: :attr:`Capture.metadata` or a sample sidecar.
        where: the file, first in error messages.

    Returns:
        ``rig.display.radiance`` (1.0 without a rig) for a calibrated capture, None for a relative one.

    Raises:
        ValueError: an unknown ``"radiometry"`` value or an invalid ``"rig"``.

    Example:
        >>> display_radiance({}), display_radiance({"rig": {"display": {"radiance": 2.5}}})
        (1.0, 2.5)
        >>> display_radiance({"radiometry": "relative"}) is None
        True
    """
    if _radiometry(metadata, where) == "relative":
        return None
    return float(_rig(metadata, where).display.radiance)
