"""Calibration target captures on disk: a folder of capture folders, each naming its ``target``.

Layout (``docs/calibration.md``)::

    CAPTURES_DIR/
      dark/capture.json            "target": "dark"        (display off)
      white_r/capture.json         "target": "white", "display_channel": "R", "albedo": 0.99, "distance_m": 0.7
      white_g/ ... white_b/ ...
      white_r_050/capture.json     ... "level": 0.5   (optional: the tone response)
      white_r_near/capture.json    ... "distance_m": 0.4   (optional: the emission profile)
      polarizer_000/capture.json   "target": "polarizer", "polarizer_angle_deg": 0
      polarizer_030/ ...           (at least three distinct angles)

Each is a normal capture folder (:mod:`pbrdf.data.capture`: raws, optional ``dark_files``,
``rig``, ``intrinsics``, ``camera_model`` with the sensor and bracket); the folder names are free.
The keys this module adds (kept in :attr:`~pbrdf.data.capture.Capture.metadata`):

* ``target``: one of :data:`pbrdf.sensor.calibration.TARGET_KINDS` (required);
* ``display_channel``: ``white`` only, the primary the display shows over its whole area,
  ``"R"``, ``"G"``, ``"B"`` (or 0, 1, 2);
* ``albedo``: ``white`` only, the reflectance standard's Lambertian reflectance in ``(0, 1]``
  (default 0.99); ``distance_m`` (required for ``white``) is the plane's distance;
* ``level``: ``white`` only, the commanded level of the primary in ``(0, 1]`` (default 1: full on);
* ``polarizer_angle_deg``: ``polarizer`` only, the polarizer's transmission axis in degrees in the
  analyzers' frame.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from pbrdf.data.capture import CAPTURE_JSON, load_capture, save_capture
from pbrdf.sensor.calibration import CHANNELS, TARGET_KINDS, Target

__all__ = ["TARGET_KEYS", "load_targets", "save_targets"]

#: The ``capture.json`` keys of a calibration target (beside the capture format's own).
TARGET_KEYS = ("target", "display_channel", "albedo", "level", "polarizer_angle_deg")


def _channel(value: Any, where: Path) -> int:
    if isinstance(value, str) and value.upper() in CHANNELS:
        return CHANNELS.index(value.upper())
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < 3:
        return value
    raise ValueError(f"{where}: display_channel must be one of {list(CHANNELS)} (or 0, 1, 2); got {value!r}")


def _finite(value: Any, name: str, where: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
        raise ValueError(f"{where}: {name} must be a finite number; got {str(value)[:40]!r}")
    return float(value)


def _target(folder: Path) -> Target:
    """One capture folder as a :class:`Target` (its ``target`` keys checked)."""
    cap = load_capture(folder)
    md, where = cap.metadata, folder / CAPTURE_JSON
    kind = md.get("target")
    if kind not in TARGET_KINDS:
        raise ValueError(f"{where}: target must be one of {list(TARGET_KINDS)}; got {str(kind)[:40]!r}")
    fields: dict[str, Any] = {}
    if kind == "white":
        if "display_channel" not in md:
            raise ValueError(f"{where}: a white target needs display_channel (the primary shown: R, G or B)")
        fields["display_channel"] = _channel(md["display_channel"], where)
        albedo = _finite(md.get("albedo", 0.99), "albedo", where)
        if not 0.0 < albedo <= 1.0:
            raise ValueError(f"{where}: albedo must be in (0, 1]; got {albedo:g}")
        if cap.meta.distance_m is None:
            raise ValueError(f"{where}: a white target needs distance_m (the target plane's distance in m)")
        level = _finite(md.get("level", 1.0), "level", where)
        if not 0.0 < level <= 1.0:
            raise ValueError(f"{where}: level must be in (0, 1] (the commanded level of the primary); got {level:g}")
        fields.update(albedo=albedo, distance_m=cap.meta.distance_m, level=level)
    if kind == "polarizer":
        if "polarizer_angle_deg" not in md:
            raise ValueError(f"{where}: a polarizer target needs polarizer_angle_deg (the polarizer's axis)")
        fields["polarizer_angle"] = math.radians(_finite(md["polarizer_angle_deg"], "polarizer_angle_deg", where))
    return Target(
        name=folder.name,
        kind=kind,
        raws=cap.raws,
        model=cap.model,
        dark=cap.dark,
        rig=cap.meta.rig,
        intrinsics=cap.meta.intrinsics,
        **fields,
    )


def load_targets(folder: str | os.PathLike) -> list[Target]:
    """Every capture folder (a subfolder holding ``capture.json``) of ``folder`` as a :class:`Target`, by name.

    Raises:
        FileNotFoundError: ``folder`` does not exist.
        ValueError: no capture subfolder, or a bad one (the message names its ``capture.json``).
    """
    root = Path(folder)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: calibration captures folder does not exist")
    subs = sorted(p for p in root.iterdir() if p.is_dir() and (p / CAPTURE_JSON).is_file())
    if not subs:
        raise ValueError(f"{root}: no calibration captures (subfolders holding {CAPTURE_JSON} with a 'target' key)")
    return [_target(p) for p in subs]


def save_targets(folder: str | os.PathLike, targets: list[Target]) -> list[Path]:
    """Write each target as a capture folder ``folder/<name>`` (:func:`pbrdf.data.capture.save_capture`).

    Returns:
        The written capture folders.
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    out = []
    for t in targets:
        extra: dict[str, Any] = {"target": t.kind, "rig": t.rig.to_dict()}
        if t.intrinsics is not None:
            extra["intrinsics"] = np.asarray(t.intrinsics, dtype=np.float64).tolist()
        if t.kind == "white":
            extra.update(display_channel=CHANNELS[t.display_channel], albedo=t.albedo, distance_m=t.distance_m)
            if t.level != 1.0:
                extra["level"] = t.level
        if t.kind == "polarizer":
            extra["polarizer_angle_deg"] = math.degrees(t.polarizer_angle)
        out.append(save_capture(root / t.name, t.raws, t.model, extra=extra, dark=t.dark, overwrite=True))
    return out
